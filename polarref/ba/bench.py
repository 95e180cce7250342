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
from polarref.core.errors import PolarrefError

log = logging.getLogger(__name__)

QUICK = ("synth-20", "bal/dubrovnik-3-7-pre.txt")
FULL = ("bal/problem-49-7776-pre.txt", "parallaxba_fakepile", "synth-20", "synth-60", "synth-200",
        "synth-60-sparse", "synth-200-sparse")
SCIPY_MAX_OBS = 400_000  # scipy is skipped on larger problems (noted in the table)
TARGET_REL = 1e-3        # "within 0.1 %" of the common final cost
CONVERGED_REL = 0.01     # solvers ending > 1 % above the best are not used to set the common cost
CERES = (("colmap", 1), ("colmap", 2), ("ours", 1), ("ours", 2))
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
    def fn(limit: int | None):
        opts = dataclasses.replace(options, param=param, **({} if limit is None else {"max_iterations": limit}))
        s = solve(base.copy(), opts, prepared=True)
        return {"final_cost": s.final_pixel_cost, "objective_final": s.final_cost, "wall_s": s.wall_s,
                "iterations": s.iterations, "accepted": s.accepted_iterations,
                "rejected": s.iterations - s.accepted_iterations, "termination": s.termination,
                "final_rms_px": s.final_rms_px, "initial_cost": s.initial_pixel_cost,
                "linear_solver": s.linear_solver, "setup_s": s.setup_s,
                "trace": [[r.iteration, r.accepted, r.wall_s, r.cost] for r in s.trace]}

    settings = {k: v for k, v in dataclasses.asdict(dataclasses.replace(options, param=param)).items()}
    settings.update(threads=options.blas_threads, threads_kind="BLAS (threadpoolctl); the solver itself is one "
                    "Python thread")
    return _Solver(param, "ours", settings, fn)


def _ceres_solver(base, options: BAOptions, which: str, threads: int) -> _Solver:
    from polarref.ba.peers import ceres_settings, run_pycolmap

    cs = ceres_settings(options, which, threads)

    def fn(limit: int | None):
        r = run_pycolmap(base.copy(), options, cs if limit is None else cs.with_iterations(limit))
        fn.settings_used = r.settings
        return {"final_cost": r.final_cost, "wall_s": r.wall_s, "iterations": r.iterations,
                "accepted": r.accepted_iterations, "rejected": r.rejected_iterations,
                "termination": r.termination, "final_rms_px": r.final_rms_px, "initial_cost": r.initial_cost,
                "reported_cost": r.reported_cost, "behind_camera": r.behind_camera,
                "linear_solver": r.settings.get("linear_solver_used", "")}

    return _Solver(cs.name, "ceres", dataclasses.asdict(cs), fn)


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


def run_problem(spec: str, options: BAOptions, scipy_max_obs: int = SCIPY_MAX_OBS, repeat: int = 1) -> dict:
    from threadpoolctl import threadpool_limits

    from polarref.ba.loaders import load_problem
    from polarref.ba.peers import run_scipy

    load = os.getloadavg()[0]  # the machine is shared: say how busy it was
    base, _ = load_problem(_resolve(spec))
    prepare(base)
    solvers = [_ours_solver(base, options, p) for p in PARAMS]
    solvers += [_ceres_solver(base, options, w, t) for w, t in CERES]
    rows: dict[str, dict] = {}
    for s in solvers:   # full runs first: they fix the common cost
        try:
            full = s.fn(None)
        except Exception as exc:  # a failing solver is reported, not fatal to the bench
            rows[s.name] = {"solver": s.name, "kind": s.kind, "settings": s.settings,
                            "error": f"{type(exc).__name__}: {exc}"}
            continue
        if s.kind == "ceres":
            s.settings = getattr(s.fn, "settings_used", s.settings)
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
        limits[s.name] = (_limit_from_trace(full, target) if "trace" in full and r["pixel_objective"]
                          else _bisect_limit(s, full, target))
        r["iterations_limit_to_target"] = limits[s.name]
        r["set_common_cost"] = s.name in finals and finals[s.name] <= best * (1 + CONVERGED_REL)
    for rep in range(repeat):   # interleaved, so load changes hit every solver alike
        for s in solvers:
            r = rows[s.name]
            if "full_runs" not in r:
                continue
            if rep > 0:
                r["full_runs"].append(s.fn(None))
            k = limits[s.name]
            if k is not None:
                r.setdefault("target_runs", []).append(s.fn(k))
    own = _ceres_own_cost(solvers, rows, limits, target, repeat)   # needs the full runs' traces
    out_rows = []
    for s in solvers:
        r = rows[s.name]
        if "full_runs" in r:
            for run in r["full_runs"]:
                run.pop("trace", None)
            tr = r.get("target_runs", [])
            for run in tr:
                run.pop("trace", None)
            r["wall_s"] = _stats([x["wall_s"] for x in r["full_runs"]])
            r["final_cost"] = r["full_runs"][0]["final_cost"]
            r["iterations"] = r["full_runs"][0]["iterations"]
            r["reached_target"] = bool(tr) and all(x["final_cost"] <= target for x in tr)
            r["time_to_target_s"] = _stats([x["wall_s"] for x in tr] if r["reached_target"] else [])
            r["iterations_to_target"] = ({"total": tr[0]["iterations"], "accepted": tr[0]["accepted"],
                                          "rejected": tr[0]["rejected"]} if tr else None)
            if s.kind == "ours":  # the forms' cost per LM step, side by side on one problem
                r["s_per_accepted_iteration"] = _stats([
                    (x["wall_s"] - x["setup_s"]) / x["accepted"] for x in r["full_runs"] if x["accepted"]])
        out_rows.append(r)
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
    summary = _summarize(out_rows)
    return {"problem": spec, "num_cameras": base.num_cameras, "num_points": base.num_points,
            "num_observations": base.num_observations, "best_final_cost": best, "common_final_cost": common,
            "target_cost": target, "rows": out_rows, "repeat": repeat, "load_1min": load, **summary,
            **({"ceres_own_cost": own} if own else {})}


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


