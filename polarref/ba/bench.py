"""Benchmark: every parameterization of ours, pycolmap (Ceres) in four settings and scipy.

Fairness rules (issue 12):

* Every solver's settings are stored beside its times (tolerances, threads, linear solver,
  iteration limit). Ceres runs under COLMAP's tolerances and under ours, on 1 and 2 threads.
* Speed is the **time to reach the common final cost**: the common cost is the highest final
  pixel cost among the pixel-objective solvers (ours euclidean/parallax, every Ceres setting)
  that end within ``CONVERGED_REL`` of the best one, i.e. a cost every converged solver reaches;
  the target is that cost + ``TARGET_REL``. For every solver the same method measures it: the
  smallest iteration limit k* whose complete solve ends at or below the target is found (ours:
  from the trace of the full run; Ceres and ours' non-pixel forms: bisection over
  ``max_num_iterations``, since pycolmap exposes no per-iteration trace), then a complete solve
  with that limit is timed in every repeat. LM runs with a smaller limit are a prefix of the full
  run, so the cost is monotone in k.
* Costs are recomputed with one definition (:func:`polarref.ba.solver.pixel_cost`) on every
  output. Every repeat is stored; tables show medians and ranges.
* tau targets (issue 35; rootBA's rule): ``best + tau (initial - best)`` for tau in TAUS, best
  = the lowest final pixel cost of any pixel-objective solver, initial = the common start.
  The time to each is read from the iteration traces of the full runs (ours: cost and wall
  time per LM step; Ceres: its per-iteration progress, its own cost shifted by its final
  recomputed - reported cost, i.e. behind-camera residuals counted as at the end, plus
  pycolmap's set-up before Solve). Above ``bisect_max_obs`` observations the common target's
  time is read the same way (bisection would run every solver ~log2(iterations) more times).
* Ceres runs under COLMAP's rule and under each of CERES_LINEAR_SOLVERS, on 1 and 2 threads;
  DENSE_SCHUR only up to DENSE_SCHUR_MAX_CAMERAS (its dense reduced matrix), each solve capped
  at ``ceres_max_s`` seconds (recorded).
* Peak memory of every first full run (bench_measure.forked) and a roofline line per problem
  (roofline.py), with the dense GEMM rate measured at the start of the bench.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import time
from pathlib import Path

import numpy as np

from polarref.core.atomic import atomic_write
from polarref.ba.options import PARAMS, BAOptions
from polarref.ba.problem import prepare
from polarref.ba.entry import solve
from polarref.ba.peers import ceres_settings
from polarref.core.errors import PolarrefError

log = logging.getLogger(__name__)

QUICK = ("synth-20", "bal/dubrovnik-3-7-pre.txt")
FULL = ("bal/problem-49-7776-pre.txt", "parallaxba_fakepile", "synth-20", "synth-60", "synth-200",
        "synth-60-sparse", "synth-200-sparse")
SCIPY_MAX_OBS = 400_000  # scipy is skipped on larger problems (noted in the table)
TARGET_REL = 1e-3        # "within 0.1 %" of the common final cost
CONVERGED_REL = 0.01     # solvers ending > 1 % above the best are not used to set the common cost
CERES = (("colmap", "", 1), ("colmap", "", 2),
         *((("ours", ls, t) for ls in ("DENSE_SCHUR", "SPARSE_SCHUR", "ITERATIVE_SCHUR")
            for t in (1, 2))))
TAUS = (1e-2, 1e-3, 1e-4)
BISECT_MAX_OBS = 400_000
DENSE_SCHUR_MAX_CAMERAS = 2000
CERES_MAX_S = 600.0
PIXEL_FORMS = ("euclidean", "parallax")   # forms whose objective is the pixel cost


def _resolve(spec: str) -> str:
    """A path that exists, ``synth-*``, or an item of the reference data (``bal/...``)."""
    if spec.startswith(("synth-", "scale-")) or Path(spec).exists():
        return spec
    from polarref.core.data import data_path
    from polarref.core.errors import DataNotFoundError
    if Path(spec).is_absolute() or spec.startswith((".", "~")):
        raise PolarrefError(f"BA problem not found: {spec}")
    try:
        return str(data_path(*spec.split("/")))
    except DataNotFoundError as exc:
        raise PolarrefError(f"BA problem not found: {spec} (neither a path here nor an item of "
                            f"the reference data: {exc})") from exc


class _Solver:
    """One solver configuration: run(limit) -> dict with final_cost, wall_s, iterations."""

    def __init__(self, name: str, kind: str, settings: dict, fn):
        self.name, self.kind, self.settings, self.fn = name, kind, settings, fn


def _ours_solver(base, options: BAOptions, param: str) -> _Solver:
    def fn(limit: int | None, trace: bool = True):  # our trace costs nothing: always kept
        opts = dataclasses.replace(options, param=param, **({} if limit is None else {"max_iterations": limit}))
        s = solve(base.copy(), opts, prepared=True)
        return {"final_cost": s.final_pixel_cost, "objective_final": s.final_cost, "wall_s": s.wall_s,
                "iterations": s.iterations, "accepted": s.accepted_iterations,
                "rejected": s.iterations - s.accepted_iterations, "termination": s.termination,
                "final_rms_px": s.final_rms_px, "initial_cost": s.initial_pixel_cost,
                "linear_solver": s.linear_solver, "setup_s": s.setup_s, "time_in": dict(s.time_in),
                "trace": [[r.iteration, r.accepted, r.wall_s, r.cost] for r in s.trace]}

    settings = {k: v for k, v in dataclasses.asdict(dataclasses.replace(options, param=param)).items()}
    settings.update(threads=options.blas_threads, threads_kind="BLAS (threadpoolctl); the solver itself is one "
                    "Python thread")
    return _Solver(param, "ours", settings, fn)


def _ceres_solver(base, options: BAOptions, which: str, linear_solver: str, threads: int,
                  max_s: float) -> _Solver:
    from polarref.ba.peers import run_pycolmap

    cs = ceres_settings(options, which, threads, linear_solver, max_s)

    def fn(limit: int | None, trace: bool = False):
        r = run_pycolmap(base.copy(), options, cs if limit is None else cs.with_iterations(limit),
                         trace=trace)
        out = {"final_cost": r.final_cost, "wall_s": r.wall_s, "iterations": r.iterations,
               "accepted": r.accepted_iterations, "rejected": r.rejected_iterations,
               "termination": r.termination, "final_rms_px": r.final_rms_px, "initial_cost": r.initial_cost,
               "reported_cost": r.reported_cost, "behind_camera": r.behind_camera,
               "linear_solver": r.settings.get("linear_solver_used", ""), "settings_used": r.settings}
        if trace:  # Ceres' own cost, shifted onto the recomputed one (module docstring)
            shift = r.final_cost - r.reported_cost
            out["trace"] = [[i, ok, t, c + shift] for i, ok, t, c in r.trace if i > 0]
            out["trace_cost_shift"] = shift
        return out

    return _Solver(cs.name, "ceres", dataclasses.asdict(cs), fn)


def _trace_time(run: dict, target: float) -> tuple[float, int] | None:
    """(seconds, LM steps) at the first accepted step of the run's trace at or below target."""
    for it, accepted, t, cost in run.get("trace", []):
        if accepted and cost <= target:
            return float(t), int(it)
    return None


