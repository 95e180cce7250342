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
* Peak memory of every first full run (ba_measure.forked) and a roofline line per problem
  (roofline.py), with the dense GEMM rate measured at the start of the bench.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from polarref.ba.options import PARAMS, BAOptions
from polarref.ba.problem import prepare
from polarref.ba.entry import solve
from polarref.ba.peers import ceres_settings
from polarref.bench.ba_records import (BenchDoc, BenchSettings, IterationsToTarget, KernelSettings,
                                       MachineRates, OwnCost, OwnCostRow, ProblemResult, Roofline, SolverKind,
                                       SolverRow, SolveRun, Stats, TauSummary, TauTarget, TauTime, TracePoint,
                                       FlopCounts, SchurBytes, StageRates, Setting)
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


# The twins' final BA problems (issue 35): each exported once, by our Euclidean SfM as the twin
# campaign runs it (seed 0), into the cache; `twin-<name>` names the file there
TWINS = ("mappilot", "rosetta", "poets-park")


def twin_problem_path(twin: str) -> Path:
    """Where the exported final BA problem of ``twin`` (seed 0) is kept for the bench."""
    from polarref.core.data import cache_root
    return cache_root() / "ba-problems" / f"twin-{twin}-seed0" / "final-ba.npz"


def _resolve_twin(spec: str) -> str:
    twin = spec.removeprefix("twin-")
    path = twin_problem_path(twin)
    if path.is_file():
        return str(path)
    raise PolarrefError(f"BA problem {spec} not exported yet: make it with `PYTHONPATH=$PWD python "
                        f"scripts/twin_ba_export.py {twin} {twin} {path.parent}` (renders the twin if needed; "
                        "a render folder may replace the first argument)")


def _resolve(spec: str) -> str:
    """A path that exists, ``synth-*``, ``scale-*``, ``twin-<twin>`` (an exported twin problem in
    the cache), or an item of the reference data (``bal/...``)."""
    if spec.startswith(("synth-", "scale-")) or Path(spec).exists():
        return spec
    if spec.startswith("twin-") and spec.removeprefix("twin-") in TWINS:
        return _resolve_twin(spec)
    from polarref.core.data import data_path
    from polarref.core.errors import DataNotFoundError
    if Path(spec).is_absolute() or spec.startswith((".", "~")):
        raise PolarrefError(f"BA problem not found: {spec}")
    try:
        return str(data_path(*spec.split("/")))
    except DataNotFoundError as exc:
        raise PolarrefError(f"BA problem not found: {spec} (neither a path here nor an item of "
                            f"the reference data: {exc})") from exc


