"""A BA bench solve holds the one record of a run (issue 29): SolveRun.run is a MethodRun, and
bench.json keeps its flat layout."""

import json

from polarref.bench.ba_records import SolveRun, TracePoint, dumps_json, from_json, read_json_doc, to_json
from polarref.core.data import REPO_ROOT
from polarref.core.status import RunStatus


def test_newest_committed_bench_writes_back_byte_for_byte():
    path = REPO_ROOT / "reports" / "bench-ba-scale-1e6" / "bench.json"
    assert dumps_json(read_json_doc(path)) == path.read_text()


def test_every_committed_solve_is_a_method_run_with_the_stored_figures():
    found = sorted(REPO_ROOT.glob("reports/bench-ba*/bench.json"))
    assert len(found) >= 3
    n = 0
    for path in found:
        raw = json.loads(path.read_text())
        doc = read_json_doc(path)
        for p_raw, p in zip(raw["problems"], doc.problems):
            for r_raw, r in zip(p_raw["rows"], p.rows):
                for s_raw, s in zip(r_raw.get("full_runs", []), r.full_runs):
                    assert s.run.status == RunStatus.OK and s.run.wall_s == s_raw["wall_s"]
                    assert s.run.peak_rss_mb == s_raw.get("peak_rss_mib")
                    assert s.run.stage_runtime_s == s_raw.get("time_in", {})
                    assert s.final_cost == s_raw["final_cost"]
                    n += 1
    assert n > 20


def test_a_solve_round_trips_and_leaves_its_trace_out():
    s = SolveRun.measured(final_cost=12.5, wall_s=0.75, iterations=3, accepted=2, rejected=1, time_in={"schur": 0.25},
                          peak_rss_mib=40.0, trace=(TracePoint(1, True, 0.2, 20.0),))
    data = to_json(s)
    assert list(data) == ["final_cost", "wall_s", "iterations", "accepted", "rejected", "termination",
                          "linear_solver", "time_in", "peak_rss_mib"]
    back = from_json(SolveRun, json.loads(json.dumps(data)))
    assert back == s.without_trace()
    assert (back.wall_s, back.run.stage_runtime_s, back.peak_rss_mib, back.name) == (0.75, {"schur": 0.25}, 40.0, None)
    # scipy's runs were stored with the peer's names for the counts and its name
    scipy = from_json(SolveRun, {"final_cost": 1.0, "wall_s": 2.0, "iterations": 5, "accepted_iterations": 4,
                                 "name": "scipy-trf"})
    assert scipy.accepted == 4 and scipy.run.method == scipy.name == "scipy-trf"
