"""Per-stage, per-iteration time of our bundle adjuster, numpy reference path vs numba kernels.

Usage: .venv/bin/python scripts/profile_ba.py [--repeat N] PROBLEM [PROBLEM ...]
(PROBLEM as in ``polarref bench ba --problem``: ``bal/problem-49-7776-pre.txt``,
``synth-200-sparse``, ``parallaxba_fakepile``, a path.)

For every problem, form and kernel path the solve runs ``--repeat`` times, interleaved; a
stage's time per LM iteration is the solver's own ``time_in`` (solver.py) divided by the
iterations, and the table shows the minimum over the repeats (the least disturbed run on a
shared machine). Stages: evaluate = residuals + Jacobians (+ cost) at each trial point;
normal = robust weighting, V, g, W, U; schur = point elimination into the reduced camera
system; solve = its Cholesky; update = back-substitution and retraction. Markdown to stdout.

``cpu ms / accepted`` is CPU time (``time.process_time``, less disturbed by other processes
than wall time on a loaded machine) of the whole solve minus that of the same solve with
``max_iterations=0`` (setup, first evaluation, write-back), divided by the accepted
iterations: the bench's ``s_per_accepted_iteration`` in CPU time. Its ratio to Euclidean
(same path, same run) is the issue's per-iteration target; minimum over the repeats.

``--stages``: instead, the kernel path's per-iteration pieces timed one by one at the initial
estimate (``time.thread_time``, 1 BLAS thread, minimum over 3 x 5 calls, forms interleaved):
evaluate (residuals + Jacobians), V (point blocks), build (W, g, U), schur (reduced system),
back (back-substitution); the Cholesky and the LM bookkeeping are left out (the same for
every form). Less noisy than whole solves on a loaded machine; works against a checkout
without the factored kernel build too (``PYTHONPATH=<checkout>``).

``--bench-cpu``: instead, the bench's own figure, ``(wall_s - setup_s) / accepted`` (so the
write-back after the last iteration counts, as in ``polarref bench ba``), with the solver's
clock read as process CPU time; median over ``--repeat`` interleaved solves, 1 BLAS thread,
kernel path; with the split of setup, first iteration (first build, step and trial) and the
tail after the last iteration record (write-back, final pixel cost). ``--anchor-schur cross``
runs the three-slot forms on the reference elimination (anchor cross terms) instead of the
X-space one (ba/xspace.py), so both can be timed from one checkout (``--stages`` too);
``--paired`` times both in one run, interleaved solve by solve, with the per-round ratios;
``--max-iterations N`` caps every solve (large problems), ``--json OUT`` writes the figures
with provenance and the load average beside the markdown.

``--cprofile N``: instead, ``cProfile`` with process CPU time as its clock around two solves of
at most N iterations per form (kernel path): CPU ms per accepted iteration and the functions
with the most own time, per iteration. Unlike ``--stages`` it includes the solver's own inline
numpy work (robust weights, box constraint, damping, step bookkeeping).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from polarref.ba import kernels
from polarref.bench.ba import _resolve
from polarref.ba.loaders import load_problem
from polarref.ba.options import PARAMS, BAOptions
from polarref.ba.problem import prepare
from polarref.ba.entry import solve
from polarref.core.heap import keep_heap

STAGES = ("evaluate", "normal_equations", "schur", "solve", "update")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("problems", nargs="+")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--forms", default=",".join(PARAMS))
    ap.add_argument("--paths", default="numpy,numba", help="kernel paths to run")
    ap.add_argument("--stages", action="store_true", help="time the kernel stages one by one")
    ap.add_argument("--cprofile", type=int, metavar="N", default=0,
                    help="per-function process CPU time over two solves of <= N iterations")
    ap.add_argument("--top", type=int, default=8, help="--cprofile: functions listed")
    ap.add_argument("--bench-cpu", action="store_true",
                    help="the bench's per-iteration figure in process CPU time")
    ap.add_argument("--anchor-schur", default="xspace", choices=("xspace", "cross"),
                    help="--bench-cpu, --stages: the three-slot forms' elimination "
                         "(BAOptions.anchor_schur)")
    ap.add_argument("--paired", action="store_true",
                    help="--bench-cpu's figure for both eliminations, interleaved, with paired "
                         "ratios")
    ap.add_argument("--max-iterations", type=int, default=None,
                    help="--paired: cap every solve at N LM steps (large problems)")
    ap.add_argument("--skip-warm-solves", action="store_true",
                    help="--paired: no untimed one-step solve per configuration first (large problems)")
    ap.add_argument("--json", default=None, help="--paired: also write the figures to this JSON file")
    args = ap.parse_args(argv)
    keep_heap()  # as the BA bench does (polarref/core/heap.py)
    if args.stages:
        return stages(args)
    if args.paired:
        return paired(args)
    if args.bench_cpu:
        return bench_cpu(args)
    if args.cprofile:
        return cprofile(args)
    print(f"kernels warm-up {kernels.warm_up():.2f} s; load {os.getloadavg()[0]:.1f}\n")
    print("| problem | form | path | iters | setup ms | " + " | ".join(STAGES)
          + " | total ms / iter | numba speed-up | x Euclidean (same path) | cpu ms / accepted"
          " | cpu x Euclidean |")
    print("|---|---|---|---|---|" + "---|" * len(STAGES) + "---|---|---|---|---|")
    for spec in args.problems:
        base, _ = load_problem(_resolve(spec))
        prepare(base)
        best: dict = {}
        for _ in range(args.repeat):
            for form in args.forms.split(","):
                for path in args.paths.split(","):
                    c0 = time.process_time()
                    solve(base.copy(), BAOptions(param=form, kernels=path, max_iterations=0),
                          prepared=True)
                    c1 = time.process_time()
                    s = solve(base.copy(), BAOptions(param=form, kernels=path), prepared=True)
                    cpu = time.process_time() - c1 - (c1 - c0)
                    n = max(s.iterations, 1)
                    row = {k: s.time_in[k] / n for k in STAGES}
                    row["total"] = (s.wall_s - s.setup_s) / n
                    row["setup"], row["iters"] = s.setup_s, s.iterations
                    row["cpu"] = cpu / max(s.accepted_iterations, 1)
                    old = best.get((form, path))
                    best[(form, path)] = row if old is None else {
                        k: min(v, old[k]) for k, v in row.items()}
        for form in args.forms.split(","):
            for path in args.paths.split(","):
                r = best[(form, path)]
                up = (best[(form, "numpy")]["total"] / r["total"]
                      if (form, "numpy") in best else float("nan"))
                eu = best.get(("euclidean", path))
                rel = r["total"] / eu["total"] if eu else float("nan")
                rel_cpu = r["cpu"] / eu["cpu"] if eu else float("nan")
                print(f"| {spec} | {form} | {path} | {r['iters']} | {1e3 * r['setup']:.0f} | "
                      + " | ".join(f"{1e3 * r[k]:.1f}" for k in STAGES)
                      + f" | {1e3 * r['total']:.1f} | {up:.2f}x | {rel:.2f}x"
                      + f" | {1e3 * r['cpu']:.1f} | {rel_cpu:.2f}x |")
        sys.stdout.flush()
    return 0


def stages(args) -> int:
    import numpy as np
    from threadpoolctl import threadpool_limits

    from polarref.ba import kernels_jit
    from polarref.ba.schur import SchurStructure
    from polarref.ba.solver import make_param

    kernels.warm_up()
    factored_ok = hasattr(kernels_jit, "build_anchored")  # a checkout before it: dense anchors

    def best(fn, n=5):
        b = np.inf
        for _ in range(n):
            t = time.thread_time()
            fn()
            b = min(b, time.thread_time() - t)
        return 1e3 * b

    keys = ("evaluate", "V", "build", "schur", "back")
    print(f"load {os.getloadavg()[0]:.1f}\n\n| problem | form | " + " | ".join(keys)
          + " | sum ms | x Euclidean |\n|---|---|" + "---|" * (len(keys) + 2))
    for spec in args.problems:
        p, _ = load_problem(_resolve(spec))
        prepare(p)
        calls = {}
        for form in args.forms.split(","):
            prm = make_param(p, BAOptions(param=form, kernels="numba"))
            st = SchurStructure(prm.slot_cams, prm.slot_cols, p.obs_pt, p.cam_mask.any(1),
                                p.num_points, fast=True)
            fac = st.fused and factored_ok
            pts = prm.init_points()
            r, Jp, Jc = prm.evaluate(p.R, p.C, pts, True, factored=fac)
            mask_v = p.cam_mask[st.var_cams].astype(float)
            V, g_p = st.point_terms(Jp, r)
            Vd = V + 1e-3 * np.eye(3)
            diag_c = np.ones((st.Nv, 6))
            dc = np.zeros((st.Nv, 6))
            xs = _xspace(st, prm) if fac and args.anchor_schur == "xspace" else None
            if xs is not None:  # the X-space elimination (ba/xspace.py)
                lam = np.full((p.num_points, 3), 1e-3)
                g_c, W, U = st.apply_mask(mask_v, *xs.build(Jc[0], Jc[1], Jp, r, V, g_p, mask_v))
                _, _, Li = xs.reduced_system(U, W, Vd, g_c, g_p, diag_c, lam)
                calls[form] = {
                    "evaluate": lambda prm=prm, pts=pts: prm.evaluate(p.R, p.C, pts, True,
                                                                      factored=True),
                    "V": lambda st=st, Jp=Jp, r=r: st.point_terms(Jp, r),
                    "build": lambda xs=xs, a=(Jc[0], Jc[1], Jp, r, V, g_p, mask_v): st.apply_mask(
                        mask_v, *xs.build(*a)),
                    "schur": lambda xs=xs, a=(U, W, Vd, g_c, g_p, diag_c, lam): xs.reduced_system(
                        *a),
                    "back": lambda xs=xs, a=(W, Li, g_p, dc): xs.back_substitute(*a)}
                continue
            g_c, W, U = st.apply_mask(mask_v, *st.build(Jc, Jp, r))
            _, _, Li = st.reduced_system(U, W, Vd, g_c, g_p, diag_c)
            calls[form] = {
                "evaluate": lambda prm=prm, pts=pts, fac=fac: prm.evaluate(p.R, p.C, pts, True,
                                                                           factored=fac),
                "V": lambda st=st, Jp=Jp, r=r: st.point_terms(Jp, r),
                "build": lambda st=st, Jc=Jc, Jp=Jp, r=r, m=mask_v: st.apply_mask(
                    m, *st.build(Jc, Jp, r)),
                "schur": lambda st=st, a=(U, W, Vd, g_c, g_p, diag_c): st.reduced_system(*a),
                "back": lambda st=st, a=(W, Li, g_p, dc): st.back_substitute(*a)}
        t = {f: dict.fromkeys(keys, np.inf) for f in calls}
        with threadpool_limits(limits=1, user_api="blas"):
            for _ in range(3):
                for f, c in calls.items():
                    for k in keys:
                        t[f][k] = min(t[f][k], best(c[k]))
        for f, row in t.items():
            tot = sum(row.values())
            eu = sum(t["euclidean"].values()) if "euclidean" in t else float("nan")
            print(f"| {spec} | {f} | " + " | ".join(f"{row[k]:.2f}" for k in keys)
                  + f" | {tot:.2f} | {tot / eu:.2f}x |")
        sys.stdout.flush()
    return 0


def _xspace(st, prm):
    """The X-space elimination on ``st``, or None in a checkout without it."""
    try:
        from polarref.ba.xspace import AnchorElimination
    except ImportError:
        return None
    return AnchorElimination(st, *prm.anchor_cams)


def paired(args) -> int:
    """--bench-cpu's figure for the forms on both eliminations (and Euclidean), interleaved
    solve by solve; min and median over --repeat and the median of the per-round ratios
    (x Euclidean, X-space / cross), which cancel the load's slow drifts."""
    import statistics
    import types

    from threadpoolctl import threadpool_limits

    from polarref.ba import solver as solver_mod

    solver_mod.time = types.SimpleNamespace(perf_counter=time.process_time)
    kernels.warm_up()
    from polarref.core.provenance import collect_record

    env = collect_record(threads={"ours_blas": 1})   # before the run: the tree it ran from
    load0 = os.getloadavg()[0]
    cap = {} if args.max_iterations is None else {"max_iterations": args.max_iterations}
    rows = []
    print(f"load {load0:.1f}; {args.repeat} rounds\n\n| problem | form | "
          "elimination | iterations | cpu ms / accepted, min | median | x Euclidean, paired | "
          "X-space / cross, paired | final cost |\n|---|---|---|---|---|---|---|---|---|")
    cfgs = [("euclidean", "cross")] + [(f, m) for f in args.forms.split(",") if f != "euclidean"
                                       for m in ("cross", "xspace")]
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            for spec in args.problems:
                base, _ = load_problem(_resolve(spec))
                prepare(base)
                for f, m in cfgs if not args.skip_warm_solves else ():
                    solve(base.copy(), BAOptions(param=f, kernels="numba", anchor_schur=m,
                                                 max_iterations=1), prepared=True)
                runs: dict = {c: [] for c in cfgs}
                for _ in range(args.repeat):
                    for f, m in cfgs:
                        runs[(f, m)].append(solve(base.copy(), BAOptions(
                            param=f, kernels="numba", anchor_schur=m, **cap), prepared=True))
                fig = {c: [(s.wall_s - s.setup_s) / max(s.accepted_iterations, 1) for s in rs]
                       for c, rs in runs.items()}
                for c in cfgs:
                    s = runs[c][0]
                    eu = statistics.median(a / b for a, b in zip(fig[c], fig[cfgs[0]]))
                    vs = (f"{statistics.median(a / b for a, b in zip(fig[c], fig[(c[0], 'cross')])):.3f}"
                          if c[1] == "xspace" else "")
                    print(f"| {spec} | {c[0]} | {c[1]} | {s.iterations}/{s.accepted_iterations} | "
                          f"{1e3 * min(fig[c]):.2f} | {1e3 * statistics.median(fig[c]):.2f} | "
                          f"{eu:.2f}x | {vs} | {s.final_cost!r} |")
                    rows.append({"problem": spec, "form": c[0], "elimination": c[1], "iterations": s.iterations,
                                 "accepted": s.accepted_iterations, "linear_solver": s.linear_solver,
                                 "cpu_s_per_accepted": fig[c], "x_euclidean_paired": eu,
                                 "xspace_over_cross_paired": float(vs) if vs else None,
                                 "final_cost": s.final_cost, "num_cameras": base.num_cameras,
                                 "num_observations": base.num_observations,
                                 "runs": [_run_record(x) for x in runs[c]]})
                sys.stdout.flush()
    finally:
        solver_mod.time = time
    if args.json:
        _write_json(args, rows, load0, env)
    return 0


