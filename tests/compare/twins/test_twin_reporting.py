"""The twins in the reports: index columns, the README's "what changed with scale" and done-when
lines, per-stage provenance and keypoint counts. Fixture tables only (no twin is run here)."""

from __future__ import annotations

import copy
import json
import re
import sqlite3

import numpy as np
import pytest
from test_report_build import _method, synthetic_metrics

from polarref.compare.twins import scale as PS
from polarref.compare.twins import readme as PR
from polarref.compare.twins import tables as PT
from polarref.sfm.feature_cache import mean_keypoints
from polarref.compare.run import jobs
from polarref.compare.twins import pipeline as twins
from polarref.core.status import RunStatus
from polarref.model.run import MethodRun
from polarref.compare.report.index import build_index
from polarref.core.errors import PolarrefError


def _ok(name, minutes, ties, obs, registered=631, rot=0.1, images=631):
    return PT.TwinRow(name, RunStatus.OK, "", images, registered, 0.4, minutes, ties, obs, rot, 1e-4,
                           {"features": 60.0, "bundle adjustment": minutes * 30}, 900.0)


def _rosetta(**kw) -> PT.TwinTable:
    methods = {PT.BASELINE: _ok(PT.BASELINE, 60.0, 120_000, 600_000, rot=0.12),
               PT.OURS: _ok(PT.OURS, 40.0, 120_500, 602_000, rot=0.10),            # x1.50, more of both
               "pycolmap-incremental-sift": _ok("pycolmap-incremental-sift", 30.0, 50_000, 200_000, 600, 0.40),
               "pycolmap-global-sift": PT.TwinRow("pycolmap-global-sift", RunStatus.FAILED, "mapping: no model", 631)}
    methods.update(kw)
    return PT.TwinTable("rosetta", 631, 4710, methods)


def _small_metrics(euclid_s, polar_s, tp, rp, pyc_tp, rot_polar, rot_pyc, registered=12) -> dict:
    """A committed-report stand-in with known values (pycolmap incremental succeeded)."""
    data = copy.deepcopy(synthetic_metrics())
    data["methods"][2] = _method("pycolmap-incremental-sift", "pycolmap incremental", np.random.default_rng(1))
    (eu, po, pc) = data["methods"]
    eu["runtime_s"], po["runtime_s"] = euclid_s, polar_s
    eu["metrics"].update(tie_points=tp[0], reprojected_px=rp[0])
    po["metrics"].update(tie_points=tp[1], reprojected_px=rp[1], registered_images=registered)
    pc["metrics"].update(tie_points=pyc_tp)
    po["gt"]["rotation_error_deg_mean"], pc["gt"]["rotation_error_deg_mean"] = rot_polar, rot_pyc
    data["claims"][0]["verdict"] = "not supported"
    return data


def _reports(tmp_path, tables: dict, small: dict | None = None):
    root = tmp_path / "reports"
    for name, data in (small or {}).items():
        (root / name).mkdir(parents=True)
        (root / name / "metrics.json").write_text(json.dumps(data))
    for t in tables.values():
        PT.write_table(root / "paper-tables" / t.twin, t)
    PR.write_readme(root / "paper-tables")
    return root


def _row(md: str, label: str) -> list[str]:
    line = next(x for x in md.splitlines() if x.startswith(f"| {label} |"))
    return [c.strip() for c in line.split("|")[2:-1]]


# ---- the index: one column per twin with a table ------------------------------------------------

def test_index_has_a_column_per_twin_table_and_links_the_readme(tmp_path):
    root = _reports(tmp_path, {"rosetta": _rosetta()}, {"comet-small": synthetic_metrics()})
    build_index(root)
    md = (root / "index.md").read_text()
    header = next(x for x in md.splitlines() if x.startswith("| # | claim |"))
    assert header == "| # | claim | comet-small | rosetta twin |"    # no column for twins without a table
    assert _row(md, "C4")[1:] == ["inconclusive", "supported"]       # the report's own / the twin's x1.50
    c5 = next(x for x in md.splitlines() if x.startswith("| C5 |"))
    assert c5.endswith("| — | supported |")                            # the report has no C5 claim
    assert "[paper-tables/README.md](paper-tables/README.md)" in md
    assert "No table yet (no column): poets-park, mappilot." in md
    assert '<a href="paper-tables/README.md">' in (root / "index.html").read_text()


