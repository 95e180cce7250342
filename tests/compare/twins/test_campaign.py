"""The twin campaign: cells from one pinned clean commit, resumable, never mixed across commits,
and C4/C5 over the seeds against statistics computed here by hand."""

from __future__ import annotations

import dataclasses
import math
import subprocess

import pytest

from polarref.compare.twins import campaign as C
from polarref.compare.twins import campaign_records as R
from polarref.compare.twins import campaign_table as T
from polarref.compare.twins.campaign_jobs import StagedRun
from polarref.model.settings import MethodSettings
from polarref.core import records
from polarref.core.errors import PolarrefError
from polarref.core.provenance import Provenance
from polarref.core.status import RunStatus
from polarref.model.run import MethodRun
from polarref.model.scores import ReconstructionMetrics
from polarref.sfm.stages import StageCost

COMMIT = "c" * 40
T_975_2 = 4.302652729911275   # Student t, 0.975 quantile, 2 degrees of freedom (tables)
T_95_2 = 2.919985580355516    # Student t, 0.95 quantile, 2 degrees of freedom


def _env(commit=COMMIT, dirty=False):
    return Provenance(commit, dirty, 2, "cpu", "x86_64", "linux", "3.12", {}, {}, {})


RUNNER_FLOOR = 2200.0   # ru_maxrss of a spawned stage: the runner's peak, not the stage's (core/memory.py)


def _cell(method, seed, minutes, ties, obs, ba_s=None, commit=COMMIT, dirty=False, stage_commit=None, peak=None):
    run = MethodRun(method, model_dir="m", peak_rss_mb=RUNNER_FLOOR)
    settings = MethodSettings("ours", 2, 2, 4096, 0, False, "file")
    costs = (StageCost("tracks", 1.0, 1.0, 300.0), StageCost("mapping", 1.0, 1.0, peak or 500.0 + seed))
    stage = R.CellStage(method, False, RunStatus.OK, wall_s=60.0 * minutes, git_commit=stage_commit or commit,
                        git_dirty=dirty, result=StagedRun(run, costs, settings))
    metrics = ReconstructionMetrics(20, 20, ties, obs, 0.2, 0.2, 0.2, 3.0)
    prov = R.CellProvenance(commit, dirty, "host", "t0", "t1", (3.0, 2.0, 1.0), (5.0, 2.0, 1.0), {}, {}, _env(commit, dirty))
    return R.CampaignCell("mappilot", "tiny", seed, method, method, 20, 50, RunStatus.OK, "", 60.0 * minutes,
                          RUNNER_FLOOR, ba_s, 0.0, (stage,), metrics, prov)


def _plan(**kw):
    return C.CampaignPlan(COMMIT, ("mappilot",), (0, 1, 2), ("ours-euclidean", "ours-polar"), "tiny", **kw)


def _save(root, cell):
    path = C.cell_path(root, _plan(), cell.twin, cell.seed, cell.method)
    path.parent.mkdir(parents=True, exist_ok=True)
    records.save(cell, path)
    return path


def _three_seeds(root, polar_minutes=(10.0, 10.0, 10.0)):
    # speed-ups 1.2 exp(-0.1), 1.2, 1.2 exp(0.1): geometric mean 1.2, SD of the logs 0.1
    for seed, (k, pm) in enumerate(zip((-0.1, 0.0, 0.1), polar_minutes)):
        _save(root, _cell("ours-euclidean", seed, pm * 1.2 * math.exp(k), 1000, 5000, ba_s=100.0))
        _save(root, _cell("ours-polar", seed, pm, 1000 + (1, 2, 3)[seed], 5000 + (10, 20, 60)[seed], ba_s=120.0))