def _run_record(s) -> dict:
    """One solve's counts and stage times, and its cost per LM step were every step accepted:
    (evaluate + schur + solve + update) per step + the normal equations per build (a rejected
    step reuses the build, so forms that reject different numbers of steps compare on this)."""
    builds = s.accepted_iterations + (0 if str(s.termination) == "function_tolerance" else 1)
    t = dict(s.time_in)
    per_step = sum(t.get(k, 0.0) for k in ("evaluate", "schur", "solve", "update")) / max(s.iterations, 1)
    return {"iterations": s.iterations, "accepted": s.accepted_iterations, "termination": str(s.termination),
            "builds": builds, "time_in_cpu_s": t, "setup_cpu_s": s.setup_s,
            "cpu_s_per_step_all_accepted": per_step + t.get("normal_equations", 0.0) / max(builds, 1)}


def add_out_arguments(ap, default: Path) -> None:
    """``--out`` (OUT.json and OUT.md) and ``--overwrite``, as the issue-35 scripts take them."""
    ap.add_argument("--out", default=str(default))
    ap.add_argument("--overwrite", action="store_true")


def begin(out: Path, overwrite: bool):
    """The shared start of the scripts that write OUT.json/OUT.md (reduced_solvers.py,
    schur_roofline.py): refuse an existing OUT.json unless ``overwrite``, then the provenance,
    the bench's heap setting and the kernels loaded before anything is timed. (provenance,
    1-minute load at the start), or None where OUT.json exists."""
    from polarref.core.provenance import collect_record

    if out.with_suffix(".json").exists() and not overwrite:
        print(f"{out.with_suffix('.json')} exists (--overwrite to replace it)", file=sys.stderr)
        return None
    env = collect_record(threads={"ours_blas": 1, "kernels": 1})
    keep_heap()
    kernels.warm_up()
    return env, os.getloadavg()[0]