def _limit_from_trace(run: dict, target: float) -> int | None:
    for it, accepted, _, cost in run["trace"]:
        if accepted and cost <= target:
            return int(it)          # iterations are numbered from 1 (accepted + rejected)
    return None


def _bisect_limit(sol: _Solver, full: dict, target: float) -> int | None:
    """Smallest iteration limit whose solve ends at or below ``target`` (None: the full run misses it)."""
    if full["final_cost"] > target:
        return None
    lo, hi = 0, max(int(full["iterations"]), 1)       # cost(lo) > target >= cost(hi)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if sol.fn(mid)["final_cost"] <= target:
            hi = mid
        else:
            lo = mid
    return hi


def _stats(vals: list) -> dict:
    v = [x for x in vals if x is not None]
    if not v:
        return {"median": None, "min": None, "max": None, "n": 0}
    return {"median": float(np.median(v)), "min": float(min(v)), "max": float(max(v)), "n": len(v)}


def solver_names() -> list[str]:
    """Every solver the bench runs, by name: our forms, then the Ceres settings."""
    return [*PARAMS, *(ceres_settings(BAOptions(), w, t, ls).name for w, ls, t in CERES)]


def _solvers(base, options: BAOptions, ceres_max_s: float,
             only: tuple = ()) -> tuple[list[_Solver], list[dict]]:
    """Our four forms and the Ceres settings that apply at this size (``only``: just these
    names; the others get a row saying so); rows for those skipped."""
    solvers = [_ours_solver(base, options, p) for p in PARAMS if not only or p in only]
    skipped = [{"solver": p, "kind": "ours", "error": "not run (--solvers)"}
               for p in PARAMS if only and p not in only]
    for which, ls, t in CERES:
        s = _ceres_solver(base, options, which, ls, t, ceres_max_s)
        if only and s.name not in only:
            skipped.append({"solver": s.name, "kind": "ceres", "settings": s.settings,
                            "error": "not run (--solvers)"})
        elif ls == "DENSE_SCHUR" and base.num_cameras > DENSE_SCHUR_MAX_CAMERAS:
            skipped.append({"solver": s.name, "kind": "ceres", "settings": s.settings,
                            "error": f"skipped: DENSE_SCHUR above {DENSE_SCHUR_MAX_CAMERAS} cameras "
                            f"(dense {6 * base.num_cameras}^2 reduced matrix)"})
        else:
            solvers.append(s)
    return solvers, skipped


