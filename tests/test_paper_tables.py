"""The paper-layout tables of the twins: values, the difference column, "not run" for a missing
method (never 0), C4/C5 on one run, and the README beside the paper's printed Tables 1-3."""

from __future__ import annotations

import json

import pytest

from polarref.compare import paper_tables as PT


def _ok(name, acc, minutes, ties, obs, ba_s):
    return PT.MethodResult(name, "ok", "", 631, 631, acc, minutes, ties, obs, 0.01, 1e-4,
                           {"features": 100.0, "bundle adjustment": ba_s}, 900.0)


def _table(**methods):
    return PT.TwinTable("rosetta", 631, 7000, methods)


def test_paper_layout_with_a_missing_method_shows_not_run(tmp_path):
    t = _table(**{PT.BASELINE: _ok(PT.BASELINE, 0.400, 50.0, 100_000, 500_000, 600.0),
                  PT.OURS: _ok(PT.OURS, 0.404, 40.0, 100_500, 502_000, 300.0),
                  "pycolmap-global-sift": PT.MethodResult("pycolmap-global-sift", "failed", "mapping: no model", 631)})
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
    # C4 from the BA time, C5 with the scorecard margin (0.1% of 100,000 = 100 < 500).
    v = PT.verdicts(t)
    assert v["C4"].startswith("supported (BA time polar/Euclidean x0.50")
    assert v["C5"].startswith("supported (+500")
    back = PT.TwinTable.from_dict(json.loads((tmp_path / "rosetta" / "paper-table.json").read_text()))
    assert back.methods[PT.OURS].tie_points == 100_500 and back.methods["pycolmap-global-sift"].status == "failed"


def test_difference_column_is_not_tested_without_both_sides_and_detects_a_real_change():
    base = _ok(PT.BASELINE, 0.400, 50.0, 100_000, 500_000, 600.0)
    worse = _ok(PT.OURS, 0.450, 60.0, 99_950, 499_000, 900.0)
    assert PT.difference("accuracy_px", base, worse) == "+0.050 px"
    assert PT.difference("tie_points", base, None) == "not tested"
    v = PT.verdicts(_table(**{PT.BASELINE: base, PT.OURS: worse}))
    assert v["C4"].startswith("not supported") and v["C5"].startswith("not supported (-50")
    assert PT.verdicts(_table(**{PT.BASELINE: base})) == {"C4": "not tested", "C5": "not tested"}


def test_readme_puts_the_papers_tables_beside_the_twins(tmp_path):
    t = _table(**{PT.BASELINE: _ok(PT.BASELINE, 0.4, 50.0, 100_000, 500_000, 600.0)})
    PT.write_table(tmp_path / "rosetta", t)
    text = PT.write_readme(tmp_path).read_text()
    table1 = text.split("## Table 1")[1].split("## Table 2")[0]
    assert "| Accuracy (px) | 0.482 | 0.481 | 0.400 | not run | not tested |" in table1
    assert "| #Tie point | 200,355 | 200,708 | 100,000 | not run | not tested |" in table1
    table3 = text.split("## Table 3")[1]
    assert "| Efficiency (min) | 164.1 | 125.4 | not run | not run | not tested |" in table3
    assert "C4 on the twin: not tested" in table3


@pytest.mark.slow
def test_twin_comparison_runs_every_method_and_resumes(tmp_path):
    """A reduced mappilot twin through all four methods (~2 min), then a rerun that skips them all."""
    import dataclasses

    from polarref.compare.twins import TwinRun, run_twin
    from synth.config import twin
    from synth.render import render_scene

    cfg = dataclasses.replace(twin("mappilot", width=320, height=240, spp=4), views=20)
    render_scene(cfg.scene, tmp_path / "scene", cfg)
    run = TwinRun("mappilot", str(tmp_path / "out"), scene_dir=str(tmp_path / "scene"), method_timeout_s=900,
                  tables_dir=str(tmp_path / "tables"))
    table = run_twin(run)
    for name in PT.METHODS:
        m = table.methods[name]
        assert m.status == "ok", (name, m.reason)
        assert m.registered >= 19 and m.rotation_error_deg < 0.5 and m.tie_points > 1000
        assert m.peak_rss_mb > 50 and m.efficiency_min > 0
    stamps = {p.name: p.stat().st_mtime for p in (tmp_path / "out" / "stages").glob("*.json")}
    again = run_twin(run)
    assert {p.name: p.stat().st_mtime for p in (tmp_path / "out" / "stages").glob("*.json")} == stamps
    assert again.methods[PT.OURS].tie_points == table.methods[PT.OURS].tie_points
    readme = (tmp_path / "tables" / "README.md").read_text().split("## Table 3")[1]
    assert f"| #Tie point | 670,355 | 671,331 | {table.methods[PT.BASELINE].tie_points:,} |" in readme