def write_doc(out: Path, doc: dict, markdown) -> None:
    """OUT.json (doc) and OUT.md (``markdown(doc)``), atomically; the markdown printed too."""
    import json

    from polarref.core.atomic import atomic_write

    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(out.with_suffix(".json"), json.dumps(doc, indent=1) + "\n")
    atomic_write(out.with_suffix(".md"), markdown(doc))
    print(markdown(doc))


def _write_json(args, rows: list, load0: float, env) -> None:
    """The --paired figures with provenance (core.provenance) and the load before and after."""
    import json

    from polarref.core.atomic import atomic_write
    from polarref.core.records import to_dict

    doc = {"command": "python scripts/profile_ba.py " + " ".join(sys.argv[1:]),
           "clock": "process CPU time (time.process_time), 1 BLAS thread",
           "figure": "(wall_s - setup_s) / accepted iterations per solve, in CPU seconds",
           "load_1min": [load0, os.getloadavg()[0]], "repeat": args.repeat,
           "max_iterations": args.max_iterations, "rows": rows,
           "environment": to_dict(env)}
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    atomic_write(Path(args.json), json.dumps(doc, indent=1) + "\n")


def bench_cpu(args) -> int:
    import statistics
    import types

    from threadpoolctl import threadpool_limits

    from polarref.ba import solver as solver_mod

    # the solver stamps wall_s / setup_s / the trace with time.perf_counter: read as process
    # CPU time, a loaded machine's waiting drops out of the bench's own formula
    solver_mod.time = types.SimpleNamespace(perf_counter=time.process_time)
    forms = args.forms.split(",")
    kernels.warm_up()
    print(f"load {os.getloadavg()[0]:.1f}; median of {args.repeat}; anchor_schur "
          f"{args.anchor_schur}\n\n| problem | form | "
          "iterations | cpu ms / accepted | x Euclidean | setup ms | first ms | tail ms | "
          "final cost |\n|---|---|---|---|---|---|---|---|---|")
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            for spec in args.problems:
                base, _ = load_problem(_resolve(spec))
                prepare(base)
                opts = dict(kernels="numba", anchor_schur=args.anchor_schur)
                for form in forms:  # first-call costs out of the timed solves
                    solve(base.copy(), BAOptions(param=form, max_iterations=1, **opts),
                          prepared=True)
                runs: dict = {f: [] for f in forms}
                for _ in range(args.repeat):
                    for form in forms:
                        s = solve(base.copy(), BAOptions(param=form, **opts), prepared=True)
                        runs[form].append(s)
                med = {f: statistics.median((s.wall_s - s.setup_s) / max(s.accepted_iterations, 1)
                                            for s in runs[f]) for f in forms}
                for form in forms:
                    rs, s = runs[form], runs[form][0]
                    first = statistics.median(r.trace[0].wall_s - r.setup_s for r in rs if r.trace)
                    tail = statistics.median(r.wall_s - r.trace[-1].wall_s for r in rs if r.trace)
                    eu = med.get("euclidean", float("nan"))
                    print(f"| {spec} | {form} | {s.iterations}/{s.accepted_iterations} | "
                          f"{1e3 * med[form]:.2f} | {med[form] / eu:.2f}x | "
                          f"{1e3 * statistics.median(r.setup_s for r in rs):.1f} | "
                          f"{1e3 * first:.1f} | {1e3 * tail:.1f} | {s.final_cost!r} |")
                sys.stdout.flush()
    finally:
        solver_mod.time = time
    return 0