def test_index_twin_column_follows_the_table_and_says_not_tested(tmp_path):
    same = _ok(PT.OURS, 60.0, 120_000, 600_000)                         # polar == Euclidean: both fail
    root = _reports(tmp_path, {"rosetta": _rosetta(**{PT.OURS: same}),
                               "mappilot": PT.TwinTable("mappilot", 493, None, {})}, {"comet-small": synthetic_metrics()})
    build_index(root)
    md = (root / "index.md").read_text()
    assert _row(md, "C4")[1:] == ["inconclusive", "not supported", "not tested"]
    assert _row(md, "C5")[1:] == ["—", "not supported", "not tested"]
    (root / "paper-tables" / "mappilot" / "paper-table.json").write_text("{")
    build_index(root)
    md = (root / "index.md").read_text()
    assert "mappilot twin" not in md and "Unreadable: `paper-tables/mappilot`" in md


def test_index_without_twin_tables_is_unchanged(tmp_path):
    root = tmp_path / "reports"
    (root / "comet-small").mkdir(parents=True)
    (root / "comet-small" / "metrics.json").write_text(json.dumps(synthetic_metrics()))
    build_index(root)
    md = (root / "index.md").read_text()
    assert "twin" not in md and "| # | claim | comet-small |" in md


# ---- README: what changed with scale, done-when ---------------------------------------------------

def test_what_changed_with_scale_sets_the_twin_beside_the_small_scenes(tmp_path):
    small = _small_metrics(10.0, 10.5, (1000, 1000), (5000, 5000), 800, 0.15, 0.45, registered=11)
    root = _reports(tmp_path, {"rosetta": _rosetta()}, {"comet-small": small})
    text = (root / "paper-tables" / "README.md").read_text()
    sec = text.split("## What changed with scale")[1].split("### `rosetta`")[1]
    header = next(x for x in sec.splitlines() if x.startswith("| |"))
    assert header == "| | twin `rosetta` (631 views) | `comet-small` (12 views) | with scale |"  # comet-default absent
    assert _row(sec, "C4, single-run rule (polar vs Euclidean)") == ["supported", "not supported", "changed (small: not supported; twin: supported)"]
    assert _row(sec, "C5, single-run rule (polar vs Euclidean)") == ["supported", "not supported", "changed (small: not supported; twin: supported)"]
    assert _row(sec, "C4 / C5 in the report's scorecard (controlled experiments decide where they ran)")[1] == "not supported / not tested"
    assert _row(sec, "whole-method time, ours-polar / ours-euclidean")[:2] == ["x0.67", "x1.05"]
    assert _row(sec, "tie points, ours-polar / pycolmap incremental")[:2] == ["x2.41", "x1.25"]
    assert _row(sec, "GT rotation error (deg), ours-polar vs pycolmap incremental")[:2] == ["0.100 vs 0.400", "0.150 vs 0.450"]
    assert _row(sec, "registered views, ours-polar / pycolmap incremental")[:2] == ["100.0% / 95.1%", "91.7% / 100.0%"]
    # The UAV twins have no results here: no section, and the three paper tables still say "not run".
    assert "### `mappilot`" not in text and "### `poets-park`" not in text


def test_scale_verdicts_unchanged_and_missing_small_reports(tmp_path):
    same = _ok(PT.OURS, 60.0, 120_000, 600_000)
    small = _small_metrics(10.0, 10.0, (1000, 1000), (5000, 5000), 800, 0.15, 0.45)
    uav = PT.TwinTable("mappilot", 493, 3000, {PT.BASELINE: _ok(PT.BASELINE, 30.0, 1, 2, 493, images=493)})
    root = _reports(tmp_path, {"rosetta": _rosetta(**{PT.OURS: same}), "mappilot": uav},
                    {"comet-small": small, "comet-default": small})
    text = (root / "paper-tables" / "README.md").read_text()
    ros = text.split("### `rosetta`")[1].split("### ")[0]
    assert _row(ros, "C4, single-run rule (polar vs Euclidean)") == ["not supported"] * 3 + ["unchanged"]
    mp = text.split("### `mappilot`")[1]
    assert _row(mp, "C4, single-run rule (polar vs Euclidean)") == ["not tested", "not tested"]
    assert _row(mp, "whole-method time, ours-polar / ours-euclidean")[0] == "not tested"
    assert "no committed small-scene report of the uav class (reports/uav-small, reports/uav-default): not tested" in mp


def _done(table) -> dict[str, str]:
    return {line.split(":")[0]: re.search(r"\*\*(.+)\*\*$", line).group(1) for line in PS.done_when(table)}


