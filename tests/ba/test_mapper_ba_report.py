"""reports/bench-ba-scale/mapper-ba.*: the markdown is the script's rendering of the committed JSON,
the summary is recomputed from the stored runs (ratio, paired range, the 1.3x bound), the figures
come from a clean commit, and the forms' results agree across repeats (the runs are deterministic)."""

from __future__ import annotations

import json
import statistics

import pytest
from _scripts import load_script

from polarref.core.data import REPO_ROOT

REPORT = REPO_ROOT / "reports" / "bench-ba-scale" / "mapper-ba"


def _script():
    return load_script("mapper_ba_forms")


@pytest.fixture(scope="module")
def doc():
    if not REPORT.with_suffix(".json").exists():
        pytest.skip("no mapper-ba.json committed")
    return json.loads(REPORT.with_suffix(".json").read_text())


def test_markdown_is_generated_from_the_json(doc):
    assert REPORT.with_suffix(".md").read_text() == _script().markdown(doc)


def test_summary_recomputed_from_the_runs(doc):
    s = _script().summarize(doc["runs"])
    assert s == doc["summary"]
    eu = statistics.median(r["ba_s"] for r in doc["runs"] if r["form"] == "euclidean")
    po = statistics.median(r["ba_s"] for r in doc["runs"] if r["form"] == "polar")
    assert s["polar"]["ratio_to_euclidean"] == pytest.approx(po / eu, rel=1e-12)
    assert s["polar"]["within_threshold"] == (po / eu <= 1.3)


def test_clean_provenance_and_deterministic_results(doc):
    env = doc["environment"]
    assert env["git_commit"] and env["git_dirty"] is False
    for form in {r["form"] for r in doc["runs"]}:
        mine = [r for r in doc["runs"] if r["form"] == form]
        assert len(mine) == doc["repeat"] >= 2
        assert len({(r["tie_points"], r["registered"], r["mean_reprojection_error_px"]) for r in mine}) == 1


def test_summary_rule_can_fail():
    """The bound is applied, not assumed: a polar run at 1.2x passes, at 1.5x fails."""
    script = _script()
    runs = [{"form": "euclidean", "repeat": 0, "ba_s": 10.0}, {"form": "polar", "repeat": 0, "ba_s": 12.0}]
    assert script.summarize(runs)["polar"]["within_threshold"] is True
    runs[1]["ba_s"] = 15.0
    s = script.summarize(runs)["polar"]
    assert s["within_threshold"] is False and s["ratio_paired_min"] == s["ratio_paired_max"] == 1.5
