"""A twin's sub-block (synth.subblock) and what the aerotriangulation reads of it: the block's
views, its cut scene.json, the priors' drift along the twin's flight, typed triangulations."""

import json

import numpy as np
import pytest

from synth.config import preset, twin
from synth.subblock import SubBlock, cut_scene_json
from synth.uav import flight_plan, nadir_views


def _position(cfg, k):
    """(line, along-track position counted along +x) of nadir view k, from the lawnmower's rule."""
    lines, per_line, _, _ = flight_plan(cfg)
    line, j = divmod(k, per_line)
    return line, (j if line % 2 == 0 else per_line - 1 - j)


def test_mappilot_block_is_every_view_inside_it():
    cfg = twin("mappilot")
    block = SubBlock("mappilot", 5, 10, 10, 24)
    idx = block.indices(cfg)
    inside = [k for k in range(nadir_views(cfg)) if 5 <= _position(cfg, k)[0] < 10 and 10 <= _position(cfg, k)[1] < 24]
    assert list(idx) == inside and len(idx) == 70
    assert list(idx) == sorted(idx)  # flight order


def test_block_views_sit_on_a_contiguous_grid():
    """On a rendered preset's own poses (uav.build): the block's centres fill whole rows and columns."""
    from synth.uav import build

    cfg = preset("uav", "small")
    lines, per_line, dx, dy = flight_plan(cfg)
    geo = build(cfg)
    idx = SubBlock("small", 0, 2, 1, 4).indices(cfg)
    C = np.array([geo.poses[k].center for k in idx])
    # the centres jitter by N(0, 0.3 m): round to the flight grid
    cols, rows = np.round(C[:, 0] / dx).astype(int), np.round(C[:, 1] / dy).astype(int)
    assert sorted(zip(rows, cols)) == [(r, c) for r in range(2) for c in range(1, 4)]


@pytest.mark.parametrize("bad", [(0, 0, 0, 3), (0, 3, 0, 3), (0, 2, 2, 7), (-1, 1, 0, 2)])
def test_block_outside_the_flight_is_refused(bad):
    with pytest.raises(ValueError, match="outside the twin"):
        SubBlock("small", *bad).indices(preset("uav", "small"))


def test_cut_scene_json_keeps_the_twins_priors():
    n = 10
    meta = {"views": [{"image_id": k + 1, "name": f"{k:04d}.png", "center": [k, 0, 0]} for k in range(n)],
            "priors": {"format": "p", "views": [{"center": [k + 0.5, 0, 0]} for k in range(n)]}}
    out = cut_scene_json(meta, SubBlock("t", 0, 1, 0, 1), (2, 3, 7))
    assert [v["name"] for v in out["views"]] == ["0002.png", "0003.png", "0007.png"]
    assert [v["image_id"] for v in out["views"]] == [1, 2, 3]
    assert [p["center"][0] for p in out["priors"]["views"]] == [2.5, 3.5, 7.5]
    assert out["priors"]["sequence"] == [2, 3, 7] and out["subblock"]["twin_views"] == n
    assert len(meta["views"]) == n and "sequence" not in meta["priors"]  # the input is left as it was


def test_prior_sequence_read_back(tmp_path):
    from polarref.core.errors import PolarrefError
    from polarref.georef.scene_priors import PRIORS_FORMAT, prior_sequence

    views = [{"name": n} for n in ("a.png", "b.png", "c.png")]
    view = {"center": [0, 0, 1], "center_sigma_m": [2, 2, 4], "qvec": [1, 0, 0, 0], "tvec": [0, 0, -1],
            "rotation_sigma_deg": 0.0}
    pri = {"format": PRIORS_FORMAT, "views": [view] * 3,
           "params": {"position_sigma_m": 2.0, "vertical_sigma_m": 4.0, "rotation_sigma_deg": 0.0, "correlation": 0.9}}
    p = tmp_path / "scene.json"
    p.write_text(json.dumps({"views": views, "priors": pri}))
    assert prior_sequence(p, ["c.png", "a.png"]).tolist() == [2, 0]
    p.write_text(json.dumps({"views": views, "priors": {**pri, "sequence": [40, 41, 75]}}))
    assert prior_sequence(p, ["a.png", "b.png", "c.png"]).tolist() == [40, 41, 75]
    with pytest.raises(PolarrefError, match="no prior for image 'd.png'"):
        prior_sequence(p, ["d.png"])
    p.write_text(json.dumps({"views": views, "priors": {**pri, "params": {}}}))
    with pytest.raises(PolarrefError, match="malformed priors section"):
        prior_sequence(p, ["a.png"])