def test_done_when_lines_are_met_not_met_or_not_tested():
    ok = _done(_rosetta())
    assert ok["- ours registers >= 99% of the views"] == "met"
    assert ok["- ours yields >= 100,000 tie points"] == "met"
    assert ok["- runtime per method, render excluded, <= 60 min"] == "not met"   # global failed
    line = PS.done_when(_rosetta())[2]
    assert "ours-euclidean 60.0 min" in line and "pycolmap-global-sift failed" in line
    # 625/631 = 99.05 % is enough, 624/631 = 98.9 % is not; 99,999 tie points are not 100,000.
    edge = _done(_rosetta(**{PT.OURS: _ok(PT.OURS, 40.0, 100_000, 602_000, registered=625),
                             PT.BASELINE: _ok(PT.BASELINE, 60.5, 99_999, 600_000, registered=631),
                             "pycolmap-global-sift": _ok("pycolmap-global-sift", 20.0, 40_000, 100_000)}))
    assert edge["- ours registers >= 99% of the views"] == "met"
    assert edge["- ours yields >= 100,000 tie points"] == "not met"
    assert edge["- runtime per method, render excluded, <= 60 min"] == "not met"     # 60.5 min
    low = _done(_rosetta(**{PT.OURS: _ok(PT.OURS, 40.0, 120_000, 602_000, registered=624)}))
    assert low["- ours registers >= 99% of the views"] == "not met"
    # A method that did not run is not tested (never a fake pass), unless another already fails.
    missing = _rosetta(**{"pycolmap-global-sift": PT.TwinRow("pycolmap-global-sift")})
    assert _done(missing)["- runtime per method, render excluded, <= 60 min"] == "not tested"
    blank = _done(PT.TwinTable("mappilot", 493, None, {}))
    assert set(blank.values()) == {"not tested"} and len(blank) == 2   # no tie-point target off rosetta


# ---- per-stage provenance and keypoints --------------------------------------------------------

def test_stage_records_name_their_commit_and_old_records_still_resume(tmp_path, monkeypatch):
    from polarref.core import isolated as runner
    from polarref.core.isolated import JobOutcome
    from polarref.core.provenance import git_state

    calls = []

    def fake(job, kwargs, timeout_s, work_dir, tag, reuse=False):
        calls.append(tag)
        return JobOutcome("ok", "", 1.5, MethodRun(stage_runtime_s={"features": 1.0}, peak_rss_mb=10.0, feature_file="x.npz"))

    monkeypatch.setattr(runner, "run_isolated", fake)
    st = twins._Stages(tmp_path, 60.0)
    rec = st.run("ours-features", jobs.ours_features, {})
    commit, dirty = git_state()
    assert rec.git_commit == commit and len(commit) == 40 and rec.git_dirty == dirty
    assert json.loads((tmp_path / "stages" / "ours-features.json").read_text())["result"]["feature_file"] == "x.npz"
    old = {"stage": "ours-polar", "status": "ok", "reason": "", "wall_s": 9.0, "result": {}, "finished_utc": "x"}
    (tmp_path / "stages" / "ours-polar.json").write_text(json.dumps(old))
    resumed = st.run("ours-polar", jobs.ours_sfm, {})
    assert resumed == twins.StageRecord("ours-polar", RunStatus.OK, "", 9.0, MethodRun(), "x") \
        and calls == ["ours-features"]   # resumed, not rerun
    assert PT.stage_commit(resumed) == "not recorded"
    assert PT.stage_commit(rec).startswith(commit[:10])


