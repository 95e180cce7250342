"""``polarref compare``: run every method on one scene, score, run the claim experiments, report.

Stages (hloc style, each skipped if its output is already on disk and the inputs match):
prepare scene -> feature databases -> methods (isolated, sequential, timed) -> scoring ->
claims -> metrics.json -> report. Work products (databases, models, logs) live in
``OUT/runs/``; an existing OUT is updated in place, never wiped.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import shlex
import sys
import threading
import time
from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from polarref.camera import Camera
from polarref.core import execution
from polarref.compare.claims import scorecard as claims_mod
from polarref.compare.run import presets
from polarref.compare.run import scenes
from polarref.compare.report import view3d
from polarref.compare.run.presets import ComparePreset
from polarref.io.scene_folder import Scene
from polarref.compare.run import jobs
from polarref.compare.run.jobs import camera_to_json
from polarref.compare.run.methods import METHOD_NAMES, PAIRS, RUN_ORDER, MethodSpec, select
from polarref.core.isolated import JobOutcome, has_finished_result, run_isolated, run_isolated_with
from polarref.compare.run.scoring import Score, load_mesh, score
from polarref.compare.schema import (SCHEMA_VERSION, BATrace, Environment, MethodResult, MetricsFile, SceneInfo, save)
from polarref.core.errors import PolarrefError
from polarref.core.progress import track
from polarref.core.provenance import Provenance, collect_record
from polarref.model.colmap import read_model
from polarref.model.run import MethodRun
from polarref.core.status import RunStatus

if TYPE_CHECKING:
    from polarref.model import Reconstruction

log = logging.getLogger(__name__)

# Under a run budget (presets.ComparePreset.run_budget_s) every later method keeps this much,
# and the report this much.
MIN_METHOD_S = 8.0
REPORT_RESERVE_S = 12.0


@dataclass(frozen=True)
class CompareConfig:
    """One comparison run."""

    scene: str | None = None          # comet | uav | folder; None = comet
    preset: ComparePreset = presets.DEFAULT
    out: Path | None = None           # report folder; None = ./polarref-out/<scene>-<preset>
    methods: tuple[str, ...] = ()     # empty = all
    seed: int = 0                     # render seed and every method/experiment seed
    method_timeout_s: float | None = None   # None = the preset's
    budget_s: float | None = -1.0     # whole-run limit in s; -1 = the preset's, None = none
    claims: bool = True               # run the claim experiments
    command: str = ""                 # exact command line, recorded in the report
    overwrite: bool = False           # allow replacing a finished report folder (metrics.json present)
    dense: bool = False               # also run the dense stage (GT, ours-euclidean, ours-polar poses)


@dataclass
class _Context:
    scene: Scene
    runs: Path
    timeout: float
    seed: int
    preset: str                                      # ComparePreset.name (a JSON-able job argument)
    cache: Path                                      # shared feature/match cache of our SfM
    camera: Camera                                   # the fixed camera every job is given
    db_results: dict[str, tuple[JobOutcome, Path | None]] = field(default_factory=dict)  # shared stage -> (outcome, db)
    run: Callable | None = None                      # how a job runs; None: run_isolated, here
    locks: dict[str, threading.Lock] = field(default_factory=lambda: defaultdict(threading.Lock))
    reuse: bool = False                              # load finished jobs of an earlier run (no --overwrite)

    def job(self, *args) -> JobOutcome:
        return (self.run or run_isolated)(*args, reuse=self.reuse)


def default_out(scene: Scene, preset: ComparePreset) -> Path:
    """``./polarref-out/<scene>/`` in the working directory (never the committed ``reports/``)."""
    name = scene.name if scene.kind == "real" else scene.name.split("-")[0]
    return Path.cwd() / "polarref-out" / f"{name}-{preset.name}"


def _refuse_finished(out: Path, overwrite: bool) -> None:
    if (out / "metrics.json").is_file() and not overwrite:
        raise PolarrefError(f"{out} holds a finished comparison (metrics.json); replace it or choose another "
                            "output folder", option="overwrite")


def _shared(ctx: _Context, key: str):
    """Run (once per comparison) a stage several methods share; returns (outcome, extra)."""
    with ctx.locks[key]:  # methods running concurrently on a cluster wait for one shared run
        return _shared_once(ctx, key)


def _shared_once(ctx: _Context, key: str):
    if key in ctx.db_results:
        return ctx.db_results[key]
    common = dict(image_dir=str(ctx.scene.image_dir), camera=camera_to_json(ctx.camera))
    if key == "ours-features":
        job, kw, extra = jobs.ours_features, dict(preset=ctx.preset, cache_dir=str(ctx.cache)), None
    elif key == "db-pycolmap-sift":
        extra = ctx.runs / key / "database.db"
        job, kw = jobs.pycolmap_sift_db, dict(image_names=ctx.scene.image_names,
                                                                 db_path=str(extra), seed=ctx.seed,
                                                                 num_threads=PYCOLMAP_THREADS)
    elif key == "db-ours":
        feat, _ = _shared(ctx, "ours-features")
        if feat.status != RunStatus.OK:
            ctx.db_results[key] = (feat, None)
            return ctx.db_results[key]
        extra = ctx.runs / key / "database.db"
        job, kw = jobs.ours_db, dict(preset=ctx.preset, cache_dir=str(ctx.cache),
                                                        db_path=str(extra))
    else:
        raise ValueError(key)
    outcome = ctx.job(job, {**common, **kw}, ctx.timeout, ctx.runs / key, "job")
    ctx.db_results[key] = (outcome, extra)
    return ctx.db_results[key]


def _run_method(ctx: _Context, spec: MethodSpec) -> tuple[MethodRun, Reconstruction | None]:
    """Run one method: its run (the shared stages' times included) and its model, or None."""
    run = MethodRun(spec.name, form=spec.ba, status=RunStatus.FAILED, timeout_s=ctx.timeout)
    work = ctx.runs / spec.name
    stages: dict[str, float] = {}
    prereqs = ["ours-features"] if spec.features == "ours" else []
    if spec.family == "pycolmap":
        prereqs.append("db-ours" if spec.features == "ours" else "db-pycolmap-sift")
    for key in prereqs:
        pre, db = _shared(ctx, key)
        if pre.status != RunStatus.OK:
            return dataclasses.replace(run, status=pre.status, reason=f"shared stage {key} failed: {pre.reason}"), None
        for k, v in pre.result.stage_runtime_s.items():
            stages[k if key != "db-ours" else f"pycolmap {k}"] = float(v)
    if spec.family == "pycolmap":
        outcome = ctx.job(jobs.pycolmap_map,
                          dict(db_path=str(db), image_dir=str(ctx.scene.image_dir), work_dir=str(work),
                               mapper=spec.mapper.split("-")[1], seed=ctx.seed,
                               num_threads=PYCOLMAP_THREADS),
                          ctx.timeout, work, "job")
    else:
        outcome = ctx.job(jobs.ours_sfm,
                          dict(image_dir=str(ctx.scene.image_dir), camera=camera_to_json(ctx.camera), ba=spec.ba,
                               work_dir=str(work), preset=ctx.preset, cache_dir=str(ctx.cache)),
                          ctx.timeout, work, "job")
    if outcome.status != RunStatus.OK:
        return dataclasses.replace(run, status=outcome.status, reason=outcome.reason), None
    stages.update(outcome.result.stage_runtime_s)
    run = dataclasses.replace(outcome.result, method=spec.name, form=spec.ba, status=RunStatus.OK, reason="",
                              timeout_s=ctx.timeout, stage_runtime_s={k: float(v) for k, v in stages.items()})
    try:
        rec = read_model(run.model_dir)
    except PolarrefError as exc:
        return dataclasses.replace(run, status=RunStatus.FAILED, reason=f"cannot read the method's model: {exc}"), None
    return run, rec


def _run_methods_on_cluster(executor, ctx: _Context, ordered: list[MethodSpec], timeout: float,
                            deadline: float | None) -> list[tuple[MethodRun, Reconstruction | None]]:
    """Every method as a task on the cluster at once (shared stages run once, first come).

    One thread per method waits for its task(s); the methods' own processes run on the workers.
    """
    ctx.run = functools.partial(run_isolated_with, executor)
    ctx.timeout = timeout if deadline is None else min(timeout, max(deadline - time.perf_counter(), 2.0))
    with ThreadPoolExecutor(max_workers=len(ordered) or 1) as pool:
        return list(pool.map(lambda spec: _run_method(ctx, spec), ordered))


def _scored(run: MethodRun, rec: Reconstruction, scene: Scene, mesh, seed: int,
            notes: list[str]) -> tuple[MethodRun, Score | None]:
    """The run with its model's ReconstructionMetrics, and the report's extras (None when scoring failed)."""
    try:
        s = score(rec, scene.gt, mesh, seed)
    except Exception as exc:  # scoring must not take the other methods down
        log.exception("scoring %s failed", run.method)
        return dataclasses.replace(run, status=RunStatus.FAILED,
                                   reason=f"scoring failed: {type(exc).__name__}: {exc}"), None
    notes += [f"{run.method}: {n}" for n in s.notes]
    run = dataclasses.replace(run, metrics=s.metrics)
    if s.metrics.registered_images == 0:
        run = dataclasses.replace(run, status=RunStatus.FAILED, reason="no image registered")
    return run, s


def method_result(spec: MethodSpec, run: MethodRun, s: Score | None, num_images: int) -> MethodResult:
    """The report's view of one method's run: its labels, status, timings and scores (metrics.json)."""
    res = MethodResult(name=spec.name, label=spec.label, family=spec.family, features=spec.features,
                       mapper=spec.mapper, ba=spec.ba, status=run.status, reason=run.reason,
                       # the method's runtime is known once its own job finished (its model written)
                       runtime_s=run.runtime_s if run.model_dir else None,
                       stage_runtime_s=dict(run.stage_runtime_s), timeout_s=run.timeout_s, num_images=num_images,
                       gt=s.gt if s is not None else None, plot=s.plot if s is not None else None)
    if run.metrics is not None:
        res.set_metrics(run.metrics)
    return res


PYCOLMAP_THREADS = 1   # pycolmap extraction, matching, mapping: one thread, so reruns repeat exactly


def _environment(cfg: CompareConfig, scene: Scene, timeout: float, total_s: float,
                 prov: Provenance) -> Environment:
    variant = scene.mitsuba_variant if scene.kind == "synthetic" else "not used (real images)"
    if scene.kind == "synthetic" and not variant:
        try:
            from synth.mitsuba_variant import selected_variant

            variant = selected_variant().variant
        except Exception as exc:  # the report must not fail for lack of a variant name
            variant = f"unknown ({type(exc).__name__})"
    return Environment(
        command=cfg.command or "polarref compare", created=datetime.now(timezone.utc).isoformat(timespec="seconds"),
        versions=prov.versions, cpu_count=prov.cpu_count, mitsuba_variant=variant,
        seeds={"scene": scene.seed, "methods": cfg.seed, "claims": cfg.seed}, preset=cfg.preset.name,
        method_timeout_s=timeout, total_runtime_s=total_s, git_commit=prov.git_commit,
        git_dirty=prov.git_dirty, cpu_model=prov.cpu_model, machine=prov.machine,
        platform=prov.platform, threads=prov.threads)


def run_compare(cfg: CompareConfig) -> tuple[Path, MetricsFile]:
    """Run the comparison and write OUT/metrics.json, OUT/report.md, OUT/report.html, OUT/figures/."""
    from polarref.compare.report.build import build_report
    t_start = time.perf_counter()
    # Taken before anything is written: regenerating a committed report must not mark the run dirty.
    prov = collect_record(threads={"pycolmap": PYCOLMAP_THREADS, "ba_blas": 1})
    specs = select(list(cfg.methods) or None)
    if cfg.out or cfg.scene is None or cfg.scene in scenes.SYNTHETIC:  # refuse before rendering
        _refuse_finished(Path(cfg.out) if cfg.out else
                         Path.cwd() / "polarref-out" / f"{cfg.scene or 'comet'}-{cfg.preset.name}", cfg.overwrite)
    scene = scenes.prepare(cfg.scene, cfg.preset, cfg.seed)
    out = Path(cfg.out) if cfg.out else default_out(scene, cfg.preset)
    if out.exists() and not out.is_dir():
        raise PolarrefError(f"output folder {out} exists and is not a directory")
    _refuse_finished(out, cfg.overwrite)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PolarrefError(f"cannot create report folder {out}: {exc}") from exc
    timeout = float(cfg.method_timeout_s or cfg.preset.method_timeout_s)
    ctx = _Context(scene, out / "runs", timeout, cfg.seed, cfg.preset.name, out / "runs" / "ours-features" / "cache",
                   camera=scene.camera, reuse=not cfg.overwrite)
    from polarref.metrics import scene_size

    resumed = ctx.reuse and has_finished_result(ctx.runs / "ours-features" / "job.result.json")
    if ctx.cache.is_dir() and not resumed:  # an earlier run's cache: the shared stage must be timed afresh
        for f in ctx.cache.iterdir():
            if f.is_file() and f.name.startswith(("features-", "matches-")):
                f.unlink()
    extent = scene_size(scene.gt) if scene.gt is not None else 0.0
    mesh = load_mesh(scene.mesh_path)
    notes: list[str] = []
    if any(s.features == "ours" and s.family == "pycolmap" for s in specs):
        notes.append("pycolmap-*-ours: our keypoints and our verified inlier matches (essential-matrix RANSAC "
                     "of polarref.sfm) are imported into a pycolmap database as CALIBRATED two-view "
                     "geometries, so pycolmap's mapper sees exactly our correspondences.")
    if scene.kind == "real" and scene.downscale != 1.0:
        notes.append(f"Images downscaled by {scene.downscale:g} (INTER_AREA) before every method; "
                     "intrinsics divided by the same factor (exact with the corner pixel origin).")
    budget = cfg.preset.run_budget_s if cfg.budget_s == -1.0 else cfg.budget_s
    claims_budget = cfg.preset.claims_budget_s if cfg.claims else 0.0
    # an unbounded claims budget (small preset) under an explicit --budget keeps the default's reserve
    reserve = claims_budget if claims_budget < float("inf") else presets.DEFAULT.claims_budget_s
    deadline = None if budget is None else t_start + budget - reserve - REPORT_RESERVE_S
    results: list[MethodResult] = []
    runs: dict[str, MethodRun] = {}
    view = view3d.new_view(scene.gt, scene.camera, mesh, cfg.seed) if scene.gt is not None else None

    def finish(spec: MethodSpec, run: MethodRun, rec: Reconstruction | None) -> None:
        s = None
        if rec is not None:
            run, s = _scored(run, rec, scene, mesh, cfg.seed, notes)
            if view is not None and run.ok:
                view3d.add_method(view, spec.name, spec.label, rec, scene.gt, cfg.seed)
        runs[spec.name] = run
        results.append(method_result(spec, run, s, len(scene.image_names)))

    ordered = sorted(specs, key=lambda m: RUN_ORDER.index(m.name))
    executor = execution.current()
    if not executor.in_process:
        for spec, (run, rec) in zip(ordered, _run_methods_on_cluster(executor, ctx, ordered, timeout, deadline)):
            finish(spec, run, rec)
        ordered = []
    for k, spec in enumerate(track(ordered, desc="methods", total=len(ordered))):
        ctx.timeout = timeout
        if deadline is not None:
            left = deadline - time.perf_counter() - MIN_METHOD_S * (len(ordered) - k - 1)
            ctx.timeout = min(timeout, max(left, 2.0))
        log.info("running %s (limit %.0f s)", spec.name, ctx.timeout)
        run, rec = _run_method(ctx, spec)
        if run.status == RunStatus.TIMEOUT and ctx.timeout < timeout:
            run = dataclasses.replace(run, reason=run.reason + f" (limit cut from {timeout:.0f} s by the "
                                                                f"{budget:.0f} s run budget)")
        finish(spec, run, rec)
        log.info("%s: %s %s", spec.name, results[-1].status, results[-1].reason)
    results.sort(key=lambda r: METHOD_NAMES.index(r.name))
    info = SceneInfo(name=scene.name, kind=scene.kind, source=scene.source, preset=scene.preset,
                     seed=scene.seed, num_images=len(scene.image_names), width=scene.camera.width,
                     height=scene.camera.height, camera_model=scene.camera.model,
                     camera_params=[float(p) for p in scene.camera.params], has_gt=scene.gt is not None,
                     has_mesh=scene.mesh_path is not None, downscale=scene.downscale,
                     render_s=scene.render_s, scene_extent=extent)
    metrics = MetricsFile(schema_version=SCHEMA_VERSION, scene=info,
                          environment=_environment(cfg, scene, timeout, 0.0, prov), methods=results,
                          pairs=[p for p in PAIRS if any(r.name == p.baseline for r in results)
                                 and any(r.name == p.candidate for r in results)],
                          claims=[], notes=notes, view3d=view)
    for spec in specs:
        run = runs.get(spec.name)
        if run is not None and run.final_ba_trace:
            metrics.ba_traces.append(BATrace(spec.ba, f"{scene.name}: final global BA of our SfM",
                                             list(run.final_ba_trace)))
    if cfg.dense:  # after the budgeted part: the dense stage has its own (benchmarked) cost
        from polarref.compare.run.dense import run_dense_stage

        metrics.dense = run_dense_stage(scene.root, {n: (runs[n].model_dir or None) if n in runs else None
                                                     for n in ("ours-euclidean", "ours-polar")}, out)
    if cfg.claims:
        c_budget = claims_budget
        if budget is not None:
            c_budget = max(0.0, min(claims_budget, t_start + budget - REPORT_RESERVE_S - time.perf_counter()))
        claims_mod.evaluate_into(metrics, ctx.runs, cfg.seed, c_budget, timeout, ctx.reuse)
    metrics.environment.run_budget_s = budget
    metrics.environment.total_runtime_s = time.perf_counter() - t_start
    save(metrics, out / "metrics.json")
    build_report(out, metrics)
    return out, metrics


def command_line(argv: list[str] | None = None) -> str:
    argv = sys.argv if argv is None else argv
    prog = "polarref" if argv and (argv[0].endswith("polarref") or argv[0].endswith("__main__.py")) else argv[0]
    return " ".join([prog, *map(shlex.quote, argv[1:])])


__all__ = ["CompareConfig", "run_compare"]
