"""Benchmark: every parameterization of ours, pycolmap (Ceres) and scipy on the same problems.

Costs are all recomputed with one definition (:func:`polarref.ba.solver.pixel_cost`).
Wall times are the best of ``repeat`` runs in one process, ours and pycolmap's interleaved,
without memory tracing (tracemalloc slows numpy allocations). Peak memory is measured in a
separate run: ``tracemalloc`` peak of Python/numpy allocations for our and scipy's solves;
for pycolmap (C++ allocations are invisible to tracemalloc) the process ``ru_maxrss`` after
its run, an upper bound that includes everything loaded before.
Per-iteration time excludes setup (landmarks, index structures, first evaluation) and the
final summary: ``(trace[-1].wall_s - setup_s) / iterations``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import resource
import time
import tracemalloc
from pathlib import Path

from polarref.atomic import atomic_write
from polarref.errors import PolarrefError
from polarref.ba.options import PARAMS, BAOptions
from polarref.ba.problem import prepare
from polarref.ba.solver import solve

log = logging.getLogger(__name__)

QUICK = ("synth-20", "bal/dubrovnik-3-7-pre.txt")
FULL = ("bal/problem-49-7776-pre.txt", "parallaxba_fakepile", "synth-20", "synth-60", "synth-200")
SCIPY_MAX_OBS = 400_000  # scipy is skipped on larger problems (noted in the table)


def _resolve(spec: str) -> str:
    """A path that exists, ``synth-*``, or an item of the reference data (``bal/...``)."""
    if spec.startswith("synth-") or Path(spec).exists():
        return spec
    from polarref.data import data_path
    from polarref.errors import DataNotFoundError
    if Path(spec).is_absolute() or spec.startswith((".", "~")):
        raise PolarrefError(f"BA problem not found: {spec}")
    try:
        return str(data_path(*spec.split("/")))
    except DataNotFoundError as exc:
        raise PolarrefError(f"BA problem not found: {spec} (neither a path here nor an item of "
                            f"the reference data: {exc})") from exc


def _ours(base, options: BAOptions, param: str, memory: bool) -> dict:
    opts = dataclasses.replace(options, param=param)
    s = solve(base.copy(), opts, prepared=True)
    peak = float("nan")
    if memory:
        tracemalloc.start()
        try:
            solve(base.copy(), opts, prepared=True)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    trace = [(r.wall_s, r.cost) for r in s.trace if r.accepted]
    loop_s = (s.trace[-1].wall_s if s.trace else s.wall_s) - s.setup_s
    return {"solver": param, "initial_cost": s.initial_pixel_cost,
            "final_cost": s.final_pixel_cost, "objective_final": s.final_cost,
            "final_rms_px": s.final_rms_px, "iterations": s.iterations,
            "wall_s": s.wall_s, "setup_s": s.setup_s, "termination": s.termination,
            "peak_mem_mb": peak / 2**20, "mem_kind": "tracemalloc",
            "per_iteration_s": loop_s / max(s.iterations, 1),
            "pixel_objective": param in ("euclidean", "parallax"), "trace": trace,
            "time_in": s.time_in, "linear_solver": s.linear_solver,
            "behind_camera": s.behind_camera, "exclusions": s.exclusions}


def run_problem(spec: str, options: BAOptions, scipy_max_obs: int = SCIPY_MAX_OBS,
                repeat: int = 1) -> dict:
    from threadpoolctl import threadpool_limits

    from polarref.ba.loaders import load_problem
    from polarref.ba.peers import run_pycolmap, run_scipy

    load = os.getloadavg()[0]  # the machine is shared: say how busy it was
    base, _ = load_problem(_resolve(spec))
    prepare(base)
    rows = {}
    py = None
    for rep in range(repeat):  # interleaved, so load changes hit both
        r = run_pycolmap(base.copy(), options)
        py = r if py is None or r.wall_s < py.wall_s else py
        for param in PARAMS:
            try:
                row = _ours(base, options, param, memory=rep == 0)
            except Exception as exc:  # a failing form is reported, not fatal to the bench
                rows[param] = {"solver": param, "error": f"{type(exc).__name__}: {exc}"}
                continue
            if param not in rows:
                rows[param] = row
            elif row["wall_s"] < rows[param].get("wall_s", float("inf")):
                row["peak_mem_mb"] = rows[param]["peak_mem_mb"]
                rows[param] = row
    rows = [rows[p] for p in PARAMS]
    rows.append({"solver": "pycolmap", "initial_cost": py.initial_cost, "final_cost": py.final_cost,
                 "final_rms_px": py.final_rms_px, "iterations": py.iterations, "wall_s": py.wall_s,
                 "termination": py.termination, "reported_cost": py.reported_cost,
                 "behind_camera": {"final": py.behind_camera},
                 "peak_mem_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                 "mem_kind": "maxrss"})
    if base.num_observations <= scipy_max_obs:
        # once, same BLAS setting as ours; memory not traced (it is the slowest solver)
        with threadpool_limits(limits=options.blas_threads, user_api="blas"):
            r = run_scipy(base.copy(), options)
        rows.append({"solver": "scipy", "initial_cost": r.initial_cost, "final_cost": r.final_cost,
                     "final_rms_px": r.final_rms_px, "iterations": r.iterations,
                     "wall_s": r.wall_s, "termination": r.termination,
                     "behind_camera": {"final": r.behind_camera},
                     "peak_mem_mb": float("nan"), "mem_kind": "not measured"})
    else:
        rows.append({"solver": "scipy", "error": f"skipped: {base.num_observations} observations "
                     f"> --scipy-max-obs {scipy_max_obs}"})
    best = min(x["final_cost"] for x in rows if "final_cost" in x)
    py = next(x for x in rows if x["solver"] == "pycolmap")
    for x in rows:
        if "final_cost" not in x:
            continue
        x["within_0.1pct_of_best"] = bool(x["final_cost"] <= best * 1.001)
        x["time_to_0.1pct_s"] = None
        if x.get("pixel_objective"):
            hit = [t for t, c in x["trace"] if c <= best * 1.001]
            x["time_to_0.1pct_s"] = hit[0] if hit else None
        elif x["within_0.1pct_of_best"] and x["solver"] in ("pycolmap", "scipy"):
            x["time_to_0.1pct_s"] = x["wall_s"]  # no per-iteration trace: upper bound
        x["ratio_to_pycolmap"] = x["wall_s"] / py["wall_s"]
    eu = next((x for x in rows if x["solver"] == "euclidean" and "per_iteration_s" in x), None)
    for x in rows:
        if eu and "per_iteration_s" in x:
            x["per_iteration_vs_euclidean"] = x["per_iteration_s"] / eu["per_iteration_s"]
    return {"problem": spec, "num_cameras": base.num_cameras, "num_points": base.num_points,
            "num_observations": base.num_observations, "best_final_cost": best, "rows": rows,
            "repeat": repeat, "load_1min": load, "cpus": os.cpu_count(),
            "blas_threads": options.blas_threads}


def _behind(x: dict) -> str:
    n = x.get("behind_camera", {}).get("final", 0)
    return f"; {n} obs behind camera" if n and n > 0 else ""


def _mem(x: dict) -> str:
    m = x.get("peak_mem_mb", float("nan"))
    return "-" if m != m else f"{m:.0f} ({x['mem_kind']})"


def markdown(results: list[dict]) -> str:
    out = ["Costs: 1/2 sum of squared pixel residuals recomputed on every solver's output (one "
           "definition; polar and angular minimize a different objective, see `objective`); "
           "wall s: best of the runs noted per problem, in one process; t to 0.1%: first "
           "accepted iteration within 0.1% of the best final cost (pixel-objective forms only; "
           "pycolmap/scipy have no trace: their wall time when they reach it); s/iter vs eu: "
           "steady per-iteration time (setup excluded) relative to euclidean; peak MB: "
           "tracemalloc peak of the solve (pycolmap: process maxrss, an upper bound); "
           "termination notes observations left behind their camera (projected anyway in "
           "the recomputed cost; COLMAP's own cost counts them as zero). Findings: notes.md.",
           "",
           "| problem | solver | initial cost | final cost | objective | RMS px | iters | wall s | "
           "t to 0.1% s | x pycolmap | s/iter | s/iter vs eu | peak MB | termination |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for res in results:
        name = (f"{res['problem']} ({res['num_cameras']} cams, {res['num_points']} pts, "
                f"{res['num_observations']} obs; best of {res.get('repeat', 1)}, load "
                f"{res.get('load_1min', float('nan')):.1f} on {res.get('cpus', '?')} CPUs)")
        for x in res["rows"]:
            if "error" in x:
                out.append(f"| {name} | {x['solver']} | {x['error']} ||||||||||||")
                name = ""
                continue
            t01 = "-" if x["time_to_0.1pct_s"] is None else f"{x['time_to_0.1pct_s']:.3f}"
            pie = x.get("per_iteration_vs_euclidean")
            pit = x.get("per_iteration_s")
            obj = x.get("objective_final")
            out.append(
                f"| {name} | {x['solver']} | {x['initial_cost']:.6g} | {x['final_cost']:.6g} | "
                f"{'-' if obj is None else f'{obj:.6g}'} | {x['final_rms_px']:.4f} | "
                f"{x['iterations']} | {x['wall_s']:.3f} | {t01} | {x['ratio_to_pycolmap']:.2f} | "
                f"{'-' if pit is None else f'{pit:.4f}'} | {'-' if pie is None else f'{pie:.2f}'} | "
                f"{_mem(x)} | {x['termination']}{_behind(x)} |")
            name = ""
    return "\n".join(out) + "\n"


def run_bench(problems, out_dir: Path, options: BAOptions = BAOptions(),
              scipy_max_obs: int = SCIPY_MAX_OBS, repeat: int = 1,
              merge: bool = False) -> list[dict]:
    """Run the problems; with ``merge`` keep the other problems of an existing bench.json
    (a problem run again replaces its old entry)."""
    path = out_dir / "bench.json"
    results = json.loads(path.read_text()) if merge and path.exists() else []
    for spec in problems:
        t = time.perf_counter()
        res = run_problem(spec, options, scipy_max_obs, repeat)
        log.info("bench %s done in %.1f s", spec, time.perf_counter() - t)
        results = [r for r in results if r["problem"] != spec] + [res]
        # written after every problem so an interrupted bench keeps what it measured
        out_dir.mkdir(parents=True, exist_ok=True)
        atomic_write(path, json.dumps(results, indent=1, default=float))
        atomic_write(out_dir / "bench.md", markdown(results))
    return results