def _full_run(s: _Solver) -> dict:
    """The first full run, in a forked child so its peak memory is its own (bench_measure)."""
    from polarref.ba.bench_measure import forked

    full, peak = forked(lambda: s.fn(None, trace=True))
    full["peak_rss_mib"] = peak
    if "settings_used" in full:
        s.settings = full.pop("settings_used")
    return full


def _tau_rows(rows: dict, initial: float, best: float) -> dict:
    """Per tau: the target and, per pixel-objective solver, the time to it over its full runs."""
    out = {}
    for tau in TAUS:
        target = best + tau * (initial - best)
        key = f"{tau:.0e}"
        out[key] = {"tau": tau, "target_cost": target}
        for r in rows.values():
            if "full_runs" not in r or not r["pixel_objective"]:
                continue
            hits = [_trace_time(x, target) for x in r["full_runs"]]
            ok = [h for h in hits if h is not None]
            r.setdefault("tau", {})[key] = {
                "time_s": _stats([h[0] for h in ok] if len(ok) == len(hits) else []),
                "iterations": ok[0][1] if ok else None}
    return out


def run_problem(spec: str, options: BAOptions, scipy_max_obs: int = SCIPY_MAX_OBS, repeat: int = 1,
                bisect_max_obs: int = BISECT_MAX_OBS, ceres_max_s: float = CERES_MAX_S,
                cold: bool = True, only: tuple = ()) -> dict:
    from threadpoolctl import threadpool_limits

    from polarref.ba.loaders import load_problem
    from polarref.ba.peers import run_scipy

    load = os.getloadavg()[0]  # the machine is shared: say how busy it was
    base, _ = load_problem(_resolve(spec))
    prepare(base)
    solvers, skipped = _solvers(base, options, ceres_max_s, only)
    bisect = base.num_observations <= bisect_max_obs
    rows: dict[str, dict] = {}
    for s in solvers:   # full runs first: they fix the common cost
        log.info("bench %s: %s", spec, s.name)
        try:
            full = _full_run(s)
        except Exception as exc:  # a failing solver is reported, not fatal to the bench
            rows[s.name] = {"solver": s.name, "kind": s.kind, "settings": s.settings,
                            "error": f"{type(exc).__name__}: {exc}"}
            continue
        rows[s.name] = {"solver": s.name, "kind": s.kind, "settings": s.settings, "full_runs": [full],
                        "pixel_objective": s.kind == "ceres" or s.name in PIXEL_FORMS}
    finals = {n: r["full_runs"][0]["final_cost"] for n, r in rows.items() if "full_runs" in r and r["pixel_objective"]}
    best = min(finals.values())
    common = max(c for c in finals.values() if c <= best * (1 + CONVERGED_REL))
    target = common * (1 + TARGET_REL)
    limits = {}
    for s in solvers:
        r = rows[s.name]
        if "full_runs" not in r:
            continue
        full = r["full_runs"][0]
        if r["pixel_objective"] and not bisect:
            hit = _trace_time(full, target)
            limits[s.name] = None if hit is None else hit[1]
        elif r["pixel_objective"] and s.kind == "ours":
            limits[s.name] = _limit_from_trace(full, target)
        else:
            limits[s.name] = _bisect_limit(s, full, target) if bisect else None
        r["iterations_limit_to_target"] = limits[s.name]
        r["set_common_cost"] = s.name in finals and finals[s.name] <= best * (1 + CONVERGED_REL)
    for rep in range(repeat):   # interleaved, so load changes hit every solver alike
        for s in solvers:
            r = rows[s.name]
            if "full_runs" not in r:
                continue
            if rep > 0:
                r["full_runs"].append(s.fn(None, trace=True))
                r["full_runs"][-1].pop("settings_used", None)
            k = limits[s.name]
            if k is not None and bisect:
                r.setdefault("target_runs", []).append(s.fn(k))
                r["target_runs"][-1].pop("settings_used", None)
    own = _ceres_own_cost(solvers, rows, limits, target, repeat) if bisect else None
    initial = rows["euclidean"]["full_runs"][0]["initial_cost"] if "full_runs" in rows.get("euclidean", {}) else None
    taus = _tau_rows(rows, initial, best) if initial is not None else {}
    out_rows = []
    for s in solvers:
        r = rows[s.name]
        if "full_runs" in r:
            if bisect:
                tr = r.get("target_runs", [])
                r["reached_target"] = bool(tr) and all(x["final_cost"] <= target for x in tr)
                r["time_to_target_s"] = _stats([x["wall_s"] for x in tr] if r["reached_target"] else [])
                r["iterations_to_target"] = ({"total": tr[0]["iterations"], "accepted": tr[0]["accepted"],
                                              "rejected": tr[0]["rejected"]} if tr else None)
            else:
                hits = [_trace_time(x, target) for x in r["full_runs"]] if r["pixel_objective"] else [None]
                r["reached_target"] = all(h is not None for h in hits)
                r["time_to_target_s"] = _stats([h[0] for h in hits] if r["reached_target"] else [])
                r["time_to_target_kind"] = "iteration trace of the full runs"
                r["iterations_to_target"] = ({"total": hits[0][1], "accepted": None, "rejected": None}
                                             if r["reached_target"] else None)
            if s.kind == "ours" and r["full_runs"][0].get("trace"):   # warm: set beside the cold process
                r["warm_first_step_s"] = r["full_runs"][0]["trace"][0][2]
            for run in r["full_runs"] + r.get("target_runs", []):
                run.pop("trace", None)
            r["wall_s"] = _stats([x["wall_s"] for x in r["full_runs"]])
            r["final_cost"] = r["full_runs"][0]["final_cost"]
            r["iterations"] = r["full_runs"][0]["iterations"]
            r["peak_rss_mib"] = r["full_runs"][0]["peak_rss_mib"]
            if s.kind == "ours":  # the forms' cost per LM step, side by side on one problem
                r["s_per_accepted_iteration"] = _stats([
                    (x["wall_s"] - x["setup_s"]) / x["accepted"] for x in r["full_runs"] if x["accepted"]])
        out_rows.append(r)
    out_rows += skipped
    if base.num_observations <= scipy_max_obs:
        # once, same BLAS setting as ours; wall time to convergence (no trace: an upper bound)
        with threadpool_limits(limits=options.blas_threads, user_api="blas"):
            sp = run_scipy(base.copy(), options)
        out_rows.append({"solver": "scipy", "kind": "scipy", "settings": {
            "method": "trf", "tr_solver": "lsmr", "ftol": options.function_tolerance, "xtol": 1e-10, "gtol": 1e-10,
            "max_nfev": options.max_iterations, "threads": options.blas_threads},
            "full_runs": [dataclasses.asdict(sp)], "final_cost": sp.final_cost, "iterations": sp.iterations,
            "wall_s": _stats([sp.wall_s]), "reached_target": sp.final_cost <= target, "pixel_objective": True,
            "time_to_target_s": _stats([sp.wall_s] if sp.final_cost <= target else []),
            "time_to_target_kind": "wall time of the whole run (upper bound)"})
    else:
        out_rows.append({"solver": "scipy", "kind": "scipy", "error": f"skipped: {base.num_observations} "
                         f"observations > --scipy-max-obs {scipy_max_obs}"})
    summary = _summarize(out_rows, taus)
    extra = {"roofline": _roofline(base, rows)} if "full_runs" in rows.get("euclidean", {}) else {}
    if cold:
        from polarref.ba.bench_measure import cold_process
        extra["cold_process"] = cold_process(_resolve(spec))
    return {"problem": spec, "num_cameras": base.num_cameras, "num_points": base.num_points,
            "num_observations": base.num_observations, "initial_cost": initial, "best_final_cost": best,
            "common_final_cost": common, "target_cost": target, "tau_targets": taus,
            "time_to_target_method": "bisection + timed solves" if bisect else "iteration traces",
            "rows": out_rows, "repeat": repeat, "load_1min": load, "load_1min_end": os.getloadavg()[0],
            **summary, **extra, **({"ceres_own_cost": own} if own else {})}


