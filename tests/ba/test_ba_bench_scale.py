"""Issue 35's bench pieces: Ceres' progress trace, tau targets, performance profiles, flop counts,
peak memory of a forked solve, the LM radius growth."""

import math

import numpy as np
import pytest

from polarref.ba import BAOptions


def test_ceres_trace_matches_its_summary():
    """The parsed progress ends at Ceres' final cost (shifted onto the recomputed one) after as many
    LM steps as its summary counts, at times inside the measured wall time."""
    from polarref.ba.loaders import load_problem
    from polarref.ba.peers import ceres_settings, run_pycolmap
    from polarref.ba.problem import prepare

    base, _ = load_problem("synth-20")
    prepare(base)
    opts = BAOptions(max_iterations=30)
    r = run_pycolmap(base.copy(), opts, ceres_settings(opts, "ours", 1, "DENSE_SCHUR"), trace=True)
    steps = [t for t in r.trace if t[0] > 0]
    assert len(steps) == r.iterations and r.trace[0][0] == 0
    assert r.trace[0][3] == pytest.approx(r.initial_cost, rel=1e-6)          # no point behind a camera here
    assert steps[-1][3] == pytest.approx(r.reported_cost, rel=1e-6)
    assert r.reported_cost == pytest.approx(r.final_cost, rel=1e-9)
    times = [t[2] for t in r.trace]
    assert all(a <= b for a, b in zip(times, times[1:])) and 0 < times[-1] <= r.wall_s
    plain = run_pycolmap(base.copy(), opts, ceres_settings(opts, "ours", 1, "DENSE_SCHUR"))
    assert plain.trace == [] and plain.final_cost == pytest.approx(r.final_cost, rel=1e-12)


def test_parse_ceres_progress_accepts_only_successful_steps():
    from polarref.ba.peers import _parse_ceres_progress

    text = """iter      cost      cost_change  |gradient|   |step|    tr_ratio  tr_radius  ls_iter  iter_time  total_time
   0  1.000000e+03    0.00e+00    1.0e+02   0.00e+00   0.00e+00  1.00e+04        0    1.0e-02    2.0e-02
   1  1.000000e+03   -5.00e+01    1.0e+02   1.00e+00  -2.00e-01  5.00e+03        1    1.0e-02    3.0e-02
   2  1.000000e+02    9.00e+02    1.0e+01   1.00e+00   9.00e-01  1.50e+04        1    1.0e-02    4.0e-02
some other line
   3  9.999999e+01    1.00e-05    1.0e+01   1.00e+00   1.00e-04  7.50e+03        1    1.0e-02    5.0e-02
"""
    tr = _parse_ceres_progress(text, 1.0)
    assert [t[0] for t in tr] == [0, 1, 2, 3]
    assert [t[1] for t in tr] == [True, False, True, False]    # ratio 1e-4 < Ceres' min_relative_decrease
    assert [t[2] for t in tr] == pytest.approx([1.02, 1.03, 1.04, 1.05])
    assert tr[2][3] == 100.0


def test_tau_targets_and_trace_times():
    from polarref.bench.ba import TAUS, _tau_targets, _tau_times, _trace_time
    from polarref.bench.ba_records import SolveRun, TracePoint

    run = SolveRun.measured(final_cost=10.0009, wall_s=1.2, iterations=4, trace=tuple(TracePoint(*p) for p in (
        (1, True, 0.5, 60.0), (2, False, 0.7, 60.0), (3, True, 0.9, 10.2), (4, True, 1.1, 10.0009))))
    assert _trace_time(run, 60.0) == (0.5, 1) and _trace_time(run, 10.5) == (0.9, 3)
    assert _trace_time(run, 9.0) is None
    targets = _tau_targets(initial=110.0, best=10.0)
    assert [t.target_cost for t in targets.values()] == pytest.approx([10.0 + t * 100.0 for t in TAUS])
    a = _tau_times([run, run], targets)
    assert a["1e-02"].time_s.median == 0.9 and a["1e-02"].iterations == 3      # 10.2 <= 11
    assert a["1e-03"].time_s.median == 1.1 and a["1e-04"].time_s.median == 1.1   # 10.0009 <= 10.01
    assert a["1e-03"].time_s.n == 2
    short = SolveRun.measured(final_cost=60.0, wall_s=0.6, iterations=1, trace=run.trace[:1])
    mixed = _tau_times([run, short], targets)     # one run misses it: no time, the first hit's steps kept
    assert mixed["1e-02"].time_s.median is None and mixed["1e-02"].iterations == 3


