"""The paper-layout tables of the twins: values, the difference column, "not run" for a missing
method (never 0), C4/C5 on one run, and the README beside the paper's printed Tables 1-3."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from _scripts import load_script

from polarref.compare.twins import scale as PS
from polarref.compare.twins import readme as PR
from polarref.compare.twins import tables as PT
from polarref.core import records
from polarref.core.status import RunStatus


def _ok(name, acc, minutes, ties, obs, ba_s):
    return PT.TwinRow(name, RunStatus.OK, "", 631, 631, acc, minutes, ties, obs, 0.01, 1e-4,
                           {"features": 100.0, "bundle adjustment": ba_s}, 900.0)


def _table(**methods):
    return PT.TwinTable("rosetta", 631, 7000, methods)


def test_paper_layout_with_a_missing_method_shows_not_run(tmp_path):
    t = _table(**{PT.BASELINE: _ok(PT.BASELINE, 0.400, 50.0, 100_000, 500_000, 600.0),
                  PT.OURS: _ok(PT.OURS, 0.404, 40.0, 100_500, 502_000, 300.0),
                  "pycolmap-global-sift": PT.TwinRow("pycolmap-global-sift", RunStatus.FAILED, "mapping: no model", 631)})
    PT.write_table(tmp_path / "rosetta", t)
    md = (tmp_path / "rosetta" / "paper-table.md").read_text()
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
            for line in md.splitlines() if line.startswith("| ")}
    assert rows["Accuracy (px)"] == ["0.400", "0.404", "equivalent"]  # |0.004| <= max(0.005, 2%)
    assert rows["Efficiency (min)"] == ["50.0", "40.0", "-10.0 min (x1.25)"]
    assert rows["#Tie point"] == ["100,000", "100,500", "+500"]
    assert rows["#Reprojected px"] == ["500,000", "502,000", "+2,000"]
    inc = rows["pycolmap incremental (its SIFT)"]
    assert inc[0] == "not run" and "not run" in inc[2:7] and "0" not in inc[2:7]
    glob = rows["pycolmap global (its SIFT)"]
    assert glob[0].startswith("failed (mapping: no model)") and glob[3] == "failed"
    # C4 by the scorecard's whole-method rule: x1.25 lies between x1.10 and x1.26 (the BA alone is x2.00,
    # reported beside it); C5 with the scorecard margin (0.1% of 100,000 = 100 < 500, of 500,000 = 500 < 2,000).
    v = PT.verdicts(t)
    assert v.c4.verdict == "inconclusive"
    assert v.c4.values["speedup"] == pytest.approx(1.25) and v.c4.values["ba_speedup"] == pytest.approx(2.0)
    assert "speed-up Euclidean/polar x1.25" in str(v.c4) and "BA time Euclidean/polar x2.00" in str(v.c4)
    assert str(v.c5).startswith("supported (+500 tie points (margin 100), +2,000 reprojected px (margin 500)")
    assert f"C4 (faster): {v.c4}" in md
    back = PT.TwinTable.from_dict(json.loads((tmp_path / "rosetta" / "paper-table.json").read_text()))
    assert back.methods[PT.OURS].tie_points == 100_500 and back.methods["pycolmap-global-sift"].status == RunStatus.FAILED


def test_difference_column_is_not_tested_without_both_sides_and_detects_a_real_change():
    base = _ok(PT.BASELINE, 0.400, 50.0, 100_000, 500_000, 600.0)
    worse = _ok(PT.OURS, 0.450, 60.0, 99_950, 499_000, 900.0)
    assert PT.difference("accuracy_px", base, worse) == "+0.050 px"
    assert PT.difference("tie_points", base, None) == "not tested"
    v = PT.verdicts(_table(**{PT.BASELINE: base, PT.OURS: worse}))
    assert v.c4.verdict == "not supported" and v.c4.values["speedup"] == pytest.approx(50 / 60)
    assert str(v.c5).startswith("not supported (-50 tie points")
    assert {k: str(x) for k, x in PT.verdicts(_table(**{PT.BASELINE: base})).by_claim()} == {
        "C4": "not tested", "C5": "not tested"}


def test_readme_puts_the_papers_tables_beside_the_twins(tmp_path):
    t = _table(**{PT.BASELINE: _ok(PT.BASELINE, 0.4, 50.0, 100_000, 500_000, 600.0)})
    PT.write_table(tmp_path / "rosetta", t)
    text = PR.write_readme(tmp_path).read_text()
    table1 = text.split("## Table 1")[1].split("## Table 2")[0]
    assert "| Accuracy (px) | 0.482 | 0.481 | 0.400 | not run | not tested |" in table1
    assert "| #Tie point | 200,355 | 200,708 | 100,000 | not run | not tested |" in table1
    table3 = text.split("## Table 3")[1]
    assert "| Efficiency (min) | 164.1 | 125.4 | not run | not run | not tested |" in table3
    assert "C4 on the twin: not tested" in table3


def test_the_baseline_against_itself_fails_both_success_rules():
    base = _ok(PT.BASELINE, 0.400, 50.0, 100_000, 500_000, 600.0)
    v = PT.verdicts(_table(**{PT.BASELINE: base, PT.OURS: dataclasses.replace(base, name=PT.OURS)}))
    assert v.c4.verdict == "not supported" and v.c4.values["speedup"] == pytest.approx(1.0)
    assert v.c5.verdict == "not supported" and v.c5.values == {"tie_points": 0, "reprojected_px": 0}


def test_a_constructed_faster_polar_run_with_more_tie_points_passes_both():
    base = _ok(PT.BASELINE, 0.400, 60.0, 100_000, 500_000, 900.0)
    ours = _ok(PT.OURS, 0.401, 40.0, 100_300, 501_200, 300.0)   # x1.50 overall, x3.00 in BA
    v = PT.verdicts(_table(**{PT.BASELINE: base, PT.OURS: ours}))
    assert v.c4.verdict == "supported"
    assert 1.49 < v.c4.values["speedup"] < 1.51 and 2.99 < v.c4.values["ba_speedup"] < 3.01
    assert v.c5.verdict == "supported" and v.c5.values == {"tie_points": 300, "reprojected_px": 1200}


@pytest.mark.parametrize("polar_min, verdict", [
    (60 / 1.27, "supported"),        # x1.27 >= 1.4 x 0.9 = 1.26
    (60 / 1.25, "inconclusive"),     # just below 1.26
    (60 / 1.11, "inconclusive"),     # just above 1.10
    (60 / 1.09, "not supported"),    # below 1 + 10 % slack
    (90.0, "not supported"),         # slower
])
def test_c4_thresholds_on_a_twin_are_the_scorecards(polar_min, verdict):
    base = _ok(PT.BASELINE, 0.4, 60.0, 100, 500, 600.0)
    v = PT.verdicts(_table(**{PT.BASELINE: base, PT.OURS: _ok(PT.OURS, 0.4, polar_min, 100, 500, 600.0)}))
    assert v.c4.verdict == verdict
    assert v.c4.values["speedup"] == pytest.approx(60.0 / polar_min)


@pytest.mark.parametrize("ties, obs, verdict", [
    (100_101, 500_501, "supported"),       # both above max(1, 0.1 %) = 100 / 500
    (100_100, 500_501, "not supported"),   # tie points exactly at the margin: not more
    (100_101, 500_500, "not supported"),   # reprojected px at the margin
    (100_500, 499_000, "not supported"),   # more tie points, fewer observations: both are needed
    (None, 500_600, "not tested"),         # a missing count is never 0
])
def test_c5_needs_both_counts_above_the_scorecards_margin(ties, obs, verdict):
    base = _ok(PT.BASELINE, 0.4, 60.0, 100_000, 500_000, 600.0)
    v = PT.verdicts(_table(**{PT.BASELINE: base, PT.OURS: _ok(PT.OURS, 0.4, 60.0, ties, obs, 600.0)}))
    assert v.c5.verdict == verdict


def test_missing_values_are_not_tested():
    base = _ok(PT.BASELINE, 0.4, 60.0, 100_000, 500_000, 600.0)
    no_time = dataclasses.replace(_ok(PT.OURS, 0.4, 40.0, 100_500, 502_000, 300.0), efficiency_min=None)
    v = PT.verdicts(_table(**{PT.BASELINE: base, PT.OURS: no_time}))
    assert v.c4.verdict == "not tested" and v.c4.figures == "" and v.c5.verdict == "supported"
    failed = PT.TwinRow(PT.OURS, RunStatus.TIMEOUT, "ours-polar: over 14400 s", 631)
    assert {k: x.verdict for k, x in PT.verdicts(_table(**{PT.BASELINE: base, PT.OURS: failed})).by_claim()} == {
        "C4": "not tested", "C5": "not tested"}
    assert {k: x.verdict for k, x in PT.verdicts(None).by_claim()} == {"C4": "not tested", "C5": "not tested"}


def test_no_second_copy_of_the_scorecards_thresholds():
    from polarref.compare.claims import single_run
    from polarref.compare.claims import thresholds

    for name in ("TIE_MARGIN_REL", "ACCURACY_MARGIN_ABS", "ACCURACY_MARGIN_REL", "SPEEDUP_CLAIM"):
        assert not hasattr(PT, name)
    assert single_run.SUPPORTED_AT == pytest.approx(thresholds.SPEEDUP_CLAIM * (1 - thresholds.TIMING_SLACK))


def test_stage_provenance_is_listed_and_old_records_say_not_recorded(tmp_path):
    t = _table(**{PT.BASELINE: _ok(PT.BASELINE, 0.4, 50.0, 100_000, 500_000, 600.0)})
    t.provenance = PT.TwinProvenance(commit="f" * 40, stages={
        "ours-features": PT.StageProvenance("", None, "2026-12-01T20:00:00Z"),
        "ours-euclidean": PT.StageProvenance("0123456789abcdef" + "0" * 24, True)})
    PT.write_table(tmp_path / "rosetta", t)
    md = (tmp_path / "rosetta" / "paper-table.md").read_text()
    assert "ours-euclidean 0123456789 (dirty); ours-features not recorded." in md
    back = PT.TwinTable.from_dict(json.loads((tmp_path / "rosetta" / "paper-table.json").read_text()))
    assert back.provenance.stages["ours-features"].finished_utc == "2026-12-01T20:00:00Z"
    # A table written before mean_keypoints existed still loads (the field defaults to unknown).
    old = json.loads((tmp_path / "rosetta" / "paper-table.json").read_text())
    del old["methods"][PT.BASELINE]["mean_keypoints"]
    assert PT.TwinTable.from_dict(old).methods[PT.BASELINE].mean_keypoints is None
    assert PT.stage_commit(PT.StageProvenance("a" * 40, False)) == "a" * 10


@pytest.mark.slow
def test_twin_comparison_runs_every_method_and_resumes(tmp_path):
    """A reduced mappilot twin through all four methods (~2 min), then a rerun that skips them all."""
    import dataclasses

    from polarref.compare.twins.pipeline import TwinRun, run_twin
    from synth.config import twin
    from synth.render import render_scene

    cfg = dataclasses.replace(twin("mappilot", width=320, height=240, spp=4), views=20)
    render_scene(cfg.scene, tmp_path / "scene", cfg)
    run = TwinRun("mappilot", str(tmp_path / "out"), scene_dir=str(tmp_path / "scene"), method_timeout_s=900,
                  tables_dir=str(tmp_path / "tables"))
    table = run_twin(run)
    for name in PT.METHODS:
        m = table.methods[name]
        assert m.status == RunStatus.OK, (name, m.reason)
        assert m.registered >= 19 and m.rotation_error_deg < 0.5 and m.tie_points > 1000
        assert m.peak_rss_mb > 50 and m.efficiency_min > 0
    stamps = {p.name: p.stat().st_mtime for p in (tmp_path / "out" / "stages").glob("*.json")}
    again = run_twin(run)
    assert {p.name: p.stat().st_mtime for p in (tmp_path / "out" / "stages").glob("*.json")} == stamps
    assert again.methods[PT.OURS].tie_points == table.methods[PT.OURS].tie_points
    # Every stage record names the code that ran it; the table lists them, and the keypoints per image.
    records = [f for f in (tmp_path / "out" / "stages").glob("*.json") if not f.name.endswith(".result.json")]
    assert len(records) == 6
    for f in records:   # (the <stage>.result.json beside them are the runner's job results)
        assert len(json.loads(f.read_text())["git_commit"]) == 40, f
    assert set(table.provenance.stages) == {"ours-features", "pycolmap-features", *PT.METHODS}
    for name in PT.METHODS:
        assert 100 < table.methods[name].mean_keypoints <= 4096, name   # both extract at most 4096
    readme = (tmp_path / "tables" / "README.md").read_text().split("## Table 3")[1]
    assert f"| #Tie point | 670,355 | 671,331 | {table.methods[PT.BASELINE].tie_points:,} |" in readme
    # The variant script with the tables' own setting reproduces the stage's model's figures
    # (same code, same caches), and refuses to overwrite its JSON.
    tv, tm = load_script("twin_variant"), load_script("twin_memory")
    out_json = tmp_path / "variant.json"
    assert tv.main([str(tmp_path / "out"), "euclidean", str(out_json), "--track-conflicts", "drop"]) == 0
    rec = json.loads(out_json.read_text())
    for key in ("registered", "tie_points", "reprojected_px"):
        assert rec["variant"][key] == rec["baseline"][key] == getattr(table.methods[PT.BASELINE], key), key
    assert rec["variant"]["rotation_error_deg"] == pytest.approx(rec["baseline"]["rotation_error_deg"], rel=1e-9)
    assert rec["target_met"] is None and len(rec["provenance"]["git_commit"]) == 40
    # the README's variant line reads the script's record as written (no target off rosetta)
    (tmp_path / "v").mkdir()
    (tmp_path / "v" / "variant-drop.json").write_text(out_json.read_text())
    (line,) = PS.variant_lines(tmp_path / "v")
    assert f"{rec['variant']['tie_points']:,} tie points" in line and "**" not in line
    assert tv.main([str(tmp_path / "out"), "euclidean", str(out_json), "--track-conflicts", "split"]) == 1
    assert tv.main([str(tmp_path / "nowhere"), "polar", str(tmp_path / "x.json"), "--track-conflicts", "split"]) == 1
    # The memory script's rerun reproduces the stage's model byte for byte.
    assert tm.main([str(tmp_path / "out"), "euclidean", str(tmp_path / "mem.json")]) == 0
    mem = json.loads((tmp_path / "mem.json").read_text())
    assert mem["model_identical_to_stage"] is True and mem["peak_rss_mb"] > 50


def test_committed_tables_read_strictly_and_rewrite_byte_for_byte():
    """The typed table (rows, provenance, stage commits) keeps the committed layout: each twin's
    paper-table.json and .md regenerate from the JSON unchanged; an unknown key is refused."""
    from polarref.core import records

    root = Path(__file__).parents[3] / "reports" / "paper-tables"
    tables = sorted(root.glob("*/paper-table.json"))
    assert len(tables) == 3
    for path in tables:
        data = json.loads(path.read_text())
        table = PT.TwinTable.from_dict(data)
        assert json.dumps(table.to_dict(), indent=1) + "\n" == path.read_text(), path
        assert PT.render_table(table) + "\n" == path.with_suffix(".md").read_text(), path
        assert table.provenance is not None and set(table.provenance.stages) >= set(PT.METHODS)
    data["provenance"]["extra"] = 1
    with pytest.raises(records.RecordError, match="extra"):
        PT.TwinTable.from_dict(data)


def test_rows_have_a_run_status_and_old_not_run_rows_read_as_skipped():
    """Rows carry RunStatus (issue 29); a table written with the old "not run" string reads back
    as SKIPPED and still prints "not run", a skipped stage with a reason prints "skipped"."""
    t = _table(**{PT.BASELINE: _ok(PT.BASELINE, 0.4, 50.0, 100_000, 500_000, 600.0)})
    old = t.to_dict()
    old["methods"][PT.OURS] = {"name": PT.OURS, "status": "not run"}
    back = PT.TwinTable.from_dict(old)
    assert back.methods[PT.OURS].status is RunStatus.SKIPPED
    assert back.methods[PT.BASELINE].status is RunStatus.OK
    assert PT.table_cell(back.methods[PT.OURS], "tie_points") == PT.NOT_RUN
    assert PT.status_text(PT.TwinRow(PT.OURS, RunStatus.SKIPPED, "features: failed")) == "skipped"
    with pytest.raises(records.RecordError):
        PT.TwinTable.from_dict(dict(old, methods={PT.OURS: {"name": PT.OURS, "status": "done"}}))