def _slug(spec: str) -> str:
    """A folder name for a problem spec (a path or a name)."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in spec)


@dataclass
class _Solver:
    """One solver configuration: ``fn(limit, trace)`` solves the problem once (limit: at most so
    many LM steps, None: the configured limit). ``settings`` is replaced by what Ceres reports
    it used after the first full run."""

    name: str
    kind: SolverKind
    settings: dict[str, Setting]
    fn: Callable[..., SolveRun]

    @property
    def pixel_objective(self) -> bool:
        return self.kind is SolverKind.CERES or self.name in PIXEL_FORMS


def _ours_solver(base, options: BAOptions, param: str) -> _Solver:
    def fn(limit: int | None, trace: bool = True) -> SolveRun:  # our trace costs nothing: always kept
        opts = dataclasses.replace(options, param=param, **({} if limit is None else {"max_iterations": limit}))
        s = solve(base.copy(), opts, prepared=True)
        return SolveRun.measured(final_cost=s.final_pixel_cost, wall_s=s.wall_s, iterations=s.iterations,
                                 accepted=s.accepted_iterations, rejected=s.iterations - s.accepted_iterations,
                                 termination=s.termination, final_rms_px=s.final_rms_px,
                                 initial_cost=s.initial_pixel_cost, linear_solver=s.linear_solver,
                                 objective_final=s.final_cost, setup_s=s.setup_s, time_in=dict(s.time_in),
                                 trace=tuple(TracePoint(r.iteration, r.accepted, r.wall_s, r.cost) for r in s.trace))

    settings = dataclasses.asdict(dataclasses.replace(options, param=param))
    settings.update(threads=options.blas_threads, threads_kind="BLAS (threadpoolctl); the solver itself is one "
                    "Python thread")
    return _Solver(param, SolverKind.OURS, settings, fn)


def _ceres_solver(base, options: BAOptions, which: str, linear_solver: str, threads: int,
                  max_s: float) -> _Solver:
    from polarref.ba.peers import run_pycolmap

    cs = ceres_settings(options, which, threads, linear_solver, max_s)

    def fn(limit: int | None, trace: bool = False) -> SolveRun:
        r = run_pycolmap(base.copy(), options, cs if limit is None else cs.with_iterations(limit),
                         trace=trace)
        shift = r.final_cost - r.reported_cost   # Ceres' own cost onto the recomputed one (docstring)
        return SolveRun.measured(final_cost=r.final_cost, wall_s=r.wall_s, iterations=r.iterations,
                                 accepted=r.accepted_iterations, rejected=r.rejected_iterations,
                                 termination=r.termination, final_rms_px=r.final_rms_px, initial_cost=r.initial_cost,
                                 reported_cost=r.reported_cost, behind_camera=r.behind_camera,
                                 linear_solver=str(r.settings.get("linear_solver_used", "")),
                                 trace_cost_shift=shift if trace else None, settings_used=dict(r.settings),
                                 trace=tuple(TracePoint(i, ok, t, c + shift) for i, ok, t, c in r.trace if i > 0))

    return _Solver(cs.name, SolverKind.CERES, dataclasses.asdict(cs), fn)


def _trace_time(run: SolveRun, target: float) -> tuple[float, int] | None:
    """(seconds, LM steps) at the first accepted step of the run's trace at or below target."""
    for p in run.trace:
        if p.accepted and p.cost <= target:
            return float(p.wall_s), int(p.iteration)   # iterations are numbered from 1
    return None


def _bisect_limit(sol: _Solver, full: SolveRun, target: float) -> int | None:
    """Smallest iteration limit whose solve ends at or below ``target`` (None: the full run misses it)."""
    if full.final_cost > target:
        return None
    lo, hi = 0, max(int(full.iterations), 1)       # cost(lo) > target >= cost(hi)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if sol.fn(mid).final_cost <= target:
            hi = mid
        else:
            lo = mid
    return hi


def solver_names() -> list[str]:
    """Every solver the bench runs, by name: our forms, then the Ceres settings."""
    return [*PARAMS, *(ceres_settings(BAOptions(), w, t, ls).name for w, ls, t in CERES)]


def _solvers(base, options: BAOptions, ceres_max_s: float,
             only: tuple = ()) -> tuple[list[_Solver], list[SolverRow]]:
    """Our four forms and the Ceres settings that apply at this size (``only``: just these
    names; the others get a row saying so); rows for those skipped."""
    solvers = [_ours_solver(base, options, p) for p in PARAMS if not only or p in only]
    skipped = [SolverRow(p, SolverKind.OURS, error="not run (--solvers)")
               for p in PARAMS if only and p not in only]
    for which, ls, t in CERES:
        s = _ceres_solver(base, options, which, ls, t, ceres_max_s)
        if only and s.name not in only:
            skipped.append(SolverRow(s.name, s.kind, s.settings, error="not run (--solvers)"))
        elif ls == "DENSE_SCHUR" and base.num_cameras > DENSE_SCHUR_MAX_CAMERAS:
            skipped.append(SolverRow(s.name, s.kind, s.settings, error=(
                f"skipped: DENSE_SCHUR above {DENSE_SCHUR_MAX_CAMERAS} cameras "
                f"(dense {6 * base.num_cameras}^2 reduced matrix)")))
        else:
            solvers.append(s)
    return solvers, skipped


@dataclass
class _Work:
    """One solver's measurements while the bench runs (frozen into a SolverRow at the end)."""

    solver: _Solver
    full_runs: list[SolveRun] = field(default_factory=list)
    target_runs: list[SolveRun] = field(default_factory=list)
    limit: int | None = None
    error: str | None = None

    @property
    def name(self) -> str:
        return self.solver.name