def _roofline(base, rows: dict) -> dict:
    """Analytic flops of our Euclidean LM step and the rates its stages reached (medians over
    the full runs: flops x LM steps / time in the stage)."""
    from polarref.ba.roofline import lm_flops

    r = rows["euclidean"]
    dense = "dense Cholesky" in r["full_runs"][0].get("linear_solver", "")
    f = lm_flops(base.obs_cam, base.obs_pt, base.cam_mask.any(1), base.num_points, dense)

    def count(x, builds):  # builds: the first, then one per accepted step that did not stop
        if not builds:
            return x["iterations"]
        return x["accepted"] + (0 if x["termination"] == "function_tolerance" else 1)

    def rate(flops_per, stage, builds=False):
        if flops_per is None:
            return None
        v = [flops_per * count(x, builds) / x["time_in"][stage] / 1e9
             for x in r["full_runs"] if x["time_in"].get(stage, 0) > 0 and x["iterations"]]
        return _stats(v)

    return {"form": "euclidean", "linear_solver": r["full_runs"][0].get("linear_solver", ""),
            "flops_per_iteration": {"build": f.build, "schur": f.schur, "factorisation": f.factorisation},
            "num_unknowns": f.num_unknowns,
            "gflops": {"build": rate(f.build, "normal_equations", builds=True),
                       "schur": rate(f.schur, "schur"), "factorisation": rate(f.factorisation, "solve")},
            "time_in_s": {k: _stats([x["time_in"].get(k, 0.0) for x in r["full_runs"]])
                          for k in ("evaluate", "normal_equations", "schur", "solve")}}