def test_performance_profiles_by_hand(tmp_path):
    from _ba_bench_docs import doc as make_doc
    from polarref.bench.ba_report import profiles, profiles_figure

    def prob(ta, tb, tc):
        times = {"euclidean": ta, "ceres-x-1t": tb, "ceres-y-1t": tc}
        return {"problem": f"p{ta}", "rows": [{"solver": n, "kind": "ours", "tau": {}} for n in times],
                "tau_summary": {"1e-03": {"fastest_ceres": None, "fastest_ceres_s": None, "times_s": times,
                                          "ratio_to_fastest_ceres": {}}}}

    doc = make_doc([prob(1.0, 2.0, 4.0), prob(3.0, 1.5, None)])
    (p,) = profiles(doc)
    prof = p.ratios
    assert p.tau_key == "1e-03"
    assert prof["euclidean"] == [1.0, 2.0]
    assert prof["ceres-x-1t"] == [1.0, 2.0]
    assert prof["ceres-y-1t"][0] == 4.0 and math.isinf(prof["ceres-y-1t"][1])
    assert profiles_figure(doc, tmp_path / "p.png") and (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"
    assert not profiles_figure(make_doc([]), tmp_path / "q.png")


def test_flop_counts_by_hand_and_by_loop():
    from polarref.ba.roofline import lm_flops

    # two points: tracks of 3 and 2 variable cameras, one observation in a held camera
    cam = np.array([0, 1, 2, 1, 3, 4])
    pt = np.array([0, 0, 0, 1, 1, 1])
    var = np.array([True, True, True, True, False])
    f = lm_flops(cam, pt, var, 2, dense=True)
    assert f.build == 288 * 5 and f.num_unknowns == 24
    assert f.schur == 144 * 5 + 216 * (6 + 3)
    assert f.factorisation == 24**3 / 3 + 2 * 24**2
    assert lm_flops(cam, pt, var, 2, dense=False).factorisation is None
    rng = np.random.default_rng(1)
    cam, pt = rng.integers(0, 30, 2000), rng.integers(0, 300, 2000)
    var = rng.random(30) > 0.2
    pairs = 0
    for p in range(300):      # an explicit loop over points and their entries
        k = int(var[cam[pt == p]].sum())
        pairs += sum(range(1, k + 1))
    assert lm_flops(cam, pt, var, 300, dense=True).schur == 144 * var[cam].sum() + 216 * pairs


def test_forked_peak_memory():
    from polarref.bench.ba_measure import forked

    big = np.ones(20_000_000)            # 160 MB held by the parent: not the child's
    value, peak = forked(lambda: float(np.ones(12_500_000).sum()))    # 100 MB in the child
    assert value == 12_500_000.0 and 90 < peak < 130
    assert forked(lambda: 1)[1] < 20
    with pytest.raises(RuntimeError, match="ZeroDivisionError"):
        forked(lambda: 1 / 0)
    del big


def test_gemm_rate_is_measured():
    from polarref.ba.roofline import gemm_gflops

    assert 0.05 < gemm_gflops(1, n=300, repeats=2) < 1e4


def test_warm_up_covers_every_kernel_signature_a_solve_uses():
    """After kernels.warm_up() no solve (any form, dense or sparse Schur, kernels or X-space)
    compiles or loads another kernel: each is loaded once per process, before the timed solves."""
    from polarref.ba import kernels
    from polarref.ba.entry import solve
    from polarref.ba.loaders import load_problem
    from polarref.ba.parameterization import PARAMS
    from polarref.ba.problem import prepare

    if not kernels.available():
        pytest.skip("numba not installed")
    import numba.core.registry

    from polarref.ba import forms_jit, kernels_jit, schur_sparse_jit, xspace_jit
    kernels.warm_up()

    def overloads():
        out = {}
        for mod in (kernels_jit, forms_jit, xspace_jit, schur_sparse_jit):
            for name, f in vars(mod).items():
                if isinstance(f, numba.core.registry.CPUDispatcher) and not name.startswith("_"):
                    out[f"{mod.__name__}.{name}"] = len(f.overloads)
        return out

    before = overloads()
    # helpers called only from compiled code keep 0 Python-level overloads
    assert sum(v >= 1 for v in before.values()) >= 20
    assert before["polarref.ba.kernels_jit.schur_dense"] >= 1 and before["polarref.ba.forms_jit.angular_obs"] >= 1
    for spec in ("synth-20", "synth-60-sparse"):
        base, _ = load_problem(spec)
        prepare(base)
        for p in PARAMS:
            for dense_max in (700, 10):       # dense S, and the sparse (slot-kernel) path
                s = solve(base.copy(), BAOptions(param=p, max_iterations=3, dense_max_cameras=dense_max),
                          prepared=True)
                assert s.iterations >= 1
    assert overloads() == before


def test_radius_growth_saves_iterations_at_the_same_minimum():
    """Ceres' growth rule (3) vs ours (30) on synth-20: one LM step fewer for the parallax and
    angular forms, the same final cost to 1e-8 relative; growth < 1 is refused."""
    from polarref.ba.entry import solve
    from polarref.ba.loaders import load_problem
    from polarref.ba.problem import prepare

    base, _ = load_problem("synth-20")
    prepare(base)
    assert BAOptions().max_radius_growth == 30.0
    for p in ("parallax", "angular"):
        ceres = solve(base.copy(), BAOptions(param=p, max_radius_growth=3.0), prepared=True)
        ours = solve(base.copy(), BAOptions(param=p), prepared=True)
        assert ours.iterations == ceres.iterations - 1 == 4
        assert ours.final_cost == pytest.approx(ceres.final_cost, rel=1e-8)
        assert ours.rejected_iterations == ceres.rejected_iterations == 0
        # the radius grew more than 3x only after near-exact model steps
        r = [x.trust_radius for x in ours.trace]
        for a, b, rec in zip(r, r[1:], ours.trace):
            assert b / a <= 3.0 + 1e-9 or rec.gain > 0.93
    with pytest.raises(ValueError, match="max_radius_growth"):
        BAOptions(max_radius_growth=0.5)


def test_bench_cli_refuses_bad_caps_and_missing_problems_early(tmp_path):
    """Usage errors exit 2 naming the flag; a missing problem is named before any measurement."""
    import subprocess
    import sys
    import time

    def cli(*a):
        return subprocess.run([sys.executable, "-m", "polarref", "bench", "ba", *a], capture_output=True,
                              text=True)

    r = cli("--ceres-max-s", "0", "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "--ceres-max-s" in r.stderr and "Traceback" not in r.stderr
    t = time.perf_counter()
    r = cli("--problem", str(tmp_path / "missing.txt"), "--out", str(tmp_path / "o"))
    assert r.returncode == 1 and "missing.txt" in r.stderr and "Traceback" not in r.stderr
    assert time.perf_counter() - t < 30 and not (tmp_path / "o").exists()


def test_report_sections_from_json_alone():
    """bench.md's tau, memory, roofline and cold tables are computed from bench.json's fields."""
    from _ba_bench_docs import doc as make_doc
    from polarref.bench.ba_report import markdown

    st = lambda v: {"median": v, "min": v, "max": v, "n": 1}   # noqa: E731
    row = lambda n, kind, t, mem: {                            # noqa: E731
        "solver": n, "kind": kind, "settings": dict.fromkeys(
            ("function_tolerance", "gradient_tolerance", "parameter_tolerance"), 1e-6), "final_cost": 1.0, "wall_s": st(2.0), "iterations": 3,
        "full_runs": [{"final_cost": 1.0, "wall_s": 2.0, "iterations": 3, "termination": "x", "linear_solver": ""}],
        "peak_rss_mib": mem, "tau": {"1e-03": {"time_s": st(t), "iterations": 2}}}
    summ = lambda r: {"fastest_ceres": None, "fastest_ceres_s": None, "times_s": {}, "ratio_to_fastest_ceres": r}  # noqa: E731
    res = {"problem": "p", "num_cameras": 2, "num_points": 3, "num_observations": 4, "target_cost": 1.0,
           "rows": [row("euclidean", "ours", 0.5, 50.0), row("ceres-a-1t", "ceres", 2.0, 100.0),
                    row("ceres-b-1t", "ceres", 4.0, 80.0)],
           "tau_summary": {"1e-02": summ({}),
                           "1e-03": summ({"euclidean": 0.25, "ceres-a-1t": 1.0, "ceres-b-1t": 2.0}),
                           "1e-04": summ({})},
           "roofline": {"form": "euclidean", "linear_solver": "Schur (x) + dense Cholesky; numba", "num_unknowns": 6,
                        "flops_per_iteration": {"build": 2e9, "schur": 3e9, "factorisation": 1e9},
                        "gflops": {"build": st(1.0), "schur": st(5.0), "factorisation": st(10.0)}, "time_in_s": {}},
           "cold_process": {"command": "c", "process_wall_s": 1.5, "solve_wall_s": 0.9, "first_iteration_s": 0.6}}
    res["rows"][0]["warm_first_step_s"] = 0.1
    doc = make_doc([res], machine={"gemm_gflops": {"1": 20.0, "2": 38.0}, "gemm": "g"})
    md = markdown(doc)
    assert "| p | euclidean | - | 0.500 (0.25x) | - | -/2/- |" in md
    assert "| p | 50 | - | - | - | 80-100 | 0.62 |" in md                 # 50 / 80
    assert "| p | 6 | dense Cholesky | 2.000 | 3.000 | 1.000 | 1.00 | 5.00 (0.25x) | 10.00 (0.50x) |" in md
    assert "| p | 1.500 | 0.900 | 0.600 | 0.100 | 2.000 |" in md


def test_merge_docs_keeps_each_runs_provenance():
    import dataclasses

    from _ba_bench_docs import ENV, doc as make_doc
    from polarref.bench.ba_report import merge_docs

    env = lambda c: {**ENV, "git_commit": c}                       # noqa: E731
    mach = lambda g: {"gemm_gflops": {"1": g}, "gemm": "g"}        # noqa: E731
    a = make_doc([{"problem": "p"}, {"problem": "q"}], machine=mach(1.0))
    a = dataclasses.replace(a, environment=dataclasses.replace(a.environment, git_commit="a"))
    b = make_doc([{"problem": "q", "environment": env("b0")}, {"problem": "r"}], machine=mach(2.0))
    b = dataclasses.replace(b, environment=dataclasses.replace(b.environment, git_commit="b"))
    m = merge_docs([a, b])
    assert [r.problem for r in m.problems] == ["p", "q", "r"]
    got = {r.problem: r.environment.git_commit for r in m.problems}
    assert got == {"p": "a", "q": "b0", "r": "b"} and m.environment.git_commit == "b"
    assert m.problems[0].machine.gemm_gflops == {"1": 1.0} and m.merged_from == 2
    assert m.problems[2].settings == b.settings


def test_bench_cache_resumes_and_tabulates_solvers_measured_apart(tmp_path):
    """Two benches each measuring one solver into one cache, then a third with both: it reruns
    nothing (the cached runs, their wall times and load readings come back unchanged) and its
    common cost is the one of the two runs together."""
    from polarref.bench.ba import run_bench

    opts = BAOptions(max_iterations=8, kernels="numpy")
    cache = tmp_path / "cache"
    a = run_bench(["synth-20"], tmp_path / "a", opts, scipy_max_obs=0, cold=False, only=("euclidean",), cache=cache)
    b = run_bench(["synth-20"], tmp_path / "b", opts, scipy_max_obs=0, cold=False,
                  only=("ceres-dense-schur-1t",), cache=cache)
    both = run_bench(["synth-20"], tmp_path / "c", opts, scipy_max_obs=0, cold=False,
                     only=("euclidean", "ceres-dense-schur-1t"), cache=cache)
    ra, rb = a.problems[0].rows[0], b.problems[0].rows[0]
    rows = {r.solver: r for r in both.problems[0].rows}
    for r in (ra, rb):
        again = rows[r.solver].full_runs[0]
        assert again == r.full_runs[0] and again.load_1min is not None and again.load_1min_end is not None
    finals = [ra.final_cost, rb.final_cost]
    close = [c for c in finals if c <= min(finals) * 1.01]
    assert both.problems[0].common_final_cost == max(close)
