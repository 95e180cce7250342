"""The before/after report of our fixed per-solve costs (polarref.bench.ba_fixed_cost): the
medians it takes from a bench problem, and the committed markdown regenerated from its JSON."""

from pathlib import Path

import pytest

from polarref.bench.ba_fixed_cost import load, render, side
from polarref.bench.ba_records import ProblemResult, SolverKind, SolverRow, SolveRun, Stats

REPORT = Path(__file__).resolve().parents[2] / "reports" / "bench-ba"


def _run(wall, setup, schur):
    return SolveRun.measured(wall_s=wall, time_in={"schur": schur, "structure": 0.001},
                             final_cost=10.0, iterations=3, setup_s=setup)


def test_side_takes_medians_of_the_full_runs():
    runs = (_run(0.03, 0.004, 0.010), _run(0.02, 0.002, 0.030), _run(0.05, 0.003, 0.020))
    row = SolverRow("euclidean", SolverKind.OURS, full_runs=runs, final_cost=10.0, iterations=3,
                    time_to_target_s=Stats.of([0.011, 0.012, 0.015]), ratio_to_fastest_ceres=0.48)
    p = ProblemResult("synth-x", 2, 3, 6, 10.0, 10.0, 10.01, (row,), fastest_ceres="ceres-a",
                      fastest_ceres_time_to_target_s=0.025, load_1min=1.5)
    s = side(p)
    assert s.setup_s == pytest.approx(0.003) and s.stages_s["schur"] == pytest.approx(0.020)
    assert s.time_to_target_s == pytest.approx(0.012) and s.ratio == 0.48
    assert s.fastest_ceres == "ceres-a" and s.iterations == 3


@pytest.mark.skipif(not (REPORT / "fixed-cost.json").exists(), reason="no committed report")
def test_committed_markdown_is_generated_from_its_json():
    doc = load(REPORT / "fixed-cost.json")
    assert (REPORT / "fixed-cost.md").read_text() == render(doc)
    for p in doc.problems:  # results unchanged by the change being measured
        assert p.before.final_cost == p.after.final_cost
        assert p.before.iterations == p.after.iterations