def _full_run(s: _Solver, cache: Path | None = None) -> SolveRun:
    """The first full run, in a forked child so its peak memory is its own (ba_measure). With
    ``cache`` (a folder per problem) a finished run is stored there and reused by a later bench
    of the same problem: a bench of hours resumes from its finished solvers, and solvers can be
    measured by separate processes, then tabulated together."""
    from polarref.bench.ba_measure import cached, forked

    def first() -> SolveRun:
        load = os.getloadavg()[0]
        full, peak = forked(lambda: s.fn(None, trace=True))
        return dataclasses.replace(full.with_peak(peak), load_1min=load, load_1min_end=os.getloadavg()[0])

    full = first() if cache is None else cached(cache / f"{s.name}.pkl", first)
    if full.settings_used is not None:
        s.settings = full.settings_used
    return dataclasses.replace(full, settings_used=None)


def _tau_targets(initial: float, best: float) -> dict[str, TauTarget]:
    return {f"{tau:.0e}": TauTarget(tau, best + tau * (initial - best)) for tau in TAUS}


def _tau_times(runs: list[SolveRun], targets: dict[str, TauTarget]) -> dict[str, TauTime]:
    """Per tau, the time to its target over the full runs (empty Stats unless every run reaches it)."""
    out = {}
    for key, t in targets.items():
        hits = [_trace_time(x, t.target_cost) for x in runs]
        ok = [h for h in hits if h is not None]
        out[key] = TauTime(Stats.of([h[0] for h in ok] if len(ok) == len(hits) else []),
                           ok[0][1] if ok else None)
    return out


@dataclass(frozen=True)
class _Targets:
    best: float
    common: float
    target: float
    bisect: bool


def _targets(work: list[_Work], bisect: bool) -> _Targets:
    finals = [w.full_runs[0].final_cost for w in work if w.full_runs and w.solver.pixel_objective]
    best = min(finals)
    common = max(c for c in finals if c <= best * (1 + CONVERGED_REL))
    return _Targets(best, common, common * (1 + TARGET_REL), bisect)


def _limit(w: _Work, tg: _Targets) -> int | None:
    """Smallest iteration limit at the common target: from the trace (ours, or any solver above
    bisect_max_obs), else by bisection; None where it is not reached or not measured."""
    full = w.full_runs[0]
    if w.solver.pixel_objective and (not tg.bisect or w.solver.kind is SolverKind.OURS):
        hit = _trace_time(full, tg.target)
        return None if hit is None else hit[1]
    return _bisect_limit(w.solver, full, tg.target) if tg.bisect else None


def _row(w: _Work, tg: _Targets, taus: dict[str, TauTarget]) -> SolverRow:
    """The finished row of a solver that ran."""
    s, full = w.solver, w.full_runs[0]
    if tg.bisect:
        tr = w.target_runs
        reached = bool(tr) and all(x.final_cost <= tg.target for x in tr)
        to_target = Stats.of([x.wall_s for x in tr] if reached else [])
        its = IterationsToTarget(tr[0].iterations, tr[0].accepted, tr[0].rejected) if tr else None
        kind = None
    else:
        hits = [_trace_time(x, tg.target) for x in w.full_runs] if s.pixel_objective else [None]
        reached = all(h is not None for h in hits)
        to_target = Stats.of([h[0] for h in hits] if reached else [])
        its = IterationsToTarget(hits[0][1]) if reached else None
        kind = "iteration trace of the full runs"
    ours = s.kind is SolverKind.OURS
    per_it = Stats.of([(x.wall_s - x.setup_s) / x.accepted for x in w.full_runs if x.accepted]) if ours else None
    return SolverRow(
        s.name, s.kind, s.settings, full_runs=tuple(x.without_trace() for x in w.full_runs),
        target_runs=tuple(x.without_trace() for x in w.target_runs), pixel_objective=s.pixel_objective,
        iterations_limit_to_target=w.limit, reached_target=reached, time_to_target_s=to_target,
        time_to_target_kind=kind, iterations_to_target=its,
        warm_first_step_s=full.trace[0].wall_s if ours and full.trace else None,
        wall_s=Stats.of([x.wall_s for x in w.full_runs]), final_cost=full.final_cost,
        iterations=full.iterations, peak_rss_mib=full.peak_rss_mib, s_per_accepted_iteration=per_it,
        tau=_tau_times(w.full_runs, taus) if s.pixel_objective and taus else None,
        set_common_cost=s.pixel_objective and full.final_cost <= tg.best * (1 + CONVERGED_REL))


