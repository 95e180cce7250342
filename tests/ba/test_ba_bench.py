"""``bench ba``: settings stored, every repeat kept, time to a common cost measured the same way for all."""

import json
import re

import numpy as np
import pytest

from polarref.ba import BAOptions
from polarref.ba.parameterization import PARAMS as FORM_NAMES


@pytest.mark.slow   # 12 solvers x bisection x 2 repeats: ~45 s on 2 busy cores
def test_bench_records_settings_repeats_and_time_to_common_cost(tmp_path):
    from polarref.bench.ba import TARGET_REL, run_bench
    from polarref.bench.ba_report import markdown, readme_table
    from polarref.ba.loaders import load_problem
    from polarref.ba.peers import CeresSettings, run_pycolmap
    from polarref.ba.problem import prepare

    from polarref.bench.ba_records import read_json_doc

    opts = BAOptions(max_iterations=30)
    mem = run_bench(["synth-20"], tmp_path, opts, scipy_max_obs=0, repeat=2, cold=False)
    doc = read_json_doc(tmp_path / "bench.json")
    assert markdown(doc) == (tmp_path / "bench.md").read_text() == markdown(mem)   # the file holds it all
    env = doc.environment
    assert re.fullmatch(r"[0-9a-f]{40}", env.git_commit) and isinstance(env.git_dirty, bool)
    assert env.cpu_count >= 1 and env.versions["pycolmap"] and env.cpu_model != ""
    res = doc.problems[0]
    rows = {r.solver: r for r in res.rows}
    ceres = [n for n in rows if n.startswith("ceres-")]
    assert sorted(ceres) == sorted(["ceres-colmap-tol-1t", "ceres-colmap-tol-2t"] + [
        f"ceres-{ls}-{t}t" for ls in ("dense-schur", "sparse-schur", "iterative-schur") for t in (1, 2)])
    for n in ceres:
        s = rows[n].settings
        assert s["num_threads_used"] == s["num_threads"] == int(n[-2])       # the thread count asked for was used
        assert s["linear_solver_used"] and s["max_num_iterations"] == 30
        if "colmap" not in n:            # the linear solver asked for was used
            assert s["linear_solver_used"] == s["linear_solver"] == n[6:-3].upper().replace("-", "_")
            assert s["preconditioner_used"] == ("SCHUR_JACOBI" if "iterative" in n else s["preconditioner_used"])
        assert s["sparse_library"] == "SUITE_SPARSE"
        assert rows[n].peak_rss_mib > 0
    assert rows["ceres-colmap-tol-1t"].settings["function_tolerance"] == 0.0
    assert rows["ceres-dense-schur-1t"].settings["function_tolerance"] == opts.function_tolerance
    assert rows["euclidean"].settings["function_tolerance"] == opts.function_tolerance
    target = res.target_cost
    assert target == pytest.approx(res.common_final_cost * (1 + TARGET_REL))
    assert res.best_final_cost <= res.common_final_cost <= 1.01 * res.best_final_cost
    for n in ["euclidean", "parallax", *ceres]:
        r = rows[n]
        assert len(r.full_runs) == 2 and len(r.target_runs) == 2           # every repeat stored
        assert r.reached_target and all(x.final_cost <= target for x in r.target_runs)
        assert r.time_to_target_s.min <= r.time_to_target_s.median <= r.time_to_target_s.max
    # the limit is the smallest that reaches the target: one iteration fewer misses it (checked directly)
    base, _ = load_problem("synth-20")
    prepare(base)
    k = rows["ceres-dense-schur-1t"].iterations_limit_to_target
    cs = CeresSettings("c", opts.function_tolerance, opts.gradient_tolerance, opts.parameter_tolerance, k - 1, 1, 1,
                       "DENSE_SCHUR")
    assert run_pycolmap(base.copy(), opts, cs).final_cost > target
    # iteration counts are LM steps, as ours: a limit of 2 gives 2 (Ceres' iteration 0 is not a step)
    two = run_pycolmap(base.copy(), opts, cs.with_iterations(2))
    assert two.iterations == two.accepted_iterations + two.rejected_iterations == 2
    # our Euclidean LM and Ceres end at the same minimum (independent solver)
    assert rows["euclidean"].final_cost == pytest.approx(rows["ceres-dense-schur-1t"].final_cost, rel=1e-4)
    fastest = res.fastest_ceres
    assert rows[fastest].ratio_to_fastest_ceres == pytest.approx(1.0)
    assert all(rows[n].ratio_to_fastest_ceres >= 1.0 for n in ceres)
    ratio = rows["euclidean"].ratio_to_fastest_ceres
    assert ratio == pytest.approx(rows["euclidean"].time_to_target_s.median / res.fastest_ceres_time_to_target_s)
    # per-iteration cost of every form, side by side; the kernel path and its warm-up recorded
    for n in list(FORM_NAMES):
        per = rows[n].s_per_accepted_iteration
        assert per.n == 2 and 0 < per.min <= per.median <= per.max < rows[n].wall_s.max
        assert rows[n].per_iteration_vs_euclidean == pytest.approx(
            per.median / rows["euclidean"].s_per_accepted_iteration.median)
    assert rows["euclidean"].per_iteration_vs_euclidean == pytest.approx(1.0)
    assert doc.settings.kernels.used in ("numba", "numpy") and doc.settings.kernels.threads == 1
    assert rows["euclidean"].settings["kernels"] == opts.kernels
    assert res.ceres_own_cost is None      # Euclidean and Ceres reach the common target here
    table = readme_table(doc)            # the README's figures come from bench.json only
    assert f"{ratio:.2f}x" in table and fastest in table
    assert np.isfinite(res.load_1min) and (tmp_path / "bench.md").read_text().count("| ceres-") == 8 * 3   # main, tau and load tables
    # tau targets: best + tau (initial - best), each solver's time from its traces, ratios to the fastest Ceres
    init, best = res.initial_cost, res.best_final_cost
    for key, tt in res.tau_targets.items():
        assert tt.target_cost == pytest.approx(best + tt.tau * (init - best))
        summ = res.tau_summary[key]
        f = summ.fastest_ceres
        assert f.startswith("ceres-") and summ.ratio_to_fastest_ceres[f] == pytest.approx(1.0)
        for n in ["euclidean", *ceres]:
            ts = rows[n].tau[key].time_s
            assert ts.n == 2 and 0 < ts.median <= rows[n].wall_s.max
    assert init > res.tau_targets["1e-02"].target_cost > res.tau_targets["1e-04"].target_cost > best
    roof = res.roofline
    n = roof.num_unknowns
    assert n == 6 * 19      # the gauge holds the first camera whole (and one centre coordinate of another)
    assert roof.flops_per_iteration.factorisation == pytest.approx(n**3 / 3 + 2 * n**2)
    assert doc.machine.gemm_gflops["1"] > 0 and (tmp_path / "profiles.png").stat().st_size > 1000