def test_c4_c5_over_seeds_match_hand_computed_statistics(tmp_path):
    _three_seeds(tmp_path)
    table = T.build(tmp_path / COMMIT)
    (tw,) = table.twins
    assert tw.twin == "mappilot-tiny" and table.cells == 6
    half = T_975_2 * 0.1 / math.sqrt(3)
    assert tw.c4.geometric_mean == pytest.approx(1.2, rel=1e-12)
    assert tw.c4.lo == pytest.approx(1.2 * math.exp(-half), rel=1e-9)
    assert tw.c4.hi == pytest.approx(1.2 * math.exp(half), rel=1e-9)
    # 0.94 - 1.54 straddles the scorecard's bar 1.4 x 0.9 = 1.26: inconclusive
    assert tw.c4.bar == pytest.approx(1.26) and tw.c4.verdict == "inconclusive"
    assert tw.c4.ba_ratios == pytest.approx((1.2, 1.2, 1.2)) and tw.c4.ba_target_met is True
    ties, obs = tw.c5
    # tie points +0.1 %, +0.2 %, +0.3 %: mean 0.2 %, SD 0.1 %, 90 % interval 0.2 +- t(0.95, 2) 0.1 / sqrt 3
    assert ties.mean == pytest.approx(0.002, rel=1e-9)
    assert ties.lo == pytest.approx(0.002 - T_95_2 * 0.001 / math.sqrt(3), rel=1e-9)
    assert ties.margin == pytest.approx(0.001) and ties.outcome == "unclear"
    # observations +0.2 %, +0.4 %, +1.2 %: mean 0.6 %, SD sqrt(0.28) %
    assert obs.mean == pytest.approx(0.006, rel=1e-9)
    assert obs.hi == pytest.approx(0.006 + T_95_2 * math.sqrt(0.28) * 0.01 / math.sqrt(3), rel=1e-9)
    assert tw.c5_verdict == "inconclusive"
    euc = next(m for m in tw.methods if m.key == "ours-euclidean")
    # a reduced size is a dry run: the twins' targets do not apply
    assert euc.median_min == pytest.approx(12.0) and euc.target_met is None and euc.target_min is None
    assert tw.peak_mb_max == 502.0 and tw.peak_target_met is None
    T.write(table, tmp_path)
    md = (tmp_path / "table.md").read_text()
    assert "**inconclusive**" in md and "x1.200" in md


def test_a_clear_speedup_is_supported_and_equal_counts_are_not():
    # speed-ups 1.5, 1.5 x 1.01, 1.5 / 1.01 -> interval well above 1.26; counts identical -> equal
    cells = {}
    for seed, k in enumerate((1.0, 1.01, 1 / 1.01)):
        cells[seed] = (_cell("ours-euclidean", seed, 15.0 * k, 1000, 5000, ba_s=100.0),
                       _cell("ours-polar", seed, 10.0, 1000, 5000, ba_s=140.0))
    pairs = [(s, b, c) for s, (b, c) in cells.items()]
    rr = T.rules()
    c4 = T.speedup_stats(pairs, rr)
    assert c4.verdict == "supported" and c4.lo > 1.26
    assert c4.ba_target_met is False            # 1.4 > the pre-registered 1.3
    c5 = (T.count_stats(pairs, "tie_points", 0.0018), T.count_stats(pairs, "reprojected_px", 0.0012))
    assert [s.outcome for s in c5] == ["equal", "equal"]   # interval [0, 0] inside +-0.1 %
    assert T.c5_verdict(c5, 3, rr) == "not supported"
    assert T.speedup_stats(pairs[:1], rr).verdict == "inconclusive"   # one seed never decides
    assert T.speedup_stats([], rr).verdict == "not tested"


def test_the_rules_are_the_preregistrations():
    rr = T.rules()
    assert rr.seeds == (0, 1, 2) and rr.min_paired_seeds == 2 and rr.ba_ratio_max == 1.3
    assert rr.minutes("rosetta", "ours-euclidean") == 15.0 and rr.minutes("rosetta", "ours-polar") == 18.0
    assert rr.minutes("mappilot", "pycolmap-global-sift") == 20.0 and rr.peak("poets-park") == 4096.0


@pytest.mark.parametrize("change", ["commit", "dirty", "stage"])
def test_a_table_refuses_cells_from_another_commit(tmp_path, change):
    _three_seeds(tmp_path)
    other = {"commit": dict(commit="d" * 40), "dirty": dict(dirty=True), "stage": dict(stage_commit="e" * 40)}[change]
    bad = _cell("ours-polar", 1, 10.0, 1001, 5001, **other)
    _save(tmp_path, bad)
    with pytest.raises(PolarrefError, match="one table holds one commit"):
        T.build(tmp_path / COMMIT)