def _scipy_row(base, options: BAOptions, scipy_max_obs: int, target: float) -> SolverRow:
    from threadpoolctl import threadpool_limits

    from polarref.ba.peers import run_scipy

    if base.num_observations > scipy_max_obs:
        return SolverRow("scipy", SolverKind.SCIPY, error=f"skipped: {base.num_observations} "
                         f"observations > --scipy-max-obs {scipy_max_obs}")
    # once, same BLAS setting as ours; wall time to convergence (no trace: an upper bound)
    with threadpool_limits(limits=options.blas_threads, user_api="blas"):
        sp = run_scipy(base.copy(), options)
    ok = sp.final_cost <= target
    run = SolveRun.measured(final_cost=sp.final_cost, wall_s=sp.wall_s, iterations=sp.iterations,
                            termination=sp.termination, final_rms_px=sp.final_rms_px, initial_cost=sp.initial_cost,
                            reported_cost=sp.reported_cost, behind_camera=sp.behind_camera, name=sp.name)
    return SolverRow("scipy", SolverKind.SCIPY, {
        "method": "trf", "tr_solver": "lsmr", "ftol": options.function_tolerance, "xtol": 1e-10, "gtol": 1e-10,
        "max_nfev": options.max_iterations, "threads": options.blas_threads},
        full_runs=(run,), final_cost=sp.final_cost, iterations=sp.iterations, wall_s=Stats.of([sp.wall_s]),
        reached_target=ok, pixel_objective=True, time_to_target_s=Stats.of([sp.wall_s] if ok else []),
        time_to_target_kind="wall time of the whole run (upper bound)")


def _measure(solvers: list[_Solver], spec: str, cache: Path | None) -> list[_Work]:
    """Every solver's first full run (they fix the common cost)."""
    work = []
    for s in solvers:
        log.info("bench %s: %s", spec, s.name)
        w = _Work(s)
        try:
            w.full_runs.append(_full_run(s, cache))
        except Exception as exc:  # a failing solver is reported, not fatal to the bench
            w.error = f"{type(exc).__name__}: {exc}"
        work.append(w)
    return work


def _repeats(work: list[_Work], tg: _Targets, repeat: int) -> None:
    """The limits to the common target, then the repeats, interleaved so load changes hit every
    solver alike."""
    ran = [w for w in work if w.error is None]
    for w in ran:
        w.limit = _limit(w, tg)
    for rep in range(repeat):
        for w in ran:
            if rep > 0:
                w.full_runs.append(dataclasses.replace(w.solver.fn(None, trace=True), settings_used=None))
            if w.limit is not None and tg.bisect:
                w.target_runs.append(w.solver.fn(w.limit).without_trace())