def test_readme_bench_table_matches_bench_json():
    """README quotes only what bench.json holds: its table is readme_table(bench.json)."""
    from polarref.bench.ba_report import readme_block, readme_table
    from polarref.bench.ba_records import read_json_doc
    from polarref.core.data import REPO_ROOT

    doc = read_json_doc(REPO_ROOT / "reports" / "bench-ba" / "bench.json")
    block = readme_block((REPO_ROOT / "README.md").read_text())
    assert block is not None and block.strip() == readme_table(doc).strip()


def test_update_readme_round_trip(tmp_path):
    from _ba_bench_docs import doc as make_doc
    from polarref.bench.ba_report import BEGIN, END, readme_block, readme_table, update_readme

    doc = make_doc([{"problem": "p", "fastest_ceres": "ceres-our-tol-1t", "fastest_ceres_time_to_target_s": 0.2,
                     "rows": [{"solver": "euclidean", "kind": "ours", "ratio_to_fastest_ceres": 1.5},
                              {"solver": "polar", "kind": "ours", "ratio_to_fastest_ceres": None}]}])
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{BEGIN}\nold\n{END}\ntail\n")
    update_readme(readme, doc)
    text = readme.read_text()
    assert text.startswith("intro\n") and text.endswith("tail\n") and "old" not in text
    assert readme_block(text).strip() == readme_table(doc).strip()
    assert "| p | ceres-our-tol-1t (0.200) | 1.50x | did not reach | did not reach | did not reach |" in text


