"""reports/bench-ba-scale/schur-panel.md is scripts/schur_panel.py's markdown of the committed
schur-panel.json, and the JSON's rates are its flops over its times (no number typed in)."""

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
REPORT = ROOT / "reports" / "bench-ba-scale" / "schur-panel"


@pytest.fixture(scope="module")
def doc():
    if not REPORT.with_suffix(".json").exists():
        pytest.skip("no schur-panel.json")
    return json.loads(REPORT.with_suffix(".json").read_text())


def _script():
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        import schur_panel
    finally:
        sys.path.pop(0)
    return schur_panel


def test_markdown_is_generated_from_json(doc):
    assert _script().markdown(doc) == REPORT.with_suffix(".md").read_text()


def test_rates_are_analytic_flops_over_times_and_paths_agree(doc):
    env = doc["environment"]
    assert not env["git_dirty"] and doc["blas_threads"] <= 2
    for r in doc["problems"]:
        runs = {x["width"]: x for x in r["schur"]}
        assert 0 in runs and r["chosen_width"] in runs
        for x in runs.values():
            assert abs(x["gflops_cpu"] - r["schur_flops"] / x["cpu_s"] / 1e9) <= 1e-9 * x["gflops_cpu"]
            assert x["max_rel_diff_S"] <= 1e-12
        for p in r["padding"]:   # the window path executes at least the useful products
            assert 0 < p["useful_share"] <= 1