def run_problem(spec: str, options: BAOptions, scipy_max_obs: int = SCIPY_MAX_OBS, repeat: int = 1,
                bisect_max_obs: int = BISECT_MAX_OBS, ceres_max_s: float = CERES_MAX_S,
                cold: bool = True, only: tuple = (), cache: Path | None = None) -> ProblemResult:
    from polarref.ba.loaders import load_problem

    load = os.getloadavg()[0]  # the machine is shared: say how busy it was
    base, _ = load_problem(_resolve(spec))
    prepare(base)
    solvers, skipped = _solvers(base, options, ceres_max_s, only)
    work = _measure(solvers, spec, None if cache is None else cache / _slug(spec))
    tg = _targets(work, base.num_observations <= bisect_max_obs)
    _repeats(work, tg, repeat)
    by = {w.name: w for w in work if w.error is None}
    own = _ceres_own_cost(by, tg.target, repeat) if tg.bisect else None
    initial = by["euclidean"].full_runs[0].initial_cost if "euclidean" in by else None
    taus = _tau_targets(initial, tg.best) if initial is not None else {}
    rows = [SolverRow(w.name, w.solver.kind, w.solver.settings, error=w.error) if w.error is not None
            else _row(w, tg, taus) for w in work]
    rows += skipped
    rows.append(_scipy_row(base, options, scipy_max_obs, tg.target))
    rows, fastest, fastest_s, tau_summary = _summarize(rows, taus)
    cold_rec = None
    if cold:
        from polarref.bench.ba_measure import cold_process
        cold_rec = cold_process(_resolve(spec))
    return ProblemResult(
        problem=spec, num_cameras=base.num_cameras, num_points=base.num_points,
        num_observations=base.num_observations, initial_cost=initial, best_final_cost=tg.best,
        common_final_cost=tg.common, target_cost=tg.target, tau_targets=taus,
        time_to_target_method="bisection + timed solves" if tg.bisect else "iteration traces",
        rows=tuple(rows), repeat=repeat, load_1min=load, load_1min_end=os.getloadavg()[0],
        fastest_ceres=fastest, fastest_ceres_time_to_target_s=fastest_s, tau_summary=tau_summary,
        roofline=_roofline(base, by["euclidean"]) if "euclidean" in by else None,
        cold_process=cold_rec, ceres_own_cost=own, ceres_scope=_ceres_scope(rows, ceres_max_s, options))


def _ceres_scope(rows: list[SolverRow], cap_s: float, options: BAOptions) -> str | None:
    """Issue 35's scope rule ("as large as Ceres finishes in 10 minutes"): where no Ceres setting
    that ran reached the common target within its time cap (each stopped at the cap, or
    stopped early above the target), the problem is past that limit and there is no ratio to
    Ceres; said so with each setting's stop, never a ratio."""
    ceres = [r for r in rows if r.kind is SolverKind.CERES and r.error is None and r.full_runs]
    if not ceres or any(r.reached_target for r in ceres):
        return None

    def stop(r: SolverRow) -> str:
        run = r.full_runs[0]
        capped = run.termination == "NO_CONVERGENCE" and run.iterations < options.max_iterations
        how = f"stopped at the {cap_s:.0f} s cap" if capped else f"stopped ({run.termination}) above the target"
        return f"{r.solver} {how} after {run.iterations} iterations at cost {run.final_cost:.6g}"

    return (f"Ceres did not finish in {cap_s:.0f} s: no setting reached the common cost within its cap; "
            + "; ".join(stop(r) for r in ceres))


def _roofline(base, w: _Work) -> Roofline:
    """Analytic flops of our Euclidean LM step and the rates its stages reached (medians over
    the full runs: flops x LM steps / time in the stage)."""
    from polarref.ba.roofline import lm_flops, schur_traffic

    runs = w.full_runs
    dense = "dense Cholesky" in runs[0].linear_solver
    f = lm_flops(base.obs_cam, base.obs_pt, base.cam_mask.any(1), base.num_points, dense)

    def count(x: SolveRun, builds: bool) -> int:  # builds: the first, then one per accepted step that did not stop
        if not builds:
            return x.iterations
        return x.accepted + (0 if x.termination == "function_tolerance" else 1)

    def rate(flops_per: float | None, stage: str, builds: bool = False) -> Stats | None:
        if flops_per is None:
            return None
        return Stats.of([flops_per * count(x, builds) / x.run.stage_runtime_s[stage] / 1e9
                         for x in runs if x.run.stage_runtime_s.get(stage, 0) > 0 and x.iterations])

    stages = ("evaluate", "normal_equations", "schur", "solve")
    tr = schur_traffic(base.obs_cam, base.obs_pt, base.cam_mask.any(1))
    return Roofline("euclidean", runs[0].linear_solver, FlopCounts(f.build, f.schur, f.factorisation),
                    f.num_unknowns, StageRates(rate(f.build, "normal_equations", builds=True),
                                               rate(f.schur, "schur"), rate(f.factorisation, "solve")),
                    {k: Stats.of([x.run.stage_runtime_s.get(k, 0.0) for x in runs]) for k in stages},
                    SchurBytes(tr.compulsory_bytes, tr.per_update_bytes, tr.pairs, tr.blocks))