def _ceres_own_cost(solvers, rows, limits, target, repeat) -> dict | None:
    """Euclidean vs Ceres on the Euclidean objective where the common target leaves our
    Euclidean form or every Ceres setting without a time (the fake pile: Ceres stops at
    ~1e5 with points behind cameras, Euclidean LM at 227, parallax at 172): the target is then
    the best Ceres final cost + TARGET_REL, and the time to it is measured as for the common
    target (smallest iteration limit, a complete solve timed in every repeat)."""
    by = {s.name: s for s in solvers}
    ceres = [n for n, r in rows.items() if r["kind"] == "ceres" and "full_runs" in r]
    if "euclidean" not in rows or "full_runs" not in rows["euclidean"] or not ceres:
        return None
    if limits.get("euclidean") is not None and any(limits.get(n) is not None for n in ceres):
        return None
    own = min(rows[n]["full_runs"][0]["final_cost"] for n in ceres) * (1 + TARGET_REL)
    out = {"target_cost": own, "why": "common target not reached by our Euclidean form or by any "
           f"Ceres setting (common target {target:.6g})", "rows": {}}
    names = ["euclidean", *ceres]
    for name in names:
        full = rows[name]["full_runs"][0]
        k = (_limit_from_trace(full, own) if "trace" in full else _bisect_limit(by[name], full, own))
        out["rows"][name] = {"iterations_limit": k, "runs": []}
    for _ in range(repeat):   # interleaved, as the common-target runs
        for name in names:
            k = out["rows"][name]["iterations_limit"]
            if k is not None:
                run = by[name].fn(k)
                run.pop("trace", None)
                run.pop("settings_used", None)
                out["rows"][name]["runs"].append(run)
    for name in names:
        runs = out["rows"][name]["runs"]
        ok = bool(runs) and all(x["final_cost"] <= own for x in runs)
        out["rows"][name]["time_to_target_s"] = _stats([x["wall_s"] for x in runs] if ok else [])
    t = {n: v["time_to_target_s"]["median"] for n, v in out["rows"].items()}
    cer = {n: v for n, v in t.items() if n != "euclidean" and v is not None}
    fastest = min(cer, key=cer.get) if cer else None
    out["fastest_ceres"] = fastest
    out["euclidean_ratio_to_fastest_ceres"] = (t["euclidean"] / cer[fastest]
                                               if fastest and t["euclidean"] is not None else None)
    return out