def test_mean_keypoints_from_our_feature_cache_and_a_colmap_database(tmp_path):
    from polarref.sfm.features import Features, save

    counts = [10, 20, 33]
    feats = [Features(f"{i}.png", 64, 48, np.zeros((n, 2)), np.zeros((n, 128), np.float32), np.ones(n),
                      np.zeros(n), np.zeros((n, 3), np.uint8)) for i, n in enumerate(counts)]
    save(tmp_path / "features-abc.npz", feats)
    assert mean_keypoints(tmp_path / "features-abc.npz") == pytest.approx(21.0)
    assert mean_keypoints(tmp_path / "none.npz") is None
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    assert mean_keypoints(tmp_path / "bad.npz") is None
    # Which cache file: the one the stage recorded; for old records every one in the cache if they agree.
    save(tmp_path / "features-def.npz", feats[:1])
    recorded = str(tmp_path / "features-def.npz")
    assert twins.ours_mean_keypoints(recorded, tmp_path) == pytest.approx(10.0)
    (tmp_path / "features-def.npz").unlink()
    assert twins.ours_mean_keypoints("", tmp_path) == pytest.approx(21.0)
    save(tmp_path / "features-ghi.npz", feats[::-1])                 # same counts, other order: agree
    assert twins.ours_mean_keypoints("", tmp_path) == pytest.approx(21.0)
    save(tmp_path / "features-def.npz", feats[:1])
    assert twins.ours_mean_keypoints("", tmp_path) is None    # they disagree: not recorded

    db = tmp_path / "database.db"
    con = sqlite3.connect(db)
    con.execute("CREATE TABLE keypoints (image_id INTEGER PRIMARY KEY, rows INTEGER, cols INTEGER, data BLOB)")
    con.executemany("INSERT INTO keypoints VALUES (?, ?, 6, NULL)", [(1, 4000), (2, 3000), (3, 2600)])
    con.commit()
    con.close()
    assert twins.mean_keypoints_db(db) == pytest.approx(3200.0)
    assert sorted(p.name for p in tmp_path.glob("database.db*")) == ["database.db"]   # nothing left beside it
    wal = tmp_path / "wal.db"   # a writer in WAL mode still open: its uncommitted-to-file rows count too
    live = sqlite3.connect(wal)
    live.execute("PRAGMA journal_mode=WAL")
    live.execute("CREATE TABLE keypoints (image_id INTEGER PRIMARY KEY, rows INTEGER, cols INTEGER, data BLOB)")
    live.executemany("INSERT INTO keypoints VALUES (?, ?, 6, NULL)", [(1, 10), (2, 30)])
    live.commit()
    assert twins.mean_keypoints_db(wal) == pytest.approx(20.0)
    live.close()
    assert twins.mean_keypoints_db(tmp_path / "missing.db") is None
    (tmp_path / "empty.db").write_bytes(b"")
    assert twins.mean_keypoints_db(tmp_path / "empty.db") is None    # no keypoints table


# ---- pipeline variants beside a twin's table ----------------------------------------------------

def _variant(ties: int, target=100_000) -> dict:
    """A record as scripts/twin_variant.py writes it (the fields the README reads)."""
    side = {"registered": 631, "reprojected_px": 1_000_000, "rotation_error_deg": 0.01}
    return {"twin": "rosetta", "method": "ours-euclidean", "images": 631,
            "variant_settings": {"track_conflicts": "split"}, "baseline_settings": {"track_conflicts": "drop"},
            "variant": {**side, "tie_points": ties, "mean_reprojection_error_px": 0.34},
            "baseline": {**side, "tie_points": 99_321, "mean_reprojection_error_px": 0.28},
            "tie_point_target": target, "provenance": {"git_commit": "e498bb0e07" + "0" * 30}}


def test_readme_lists_variants_with_their_own_verdict_and_keeps_the_tables_check(tmp_path):
    root = _reports(tmp_path, {"rosetta": _rosetta(**{
        PT.BASELINE: _ok(PT.BASELINE, 50.0, 99_321, 600_000), PT.OURS: _ok(PT.OURS, 55.0, 99_277, 600_000)})})
    twin = root / "paper-tables" / "rosetta"
    (twin / "variant-a-split.json").write_text(json.dumps(_variant(119_860)))
    (twin / "variant-b-split.json").write_text(json.dumps(_variant(99_999)))
    PR.write_readme(root / "paper-tables")
    ros = (root / "paper-tables" / "README.md").read_text().split("### `rosetta`")[1]
    assert "- ours yields >= 100,000 tie points: ours-euclidean 99,321, ours-polar 99,277: **not met**" in ros
    lines = [x for x in ros.splitlines() if x.startswith("- variant of ")]
    assert len(lines) == 2
    assert "119,860 tie points" in lines[0] and "99,321" in lines[0] and lines[0].endswith("**met**")
    assert "99,999 tie points" in lines[1] and lines[1].endswith("**not met**")
    assert "commit e498bb0" in lines[0] and "track_conflicts = split" in lines[0]
    # a variant without a target (another twin) gets no verdict; a broken record is one clear error
    (twin / "variant-b-split.json").write_text(json.dumps(_variant(50_000, target=None)))
    assert "**" not in PS.variant_lines(twin)[1]
    (twin / "variant-c.json").write_text("{not json")
    with pytest.raises(PolarrefError, match="variant-c.json: not a pipeline-variant record"):
        PS.variant_lines(twin)