def test_prediction_follows_the_flight_sequence():
    """Two strips cut from a 60-view AR(1) flight (rho 0.95): the prediction with the flight
    indices matches a Monte Carlo of Umeyama fits (closed form, independent of the linear
    propagation); the one that takes the block's own order (no gap) does not."""
    from polarref.core.geometry import umeyama
    from polarref.georef.predict import predict_priors_only

    rho, sig, n_flight = 0.95, 2.0, 60
    seq = np.r_[np.arange(5, 15), np.arange(45, 55)]
    C = np.array([[20.0 * (k % 10), 40.0 * (k // 10), 100.0] for k in range(20)])
    G = np.array([[x, y, 0.0] for x in (10.0, 90.0, 170.0) for y in (0.0, 40.0)])
    pred = predict_priors_only(C, np.full(C.shape, sig), G, rho, sequence=seq)
    wrong = predict_priors_only(C, np.full(C.shape, sig), G, rho)
    rng = np.random.default_rng(3)
    err = []
    for _ in range(1500):
        e = np.empty((n_flight, 3))
        e[0] = rng.normal(0, 1, 3)
        for k in range(1, n_flight):
            e[k] = rho * e[k - 1] + np.sqrt(1 - rho**2) * rng.normal(0, 1, 3)
        err.append(umeyama(C, C + sig * e[seq]).apply(G) - G)
    rm = np.sqrt((np.concatenate(err) ** 2).mean(0))
    ratio = np.array([rm[0] / pred.rmse_x, rm[1] / pred.rmse_y, rm[2] / pred.rmse_z])
    assert np.all(np.abs(ratio - 1) < 0.08), ratio
    # ignoring the gap gets it wrong: the strips' drifts are nearly independent (0.95^31 = 0.2), so
    # they tilt the datum about the strips' axis, which one continuous drift would not
    assert wrong.rmse_horizontal < 0.85 * pred.rmse_horizontal


def test_triangulated_matches_points_by_id():
    from polarref.georef.adjust import Triangulated, check_stats
    from polarref.georef.formats import GroundPoint, Role

    tri = Triangulated(("B", "A"), np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 1.0]]))
    pts = tuple(GroundPoint(g, np.zeros(3), np.ones(3), Role.CHECK) for g in ("A", "C", "B"))
    found, X = tri.matched(pts)
    assert [p.id for p in found] == ["A", "B"] and X.tolist() == [[0, 0, 1], [1, 2, 3]]
    st = check_stats(tri, pts)
    assert st.count == 2 and st.rmse_z == pytest.approx(np.sqrt(5.0)) and st.max_3d == pytest.approx(np.sqrt(14.0))
    assert check_stats(tri, pts[1:2]) is None


@pytest.mark.parametrize("args, match", [
    (["rosetta", "--lines", "0:2", "--positions", "0:2"], "not a UAV twin"),
    (["mappilot", "--lines", "0:99", "--positions", "0:2"], "outside the twin's 15 lines x 33 positions"),
])
def test_subblock_script_bad_input_is_one_line(tmp_path, args, match):
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    cmd = [sys.executable, str(root / "scripts" / "twin_subblock.py"), args[0], str(tmp_path / "out"), *args[1:]]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=root, env={**os.environ, "PYTHONPATH": str(root)})
    assert r.returncode == 2 and match in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert not (tmp_path / "out").exists()