def _fastest(times: dict) -> tuple[str | None, dict]:
    """The fastest Ceres setting of {solver: seconds or None} and every solver's ratio to it."""
    ceres = {n: v for n, v in times.items() if n.startswith("ceres-") and v is not None}
    fastest = min(ceres, key=ceres.get) if ceres else None
    return fastest, {n: (v / ceres[fastest] if fastest and v is not None else None) for n, v in times.items()}


def _summarize(rows: list[dict], taus: dict | None = None) -> dict:
    """The fastest Ceres setting to the target and every solver's ratio to it (medians); our
    forms' seconds per accepted iteration relative to the Euclidean form's; per tau target the
    same (``tau_summary``)."""
    per = {r["solver"]: (r.get("s_per_accepted_iteration") or {}).get("median") for r in rows}
    for r in rows:
        if per.get(r["solver"]) is not None and per.get("euclidean"):
            r["per_iteration_vs_euclidean"] = per[r["solver"]] / per["euclidean"]
    t = {r["solver"]: (r.get("time_to_target_s") or {}).get("median") for r in rows}
    fastest, ratio = _fastest(t)
    for r in rows:
        r["ratio_to_fastest_ceres"] = ratio.get(r["solver"])
    tau_summary = {}
    for key in taus or {}:
        tt = {r["solver"]: ((r.get("tau") or {}).get(key, {}).get("time_s") or {}).get("median") for r in rows}
        f, ratio = _fastest(tt)
        tau_summary[key] = {"fastest_ceres": f, "fastest_ceres_s": tt.get(f) if f else None,
                            "times_s": tt, "ratio_to_fastest_ceres": ratio}
    return {"fastest_ceres": fastest, "fastest_ceres_time_to_target_s": t.get(fastest) if fastest else None,
            "tau_summary": tau_summary}


