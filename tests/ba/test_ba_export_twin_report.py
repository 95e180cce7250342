"""reports/bench-ba-scale/twin-problems.*: the markdown is the script's rendering of the committed
JSON, the summary is recomputed from the stored runs, and the figures come from a clean commit."""

from __future__ import annotations

import json
import re

import pytest
from _scripts import load_script

from polarref.ba.parameterization import PARAMS
from polarref.core.data import REPO_ROOT

REPORT = REPO_ROOT / "reports" / "bench-ba-scale" / "twin-problems"


def _script():
    return load_script("twin_ba_forms")


@pytest.fixture(scope="module")
def doc():
    if not REPORT.with_suffix(".json").exists():
        pytest.skip("no twin-problems.json committed")
    return json.loads(REPORT.with_suffix(".json").read_text())


def test_markdown_is_generated_from_the_json(doc):
    assert REPORT.with_suffix(".md").read_text() == _script().markdown(doc)


def test_summary_recomputed_from_the_runs(doc):
    script = _script()
    for p in doc["problems"]:
        assert p["summary"] == script.summarize(p["runs"])
        assert sorted(p["summary"]) == sorted(PARAMS)
        for run in p["runs"]:
            assert run["per_iteration_s"] == pytest.approx((run["wall_s"] - run["setup_s"]) / run["iterations"],
                                                           rel=1e-12)


def test_provenance_of_a_clean_commit_and_a_named_problem_file(doc):
    for p in doc["problems"]:
        env = p["environment"]
        assert env["git_dirty"] is False and re.fullmatch(r"[0-9a-f]{40}", env["git_commit"])
        assert re.fullmatch(r"[0-9a-f]{64}", p["sha256"]) and p["size_bytes"] > 0
        assert "twin_ba_export.py" in p["regenerate"]
        assert p["num_observations"] > 100_000  # a twin's final BA, not a test scene


def test_the_export_reproduces_the_mappers_final_ba_at_scale(doc):
    """The committed run re-solved each twin's problem under the mapper's options: same cost and
    centres as the mapper's own final BA (the tolerances of tests/sfm/test_sfm_ba_export.py)."""
    for p in doc["problems"]:
        rep = p["reproduction"]
        assert rep["same_cameras"] and rep["final_cost_rel_diff"] <= 1e-8 and rep["max_centre_diff_rel"] <= 1e-6
        assert rep["final_cost_rel_diff"] == pytest.approx(
            abs(rep["final_cost"] - rep["mapper_final_cost"]) / rep["mapper_final_cost"], rel=1e-12, abs=1e-300)