def test_ceres_own_cost_when_the_common_target_is_missed():
    """Euclidean vs Ceres to Ceres' best final cost: limits by trace (ours) and bisection (Ceres)."""
    from polarref.bench.ba import TARGET_REL, _ceres_own_cost, _Solver, _Work
    from polarref.bench.ba_records import SolverKind, SolveRun, TracePoint

    costs = {"euclidean": [100.0, 50.0, 20.0, 10.0], "ceres-a": [100.0, 80.0, 60.0, 40.0]}
    calls = []

    def fn_for(name):
        def fn(limit, trace=False):
            c = costs[name]
            k = len(c) - 1 if limit is None else min(limit, len(c) - 1)
            calls.append((name, limit))
            tr = tuple(TracePoint(i, True, 0.1 * i, c[i]) for i in range(1, k + 1)) if name == "euclidean" else ()
            return SolveRun.measured(final_cost=c[k], wall_s=0.1 * k + (0.05 if name == "euclidean" else 0.0),
                                     iterations=k, accepted=k, trace=tr)
        return fn

    solvers = [_Solver(n, SolverKind.OURS if n == "euclidean" else SolverKind.CERES, {}, fn_for(n)) for n in costs]
    by = {s.name: _Work(s, [s.fn(None)]) for s in solvers}
    # common target 5: nobody reaches it -> compare on Ceres' own best cost (40)
    out = _ceres_own_cost(by, 5.0, repeat=2)
    assert out.target_cost == pytest.approx(40.0 * (1 + TARGET_REL))
    assert out.rows["euclidean"].iterations_limit == 2      # 20 <= 40.04 first at iteration 2
    assert out.rows["ceres-a"].iterations_limit == 3        # bisection: 40 first at 3
    assert len(out.rows["euclidean"].runs) == 2
    assert out.euclidean_ratio_to_fastest_ceres == pytest.approx(0.25 / 0.3)
    # when Euclidean and a Ceres setting both reached the common target there is nothing to add
    by["euclidean"].limit, by["ceres-a"].limit = 2, 3
    assert _ceres_own_cost(by, 50.0, repeat=1) is None


def test_committed_bench_reports_load_and_regenerate_byte_for_byte():
    """Every committed BA bench (several versions of the format) reads into the typed records, and
    its bench.md is markdown() of them, byte for byte; writing the records back reads the same."""
    from polarref.bench.ba_report import markdown
    from polarref.bench.ba_records import BenchDoc, from_json, read_json_doc, to_json
    from polarref.core.data import REPO_ROOT

    found = sorted(REPO_ROOT.glob("reports/bench-ba*/bench.json"))
    assert len(found) >= 2
    for path in found:
        doc = read_json_doc(path)
        assert markdown(doc) == (path.parent / "bench.md").read_text(), path
        again = from_json(BenchDoc, json.loads(json.dumps(to_json(doc), default=float)))
        assert again == doc and markdown(again) == markdown(doc)


def test_bench_json_refuses_unknown_keys(tmp_path):
    from polarref.bench.ba_records import read_json_doc
    from polarref.core.data import REPO_ROOT
    from polarref.core.records import RecordError

    data = json.loads((REPO_ROOT / "reports" / "bench-ba" / "bench.json").read_text())
    data["problems"][0]["rows"][0]["full_runs"][0]["wal_s"] = 1.0
    bad = tmp_path / "bench.json"
    bad.write_text(json.dumps(data))
    with pytest.raises(RecordError, match=r"wal_s.*problems\[0\]\.rows\[0\]\.full_runs\[0\]"):
        read_json_doc(bad)


def test_ours_threads_reach_our_solver_and_its_record(tmp_path):
    """``--ours-threads`` (BAOptions.blas_threads): our rows and the provenance carry the count
    the solve ran with; Ceres' settings keep their own 1 / 2 threads."""
    from polarref.bench.ba import run_bench
    from polarref.bench.ba_records import read_json_doc

    run_bench(["synth-20"], tmp_path, BAOptions(max_iterations=3, blas_threads=2), scipy_max_obs=0, repeat=1,
              cold=False, only=("euclidean", "ceres-colmap-tol-1t"))
    doc = read_json_doc(tmp_path / "bench.json")
    rows = {r.solver: r for r in doc.problems[0].rows}
    assert rows["euclidean"].settings["threads"] == 2 and rows["euclidean"].settings["blas_threads"] == 2
    assert rows["ceres-colmap-tol-1t"].settings["num_threads"] == 1
    assert doc.environment.threads["ours_blas"] == 2