def test_only_cells_without_a_result_are_todo(tmp_path):
    plan = _plan()
    assert len(C.todo(plan, tmp_path)) == 6
    _save(tmp_path, _cell("ours-polar", 1, 10.0, 1, 1))
    failed = dataclasses.replace(_cell("ours-euclidean", 2, 10.0, 1, 1), status=RunStatus.FAILED, reason="x")
    _save(tmp_path, failed)
    left = C.todo(plan, tmp_path)
    assert ("mappilot", 1, "ours-polar") not in left and ("mappilot", 2, "ours-euclidean") not in left
    assert ("mappilot", 2, "ours-euclidean") in C.todo(plan, tmp_path, retry_failed=True)
    # pycolmap's thread count names the cell: a 1-thread run is another cell
    p1 = C.CampaignPlan(COMMIT, ("mappilot",), (0,), ("pycolmap-incremental-sift",), "tiny", pycolmap_threads=1)
    assert C.cell_path(tmp_path, p1, "mappilot", 0, "pycolmap-incremental-sift").name == "pycolmap-incremental-sift-t1.json"


def test_cells_run_only_from_the_clean_pinned_checkout(tmp_path):
    with pytest.raises(PolarrefError, match="pinned"):
        C.check_checkout(COMMIT, ("d" * 40, False))
    with pytest.raises(PolarrefError, match="pinned"):
        C.check_checkout(COMMIT, (COMMIT, True))
    C.check_checkout(COMMIT, (COMMIT, False))
    with pytest.raises(PolarrefError, match="pinned"):
        C.run_campaign(_plan(), tmp_path / "cells", tmp_path / "work", state=(COMMIT, None))
    with pytest.raises(PolarrefError):
        C.CampaignPlan("abc", ("mappilot",), (0,))


def test_kernels_compile_before_the_first_cell_of_ours_only(tmp_path, monkeypatch):
    """The first cell's BA times must not include compiling the kernels into the worktree's cache:
    the warm-up runs once, before the first render, when one of our methods is to run."""
    calls = []

    class Stop(Exception):
        pass

    def render(*a, **k):
        calls.append("render")
        raise Stop

    monkeypatch.setattr(C.kernels, "warm_up", lambda: calls.append("warm") or 0.0)
    monkeypatch.setattr(C, "render_twin", render)
    for methods, expected in ((("ours-polar", "pycolmap-global-sift"), ["warm", "render"]),
                              (("pycolmap-global-sift",), ["render"])):
        calls.clear()
        plan = dataclasses.replace(_plan(), methods=methods)
        with pytest.raises(Stop):
            C.run_campaign(plan, tmp_path / "cells", tmp_path / "work", state=(COMMIT, False))
        assert calls == expected
    calls.clear()
    _save(tmp_path / "cells2", _cell("ours-polar", 0, 5.0, 10, 20))
    plan = dataclasses.replace(_plan(), seeds=(0,), methods=("ours-polar",))
    assert C.run_campaign(plan, tmp_path / "cells2", tmp_path / "work", state=(COMMIT, False)) == []
    assert calls == []                                   # nothing to run: nothing compiled


def test_the_pinned_commit_is_checked_out_into_a_clean_worktree(tmp_path):
    repo = tmp_path / "repo"
    repo.mkdir()
    git = lambda *a, cwd=repo: subprocess.run(["git", *a], cwd=cwd, check=True, capture_output=True, text=True).stdout
    git("init", "-q")
    (repo / "f.txt").write_text("one\n")
    git("add", "f.txt")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "one")
    first = git("rev-parse", "HEAD").strip()
    (repo / "f.txt").write_text("two\n")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qam", "two")
    tree = C.ensure_worktree(repo, first[:8], tmp_path / "src")
    assert (tree / "f.txt").read_text() == "one\n" and git("rev-parse", "HEAD", cwd=tree).strip() == first
    assert C.ensure_worktree(repo, first, tmp_path / "src") == tree      # made once, reused
    (tree / "f.txt").write_text("changed\n")
    with pytest.raises(PolarrefError, match="not a clean checkout"):
        C.ensure_worktree(repo, first, tmp_path / "src")


