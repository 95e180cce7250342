"""The twin-scaling fits: power laws recovered exactly, CPU seconds per stage (the BA's from the
mapping stage's CPU rate, less its first call), and the extrapolation computed by hand."""

from __future__ import annotations

import pytest

from polarref.compare.twins import scaling as S
from polarref.core.provenance import Provenance
from polarref.sfm.stages import StageCost


def _run(views, pairs, ba="euclidean", cached=False):
    # CPU: features 0.5 s/view, matching 0.1 s/pair; mapping runs at CPU/wall 0.5, its BA (wall)
    # 0.01 views^2 + a 3 s first call, the rest of it (wall) 2 s/view
    ba_wall = 0.01 * views ** 2 + 3.0          # + 3 s first call
    stages = (StageCost("features", 9.0, 0.5 * views, cached=cached),
              StageCost("matching", 9.0, 0.1 * pairs, cached=cached),
              StageCost("verification", 9.0, 0.02 * pairs, cached=cached),
              StageCost("tracks", 1.0, 0.001 * pairs),
              StageCost("mapping", ba_wall + 2 * views, 0.5 * (ba_wall + 2 * views)),
              StageCost("ba", ba_wall))
    env = Provenance("a" * 40, False, 2, "cpu", "x86_64", "linux", "3.12", {}, {}, {})
    return S.BlockRun(f"b{views}", ba, views, pairs, pairs, 10, 100 * views, views, 10 * views, 0.01, stages,
                      S.BAStats(1, 1.0, 1, 1.0, 1.0, 2, first_s=3.0), (1.0, 1.0, 1.0), (2.0, 1.0, 1.0), 2, 1.0, env)


def test_power_law_is_recovered_and_extrapolated():
    assert S.fit_power([10, 20, 40], [3 * 10 ** 1.5, 3 * 20 ** 1.5, 3 * 40 ** 1.5]) == pytest.approx((1.5, 3.0))
    assert S.fit_power([10, 10], [1.0, 2.0]) == (None, None)
    runs = [_run(36, 240), _run(72, 480), _run(144, 960), _run(144, 960, "polar", cached=True)]
    rep = S.build("mappilot", "euclidean", runs)
    fit = {f.stage: f for f in rep.fits}
    assert rep.pairs_per_view == pytest.approx(960 / 144)
    assert fit["features"].exponent == pytest.approx(1.0) and fit["features"].coef == pytest.approx(0.5)
    assert fit["matching"].at_twin_s["mappilot"] == pytest.approx(0.1 * 960 / 144 * 493)
    # BA: (wall - first call) x the mapping's CPU/wall rate 0.5 = 0.005 views^2
    assert fit["ba"].exponent == pytest.approx(2.0) and fit["ba"].at_twin_s["poets-park"] == pytest.approx(0.005 * 857 ** 2)
    assert fit["mapping (excl. BA)"].at_twin_s["rosetta"] == pytest.approx(1.0 * 631)
    assert fit["ba first call"].at_twin_s["rosetta"] == pytest.approx(1.5)
    total = sum(f.at_twin_s["rosetta"] for f in rep.fits)
    assert rep.total_at_twin_s["rosetta"] == pytest.approx(total)
    # the polar runs read the front end from the cache: its fits come from the Euclidean runs
    polar = S.build("mappilot", "polar", runs + [_run(36, 240, "polar", cached=True)])
    assert {f.stage: f for f in polar.fits}["matching"].exponent == pytest.approx(1.0)
    assert "Indicative" in S.render(rep)


def test_wall_estimate_scales_each_stage_by_its_measured_wall_over_cpu():
    runs = [_run(36, 240), _run(72, 480), _run(144, 960)]
    rep = S.build("mappilot", "euclidean", runs)
    big = runs[-1]
    # features: 9 s wall for 0.5 * 144 CPU s at the largest block
    assert S.wall_ratio(rep, "features") == pytest.approx(9.0 / (0.5 * 144))
    expected = 0.0
    for f in rep.fits:
        r = S.wall_ratio(rep, f.stage)
        expected += f.at_twin_s["rosetta"] * (1.0 if r is None else r)
    text = S._wall_estimate(rep, "rosetta")
    assert text.startswith(f"{expected:.1f} (")
    # the front end read from a cache has no ratio: counted at CPU time and marked
    polar = S.build("mappilot", "polar", runs + [_run(36, 240, "polar", cached=True), _run(144, 960, "polar", cached=True)])
    assert S.wall_ratio(polar, "features") is None and S._wall_estimate(polar, "rosetta").endswith("*")
    assert big.wall("features") == 9.0