def _summarize(rows: list[dict]) -> dict:
    """The fastest Ceres setting to the target and every solver's ratio to it (medians); our
    forms' seconds per accepted iteration relative to the Euclidean form's."""
    per = {r["solver"]: (r.get("s_per_accepted_iteration") or {}).get("median") for r in rows}
    for r in rows:
        if per.get(r["solver"]) is not None and per.get("euclidean"):
            r["per_iteration_vs_euclidean"] = per[r["solver"]] / per["euclidean"]
    t = {r["solver"]: (r.get("time_to_target_s") or {}).get("median") for r in rows}
    ceres = {n: v for n, v in t.items() if n.startswith("ceres-") and v is not None}
    fastest = min(ceres, key=ceres.get) if ceres else None
    for r in rows:
        v = t.get(r["solver"])
        r["ratio_to_fastest_ceres"] = v / ceres[fastest] if fastest and v is not None else None
    return {"fastest_ceres": fastest, "fastest_ceres_time_to_target_s": ceres.get(fastest)}


def run_bench(problems, out_dir: Path, options: BAOptions = BAOptions(),
              scipy_max_obs: int = SCIPY_MAX_OBS, repeat: int = 1,
              merge: bool = False) -> list[dict]:
    """Run the problems; with ``merge`` keep the other problems of an existing bench.json
    (a problem run again replaces its old entry). bench.json: {"environment", "settings",
    "problems"}."""
    from polarref.ba import kernels
    from polarref.ba.bench_report import markdown
    from polarref.core.heap import keep_heap
    from polarref.core.provenance import collect

    # compile (or load) the kernels before any timed solve; the time is recorded, not hidden
    fast = kernels.use_kernels(options.kernels)
    heap = keep_heap()  # per-iteration arrays kept mapped (heap.py); recorded below
    warm = kernels.warm_up() if fast else 0.0
    path = out_dir / "bench.json"
    old = json.loads(path.read_text()) if merge and path.exists() else {}
    results = old.get("problems", []) if isinstance(old, dict) else []
    doc = {"environment": collect(threads={"ours_blas": options.blas_threads or 0}),
           "settings": {"repeat": repeat, "target": f"common final cost + {TARGET_REL:.1%}",
                        "converged_rel": CONVERGED_REL, "ours": dataclasses.asdict(options),
                        "ceres": [f"{w} tolerances, {t} thread(s)" for w, t in CERES],
                        "kernels": {"used": "numba" if fast else "numpy",
                                    "numba": kernels.numba_version(),
                                    "warm_up_s": warm, "threads": 1},
                        "heap": heap},
           "problems": results}
    for spec in problems:
        t = time.perf_counter()
        res = run_problem(spec, options, scipy_max_obs, repeat)
        log.info("bench %s done in %.1f s", spec, time.perf_counter() - t)
        doc["problems"] = [r for r in doc["problems"] if r["problem"] != spec] + [res]
        # written after every problem so an interrupted bench keeps what it measured
        out_dir.mkdir(parents=True, exist_ok=True)
        atomic_write(path, json.dumps(doc, indent=1, default=float))
        atomic_write(out_dir / "bench.md", markdown(doc))
    return doc["problems"]