@pytest.mark.slow
def test_a_tiny_campaign_runs_resumes_and_tabulates(tmp_path):
    """Two seeds of a tiny mappilot through both BAs and pycolmap incremental (2 threads); the second
    call reruns nothing; the table's C4 is the cells' own times (~5 min on the shared machine)."""
    from polarref.core.provenance import git_state

    head, _ = git_state()
    plan = C.CampaignPlan(head, ("mappilot",), (0, 1), ("ours-euclidean", "ours-polar", "pycolmap-incremental-sift"),
                          "tiny", timeout_s=1200)
    cells = tmp_path / "cells"
    written = C.run_campaign(plan, cells, tmp_path / "work", state=(head, False))
    assert len(written) == 6
    for p in written:
        cell = R.read_cell(p)
        assert cell.status == RunStatus.OK, (p, cell.reason)
        assert cell.provenance.commit == head and cell.provenance.dirty is False
        assert cell.metrics.registered_images >= 12 and cell.metrics.gt.rotation_error_deg_mean < 0.5
        shared, own = cell.stages
        assert shared.shared and not own.shared and cell.wall_s == pytest.approx(shared.wall_s + own.wall_s)
        assert own.result.settings.max_num_features == 4096 and own.result.settings.parallel == 2
        assert all(s.peak_rss_mb and s.cpu_s is not None for s in shared.result.stages)
    euc = R.read_cell(C.cell_path(cells, plan, "mappilot", 1, "ours-euclidean"))
    pol = R.read_cell(C.cell_path(cells, plan, "mappilot", 1, "ours-polar"))
    assert euc.stages[0].reused is False and pol.stages[0].reused is True   # one front end per (twin, seed)
    assert pol.stages[0].wall_s == euc.stages[0].wall_s                      # counted in both
    assert {s.stage for s in pol.stages[1].result.stages if s.cached} >= {"features", "matching"}
    stamps = {p: p.stat().st_mtime for p in written}
    assert C.run_campaign(plan, cells, tmp_path / "work", state=(head, False)) == []
    assert {p: p.stat().st_mtime for p in written} == stamps
    (tw,) = T.build(cells / head).twins
    ratios = [R.read_cell(C.cell_path(cells, plan, "mappilot", s, "ours-euclidean")).wall_s
              / R.read_cell(C.cell_path(cells, plan, "mappilot", s, "ours-polar")).wall_s for s in (0, 1)]
    assert tw.c4.geometric_mean == pytest.approx(math.sqrt(ratios[0] * ratios[1]), rel=1e-12)
    assert tw.c4.seeds == (0, 1) and len(tw.methods) == 3


def test_settings_of_both_pycolmap_mappers_flatten_to_json():
    """pycolmap's global options hold arrays (the first campaign's global cells failed on them)."""
    import json

    pytest.importorskip("pycolmap")
    from polarref.compare.twins.campaign_jobs import _colmap_settings
    from polarref.peers.colmap_sfm import ColmapSfMOptions

    for mapper, ignore in (("incremental", True), ("global", False)):
        s = _colmap_settings(ColmapSfMOptions(num_threads=2, max_num_features=4096), mapper, "file: p.txt")
        assert s.parallel == 2 and s.max_num_features == 4096 and s.ignore_two_view_tracks is ignore
        assert all(json.loads(x.value) is not None or x.value == "null" for x in s.options) and len(s.options) > 50


def test_memory_target_judges_our_pipeline_not_the_peer(tmp_path):
    """A peer's larger peak stays in its own row; the twin's peak (and its target) is ours."""
    _three_seeds(tmp_path)
    _save(tmp_path, _cell("pycolmap-global-sift-t2", 0, 5.0, 900, 4000, peak=9000.0))
    (tw,) = T.build(tmp_path / COMMIT).twins
    assert tw.peak_mb_max == 502.0
    assert next(m for m in tw.methods if m.key.startswith("pycolmap")).peak_mb == 9000.0


def test_a_stage_peak_is_its_sampled_stages_not_the_inherited_ru_maxrss():
    """Stage peaks come from the sampled pipeline stages (process plus workers); the record's own
    figure only where nothing was sampled (a stage that failed before its first clock)."""
    cell = _cell("ours-polar", 1, 10.0, 1000, 5000)
    assert R.stage_peak_mb(cell.stages[0]) == 501.0 and cell.largest_stage_mb == 501.0
    assert cell.peak_rss_mb == RUNNER_FLOOR  # what such a cell recorded
    (stage,) = cell.stages
    workers = dataclasses.replace(stage, result=dataclasses.replace(
        stage.result, stages=(StageCost("features", 1.0, 1.0, 200.0, 450.0), StageCost("mapping", 1.0, 1.0, 600.0))))
    assert R.stage_peak_mb(workers) == 650.0
    unsampled = dataclasses.replace(stage, result=dataclasses.replace(stage.result, stages=(StageCost("total", 1.0),)))
    assert R.stage_peak_mb(unsampled) == RUNNER_FLOOR
    assert R.stage_peak_mb(dataclasses.replace(stage, result=None)) is None
    two = dataclasses.replace(cell, stages=(workers, stage))
    assert two.largest_stage_mb == 650.0