def _ceres_own_cost(by: dict[str, _Work], target: float, repeat: int) -> OwnCost | None:
    """Euclidean vs Ceres on the Euclidean objective where the common target leaves our
    Euclidean form or every Ceres setting without a time (the fake pile: Ceres stops at
    ~1e5 with points behind cameras, Euclidean LM at 227, parallax at 172): the target is then
    the best Ceres final cost + TARGET_REL, and the time to it is measured as for the common
    target (smallest iteration limit, a complete solve timed in every repeat)."""
    ceres = [n for n, w in by.items() if w.solver.kind is SolverKind.CERES]
    if "euclidean" not in by or not ceres:
        return None
    if by["euclidean"].limit is not None and any(by[n].limit is not None for n in ceres):
        return None
    own = min(by[n].full_runs[0].final_cost for n in ceres) * (1 + TARGET_REL)
    names = ["euclidean", *ceres]
    limits = {}
    for name in names:
        full = by[name].full_runs[0]
        hit = _trace_time(full, own)
        limits[name] = (None if hit is None else hit[1]) if full.trace else _bisect_limit(by[name].solver, full, own)
    runs: dict[str, list[SolveRun]] = {n: [] for n in names}
    for _ in range(repeat):   # interleaved, as the common-target runs
        for name in names:
            if limits[name] is not None:
                runs[name].append(by[name].solver.fn(limits[name]).without_trace())
    rows = {}
    for name in names:
        ok = bool(runs[name]) and all(x.final_cost <= own for x in runs[name])
        rows[name] = OwnCostRow(limits[name], tuple(runs[name]),
                                Stats.of([x.wall_s for x in runs[name]] if ok else []))
    t = {n: r.time_to_target_s.median for n, r in rows.items()}
    cer = {n: v for n, v in t.items() if n != "euclidean" and v is not None}
    fastest = min(cer, key=cer.get) if cer else None
    return OwnCost(own, "common target not reached by our Euclidean form or by any "
                   f"Ceres setting (common target {target:.6g})", rows, fastest,
                   t["euclidean"] / cer[fastest] if fastest and t["euclidean"] is not None else None)


def _fastest(times: dict[str, float | None]) -> tuple[str | None, dict[str, float | None]]:
    """The fastest Ceres setting of {solver: seconds or None} and every solver's ratio to it."""
    ceres = {n: v for n, v in times.items() if n.startswith("ceres-") and v is not None}
    fastest = min(ceres, key=ceres.get) if ceres else None
    return fastest, {n: (v / ceres[fastest] if fastest and v is not None else None) for n, v in times.items()}


def _summarize(rows: list[SolverRow], taus: dict[str, TauTarget]
               ) -> tuple[list[SolverRow], str | None, float | None, dict[str, TauSummary]]:
    """The rows with their ratios to the fastest Ceres setting and (ours) per-iteration cost
    relative to the Euclidean form's; the fastest Ceres setting and its time; per tau the same."""
    per = {r.solver: r.s_per_accepted_iteration.median for r in rows if r.s_per_accepted_iteration}
    t = {r.solver: (r.time_to_target_s.median if r.time_to_target_s else None) for r in rows}
    fastest, ratio = _fastest(t)
    rows = [dataclasses.replace(
        r, ratio_to_fastest_ceres=ratio.get(r.solver),
        per_iteration_vs_euclidean=(per[r.solver] / per["euclidean"]
                                    if per.get(r.solver) is not None and per.get("euclidean") else None))
        for r in rows]
    tau_summary = {}
    for key in taus:
        tt = {r.solver: (r.tau[key].time_s.median if r.tau and key in r.tau else None) for r in rows}
        f, rr = _fastest(tt)
        tau_summary[key] = TauSummary(f, tt.get(f) if f else None, tt, rr)
    return rows, fastest, t.get(fastest) if fastest else None, tau_summary