def run_bench(problems, out_dir: Path, options: BAOptions = BAOptions(),
              scipy_max_obs: int = SCIPY_MAX_OBS, repeat: int = 1,
              merge: bool = False, bisect_max_obs: int = BISECT_MAX_OBS,
              ceres_max_s: float = CERES_MAX_S, cold: bool = True, only: tuple = ()) -> list[dict]:
    """Run the problems; with ``merge`` keep the other problems of an existing bench.json
    (a problem run again replaces its old entry). bench.json: {"environment", "settings",
    "machine", "problems"}; bench.md and the performance profiles (profiles.png) beside it."""
    from polarref.ba import kernels
    from polarref.ba.bench_measure import kernel_load_s
    from polarref.ba.bench_report import markdown, profiles_figure
    from polarref.ba.roofline import gemm_gflops
    from polarref.core.heap import keep_heap
    from polarref.core.provenance import collect

    for spec in problems:   # a missing problem fails before minutes of measurements
        _resolve(spec)
    # compile (or load) the kernels before any timed solve; the time is recorded, not hidden
    fast = kernels.use_kernels(options.kernels)
    cold_load = kernel_load_s() if fast and cold else None   # a fresh interpreter's load
    heap = keep_heap()  # per-iteration arrays kept mapped (heap.py); recorded below
    warm = kernels.warm_up() if fast else 0.0
    path = out_dir / "bench.json"
    old = json.loads(path.read_text()) if merge and path.exists() else {}
    results = old.get("problems", []) if isinstance(old, dict) else []
    for r in results:   # merged problems keep the provenance and machine figures of their run
        r.setdefault("environment", old.get("environment"))
        r.setdefault("machine", old.get("machine"))
    machine = {"gemm_gflops": {str(t): gemm_gflops(t) for t in (1, 2)},
               "gemm": "numpy float64 1500x1500 @ 1500x1500, best of 3, BLAS threads by threadpoolctl",
               "load_1min_at_gemm": os.getloadavg()[0]}
    doc = {"environment": collect(threads={"ours_blas": options.blas_threads or 0}),
           "settings": {"repeat": repeat, "target": f"common final cost + {TARGET_REL:.1%}",
                        "taus": list(TAUS), "bisect_max_obs": bisect_max_obs,
                        "converged_rel": CONVERGED_REL, "ours": dataclasses.asdict(options),
                        "ceres": [f"{w} tolerances, {ls or 'COLMAP rule'}, {t} thread(s)" for w, ls, t in CERES],
                        "ceres_max_s": ceres_max_s, "solvers": list(only) or "all", "dense_schur_max_cameras": DENSE_SCHUR_MAX_CAMERAS,
                        "kernels": {"used": "numba" if fast else "numpy",
                                    "numba": kernels.numba_version(),
                                    "warm_up_s": warm, "cold_process_load_s": cold_load, "threads": 1},
                        "heap": heap},
           "machine": machine,
           "problems": results}
    for spec in problems:
        t = time.perf_counter()
        res = run_problem(spec, options, scipy_max_obs, repeat, bisect_max_obs, ceres_max_s, cold, only)
        res["bench_s"] = time.perf_counter() - t
        res["environment"], res["machine"] = doc["environment"], machine
        log.info("bench %s done in %.1f s", spec, res["bench_s"])
        doc["problems"] = [r for r in doc["problems"] if r["problem"] != spec] + [res]
        # written after every problem so an interrupted bench keeps what it measured
        out_dir.mkdir(parents=True, exist_ok=True)
        atomic_write(path, json.dumps(doc, indent=1, default=float))
        profiles_figure(doc, out_dir / "profiles.png")
        atomic_write(out_dir / "bench.md", markdown(doc))
    return doc["problems"]