def cprofile(args) -> int:
    import cProfile
    import pstats

    kernels.warm_up()
    print(f"load {os.getloadavg()[0]:.1f}; max_iterations {args.cprofile}; 2 solves per form\n")
    for spec in args.problems:
        base, _ = load_problem(_resolve(spec))
        prepare(base)
        for form in args.forms.split(","):
            opts = BAOptions(param=form, kernels="numba", max_iterations=args.cprofile)
            solve(base.copy(), BAOptions(param=form, kernels="numba", max_iterations=1),
                  prepared=True)  # first-call costs (imports, caches) out of the profile
            prof = cProfile.Profile(time.process_time)
            acc = its = 0
            for _ in range(2):
                prof.enable()
                s = solve(base.copy(), opts, prepared=True)
                prof.disable()
                acc, its = acc + s.accepted_iterations, its + s.iterations
            st = pstats.Stats(prof)
            total = sum(v[2] for v in st.stats.values())
            print(f"{spec} {form}: {its} iterations, {acc} accepted, "
                  f"{1e3 * total / max(acc, 1):.2f} cpu ms / accepted")
            rows = sorted(st.stats.items(), key=lambda kv: -kv[1][2])[:args.top]
            for (file, line, fn), v in rows:
                where = f"{os.path.basename(file)}:{line}({fn})" if line else fn
                print(f"    {1e3 * v[2] / max(its, 1):7.2f} ms / iteration  {v[1]:5d} calls  "
                      f"{where}")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