def _settings(options: BAOptions, repeat: int, bisect_max_obs: int, ceres_max_s: float, only: tuple,
              kernels: KernelSettings, heap: str) -> BenchSettings:
    return BenchSettings(
        repeat=repeat, target=f"common final cost + {TARGET_REL:.1%}", converged_rel=CONVERGED_REL,
        ours=dataclasses.asdict(options),
        ceres=tuple(f"{w} tolerances, {ls or 'COLMAP rule'}, {t} thread(s)" for w, ls, t in CERES),
        kernels=kernels, heap=heap, taus=TAUS, bisect_max_obs=bisect_max_obs, ceres_max_s=ceres_max_s,
        solvers=list(only) or "all", dense_schur_max_cameras=DENSE_SCHUR_MAX_CAMERAS)


def _machine() -> MachineRates:
    from polarref.ba.roofline import gemm_gflops, triad_gbs

    load = os.getloadavg()[0]
    gemm = {str(t): gemm_gflops(t) for t in (1, 2)}
    load_triad = os.getloadavg()[0]
    return MachineRates(gemm, "numpy float64 1500x1500 @ 1500x1500, best of 3, BLAS threads by threadpoolctl",
                        load, triad_gbs(), load_triad)


def _previous(path: Path, merge: bool) -> tuple[ProblemResult, ...]:
    """With ``merge``, the problems of an existing bench.json, each keeping its run's provenance."""
    from polarref.bench.ba_records import read_json_doc

    if not (merge and path.exists()):
        return ()
    old = read_json_doc(path)
    return tuple(dataclasses.replace(r, environment=r.environment or old.environment,
                                     machine=r.machine or old.machine) for r in old.problems)


def run_bench(problems, out_dir: Path, options: BAOptions = BAOptions(),
              scipy_max_obs: int = SCIPY_MAX_OBS, repeat: int = 1,
              merge: bool = False, bisect_max_obs: int = BISECT_MAX_OBS,
              ceres_max_s: float = CERES_MAX_S, cold: bool = True, only: tuple = (),
              cache: Path | None = None) -> BenchDoc:
    """Run the problems; with ``merge`` keep the other problems of an existing bench.json
    (a problem run again replaces its old entry). bench.json, bench.md and the performance
    profiles (profiles.png) in ``out_dir``, written after every problem."""
    from polarref.ba import kernels
    from polarref.bench.ba_measure import kernel_load_s
    from polarref.bench.ba_report import write_report
    from polarref.core.heap import keep_heap
    from polarref.core.provenance import collect_record

    for spec in problems:   # a missing problem fails before minutes of measurements
        _resolve(spec)
    # compile (or load) the kernels before any timed solve; the time is recorded, not hidden
    fast = kernels.use_kernels(options.kernels)
    cold_load = kernel_load_s() if fast and cold else None   # a fresh interpreter's load
    heap = keep_heap()  # per-iteration arrays kept mapped (heap.py); recorded below
    warm = kernels.warm_up() if fast else 0.0
    previous = _previous(out_dir / "bench.json", merge)
    machine = _machine()
    kern = KernelSettings("numba" if fast else "numpy", kernels.numba_version(), warm, cold_load, 1)
    doc = BenchDoc(collect_record(threads={"ours_blas": options.blas_threads or 0}),
                   _settings(options, repeat, bisect_max_obs, ceres_max_s, only, kern, heap), previous, machine)
    for spec in problems:
        t = time.perf_counter()
        res = run_problem(spec, options, scipy_max_obs, repeat, bisect_max_obs, ceres_max_s, cold, only, cache)
        res = dataclasses.replace(res, bench_s=time.perf_counter() - t, environment=doc.environment,
                                  machine=machine)
        log.info("bench %s done in %.1f s", spec, res.bench_s)
        doc = dataclasses.replace(doc, problems=tuple(r for r in doc.problems if r.problem != spec) + (res,))
        write_report(doc, out_dir)   # after every problem: an interrupted bench keeps what it measured
    return doc
