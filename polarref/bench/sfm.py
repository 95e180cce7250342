"""``polarref bench sfm``: our SfM vs pycolmap incremental on the same images and pairs, vs views.

Level by construction (issue 34): the same images, the fixed GT intrinsics, the same image pairs
(our pairing, imported by pycolmap as its pair list; the SHA-256 of the list is in every cell)
and the same SIFT budget (``--max-features``, default 4096) for both. Each method runs in columns
of 1 and 2 cores: ours with its front end (features, matching, verification) on 1 and 2 worker
threads (:mod:`polarref.sfm.frontend`, the pipeline's default way to use every core; the mapper's BLAS
on as many threads), pycolmap with 1 and 2 threads. Tie points are counted by one rule for both
from the finished models: 3D points seen by >= 2 registered images, and a second column >= 3
(pycolmap's mapper drops two-view tracks by default, ours keeps them: both counts show it).

One *cell* is one variant (method and core count) on one view count, one repeat. Every cell runs
in its own child process, so its memory belongs to that method alone; every stage (features
and matching included) records its wall and CPU seconds and its own peak memory (the peak-RSS mark is
reset at each stage's start, workers included: :mod:`polarref.sfm.stages`). A cell writes
``OUT/cells/<variant>-v<N>-r<k>.json`` with its stages, tie points, GT errors, the load average
at its start and the method's settings (:class:`polarref.bench.records.MethodSettings`). Repeats
run interleaved (all cells once, then again) and the tables show median and range. A finished
cell is reused on the next run (resume); a cell made with other settings is refused unless
``--overwrite``. ``bench.json``, ``bench.md`` and ``bench.png`` are rebuilt from the cells
(:mod:`polarref.bench.sfm_report`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import resource
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.bench.records import (STAGES, BenchSfMSettings, FailedCell, MethodSettings, PeakMemory, SfMBench,
                                    SfMCell, flatten_settings, read_cell, variant_label, write)
from polarref.bench.sfm_report import write_outputs
from polarref.core import records
from polarref.core.errors import PolarrefError
from polarref.core.memory import maxrss_mb, vmhwm_mb
from polarref.core.provenance import collect_record
from polarref.core.status import RunStatus
from polarref.model import Reconstruction
from polarref.io.scene_folder import Scene, discover
from polarref.model.colmap import from_pycolmap
from polarref.model.run import MethodRun
from polarref.sfm.stages import StageClock, StageCost

log = logging.getLogger(__name__)

METHODS = ("ours", "pycolmap")
PARALLEL = (1, 2)   # ours: front-end worker threads; pycolmap: threads (the four columns of issue 34)
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@dataclass(frozen=True)
class Variant:
    """One column: a method on ``parallel`` workers (ours) or threads (pycolmap)."""

    method: str
    parallel: int = 1

    @property
    def label(self) -> str:
        return variant_label(self.method, self.parallel)


@dataclass(frozen=True)
class _MethodOutput:
    """What one method's run hands to the cell (in the cell's process)."""

    stages: tuple[StageCost, ...]
    rec: Reconstruction
    scene: Scene          # the images the method saw and the ground truth it is scored against
    pairs: int
    pairs_sha256: str
    settings: MethodSettings


def scene_root(settings: BenchSfMSettings, views: int) -> Path:
    """Render (or reuse from the cache) the scene with ``views`` views; returns its folder."""
    try:
        from synth.config import preset
        from synth.render import code_version, render_scene
    except ImportError as exc:
        raise PolarrefError(f"cannot render the {settings.scene} scene: synth is not available ({exc})") from exc
    from polarref.core.data import cache_root

    cfg = preset(settings.scene, settings.preset, seed=settings.seed, views=int(views))
    # the name polarref compare and the tests use: the digest covers the view count
    root = cache_root() / "scenes" / f"{settings.scene}-{settings.preset}-seed{settings.seed}-{cfg.digest(code_version())}"
    result = render_scene(settings.scene, root, cfg)
    if result.rendered:
        log.info("rendered %d views into %s in %.1f s", result.rendered, root, result.total_seconds)
    return root


def pairs_for(num_images: int, settings: BenchSfMSettings) -> list[tuple[int, int]]:
    from polarref.sfm.matching import MatchConfig, select_pairs

    return select_pairs(num_images, MatchConfig(pairing=settings.pairing, sequential_overlap=settings.overlap))


def _pairs_digest(names: list[str], pairs) -> str:
    return hashlib.sha256("".join(f"{names[i]} {names[j]}\n" for i, j in pairs).encode()).hexdigest()


def _cpu_seconds() -> float:
    """This process's CPU seconds and its finished children's (the Dask workers, once shut down)."""
    r, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return float(r.ru_utime + r.ru_stime + c.ru_utime + c.ru_stime)


def peak_memory_mb() -> PeakMemory:
    """Peak resident memory of this process: ru_maxrss and /proc VmHWM (MiB; None if unknown)."""
    return PeakMemory(maxrss_mb(), vmhwm_mb())


# ---- one cell (child process) ------------------------------------------------------------------
def open_scene(root: Path) -> Scene:
    """The rendered scene at ``root`` as the one Scene record: its images (sorted names), the
    fixed camera of the render and the ground truth (``root/gt``)."""
    from synth.scene import load_scene

    found = discover(root)
    return dataclasses.replace(found, name=root.name, kind="synthetic", camera=load_scene(root).polarref_camera(),
                               gt=found.read_ground_truth())


def _ours_config(settings: BenchSfMSettings, parallel: int = 1):
    from polarref.sfm.pipeline import PRESETS

    base = PRESETS["default"]
    return dataclasses.replace(
        base, use_cache=False, threads=parallel,
        features=dataclasses.replace(base.features, max_num_features=settings.max_num_features),
        matching=dataclasses.replace(base.matching, pairing=settings.pairing, sequential_overlap=settings.overlap))


def _run_ours(root: Path, settings: BenchSfMSettings, parallel: int) -> _MethodOutput:
    """Our pipeline in this process, its front end on ``parallel`` threads (polarref.sfm.frontend)."""
    from polarref.sfm.pipeline import run_sfm

    scene = open_scene(root)
    names = scene.image_names
    config = _ours_config(settings, parallel)
    res = run_sfm(scene.image_dir, None, config, camera=scene.camera, gt=scene.gt)
    pairs = pairs_for(len(names), settings)
    ms = MethodSettings("ours", parallel, parallel, config.features.max_num_features, config.features.max_image_size,
                        False, f"{settings.pairing}, overlap {settings.overlap}",
                        flatten_settings(dataclasses.asdict(config)))
    return _MethodOutput(res.stages, res.reconstruction, scene, len(pairs), _pairs_digest(names, pairs), ms)


def _run_pycolmap(root: Path, settings: BenchSfMSettings, parallel: int, work: Path) -> _MethodOutput:
    from polarref.peers.colmap_sfm import (ColmapSfMOptions, extract_sift, incremental_options, match_sift,
                                           run_mapper, sift_options)

    scene = open_scene(root)
    names = scene.image_names
    pairs = pairs_for(len(names), settings)
    opts = ColmapSfMOptions(seed=settings.seed, num_threads=parallel, max_num_features=settings.max_num_features)
    db = work / "database.db"
    pairs_txt = work / "pairs.txt"
    pairs_txt.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
    # The same extraction and imported-pair matching as the twin comparison (one code path).
    clock = StageClock()
    clock.start("features")
    extract_sift(scene.image_dir, scene.camera, db, opts, image_names=names, overwrite=True)
    clock.stop()
    clock.start("matching")
    match_sift(db, opts, pairs_txt)
    clock.stop()
    clock.start("mapping")
    run = run_mapper(db, scene.image_dir, work / "sparse", "incremental", opts)
    clock.stop()
    if run.reconstruction is None:
        raise PolarrefError("pycolmap incremental mapping registered no images")
    extraction, matching = sift_options(opts)
    mapper = incremental_options(opts)
    ms = MethodSettings("pycolmap", parallel, parallel, opts.max_num_features, opts.max_image_size,
                        bool(mapper.triangulation.ignore_two_view_tracks),
                        f"imported pair list ({settings.pairing}, overlap {settings.overlap})",
                        flatten_settings({"colmap_sfm_options": dataclasses.asdict(opts),
                                          "incremental_options": mapper.todict(),
                                          "extraction_options": extraction.todict(),
                                          "matching_options": matching.todict()}))
    return _MethodOutput(tuple(clock.stages), from_pycolmap(run.reconstruction), scene, len(pairs),
                         _pairs_digest(names, pairs), ms)


def tie_points_seen_by(rec: Reconstruction, min_images: int) -> int:
    """3D points whose track holds >= ``min_images`` distinct registered images (one rule for both methods)."""
    registered = np.array(sorted(rec.images), np.int64)
    n = 0
    for p in rec.points3D.values():
        ids = np.unique(np.asarray(p.track, np.int64).reshape(-1, 2)[:, 0])
        n += int(np.isin(ids, registered).sum() >= min_images)
    return n


def run_cell(variant: Variant, root: Path, settings: BenchSfMSettings, work: Path, repeat: int = 1) -> SfMCell:
    """Run one method variant on one scene here and return the cell record."""
    from polarref import metrics as M

    load = os.getloadavg()
    t0 = time.perf_counter()
    got = (_run_ours(root, settings, variant.parallel) if variant.method == "ours"
           else _run_pycolmap(root, settings, variant.parallel, work))
    wall = time.perf_counter() - t0
    m = M.evaluate(got.rec, gt=got.scene.gt, num_images=len(got.scene.image_names))
    stages_s = {s.stage: float(s.wall_s) for s in got.stages if s.stage in (*STAGES[variant.method], "ba")}
    peak = peak_memory_mb()
    run = MethodRun(variant.method, status=RunStatus.OK, stage_runtime_s=stages_s, wall_s=wall,
                    peak_rss_mb=peak.ru_maxrss_mb, registered=m.registered_images)
    return SfMCell(
        run=run, views=len(got.scene.image_names), vmhwm_mb=peak.vmhwm_mb,
        # CPU seconds of the whole cell process and its workers (imports and scoring included):
        # on a loaded machine a steadier figure than wall time
        cpu_s=_cpu_seconds(),
        tie_points=m.tie_points, observations=m.reprojected_px,
        mean_track_length=m.mean_track_length, mean_reprojection_error_px=m.mean_reprojection_error_px,
        rotation_error_deg_mean=None if m.gt is None else m.gt.rotation_error_deg_mean,
        center_error_rel_mean=None if m.gt is None else m.gt.center_error_rel_mean,
        pairs=got.pairs, pairs_sha256=got.pairs_sha256, bench_settings=settings, method_settings=got.settings,
        scene_root=str(root), environment=collect_record(seeds={"seed": settings.seed},
                                                         threads={"all_stages": variant.parallel}),
        parallel=variant.parallel, repeat=repeat, tie_points_2v=tie_points_seen_by(got.rec, 2),
        tie_points_3v=tie_points_seen_by(got.rec, 3), stages=got.stages, load_average=tuple(load))


def _child(argv: list[str]) -> int:
    """``python -m polarref.bench.sfm METHOD PARALLEL REPEAT SCENE_ROOT SETTINGS_JSON OUT_JSON`` (one cell)."""
    import tempfile

    import cv2

    method, parallel, repeat, root, settings_json, out = argv
    cv2.setNumThreads(int(parallel))
    settings = records.from_dict(BenchSfMSettings, json.loads(settings_json), label="bench settings")
    with tempfile.TemporaryDirectory(prefix="bench-sfm-") as work:
        cell = run_cell(Variant(method, int(parallel)), Path(root), settings, Path(work), int(repeat))
    write(cell, Path(out))
    return 0


# ---- the sweep (parent) ------------------------------------------------------------------------
def cell_path(out: Path, variant: Variant, views: int, repeat: int = 1) -> Path:
    return out / "cells" / f"{variant.label}-v{views}-r{repeat}.json"


def load_cell(path: Path, settings: BenchSfMSettings) -> SfMCell | None:
    """A finished cell made with ``settings`` (None: absent); PolarrefError when it differs."""
    if not path.is_file():
        return None
    try:
        cell = read_cell(path)
    except records.RecordError as exc:
        raise PolarrefError(f"unreadable bench cell ({exc}); delete it or use --overwrite") from exc
    if cell.bench_settings != settings:
        raise PolarrefError(f"{path} was made with other settings ({dataclasses.asdict(cell.bench_settings)}); "
                            "use --overwrite or another --out", option="overwrite")
    return cell


def _log_line(out: Path, text: str) -> None:
    log.info(text)
    with open(out / "bench.log", "a", encoding="utf-8") as fh:
        fh.write(f"{time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())} {text}\n")


def _spawn(variant: Variant, repeat: int, root: Path, settings: BenchSfMSettings, path: Path,
           timeout_s: float | None) -> None:
    env = dict(os.environ, **{v: str(variant.parallel) for v in THREAD_VARS})
    cmd = [sys.executable, "-m", "polarref.bench.sfm", variant.method, str(variant.parallel), str(repeat), str(root),
           json.dumps(dataclasses.asdict(settings)), str(path)]
    try:
        r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired as exc:
        raise PolarrefError(f"bench cell {variant.label} ran past {timeout_s:.0f} s") from exc
    if r.returncode != 0:
        tail = (r.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise PolarrefError(f"bench cell {variant.label} on {root.name} failed: {tail}")


def variants(methods: tuple[str, ...] = METHODS, parallel: tuple[int, ...] = PARALLEL) -> list[Variant]:
    return [Variant(m, p) for p in parallel for m in methods]


def _one(out: Path, variant: Variant, n: int, repeat: int, settings: BenchSfMSettings, overwrite: bool,
         timeout_s: float | None, roots: list[Path], report_only: bool = False) -> SfMCell | FailedCell | None:
    path = cell_path(out, variant, n, repeat)
    name = f"{variant.label} v{n} r{repeat}"
    cell = None if overwrite else load_cell(path, settings)
    if cell is not None:
        _log_line(out, f"{name}: finished cell reused ({cell.total_s:.1f} s)")
        return cell
    if report_only:
        _log_line(out, f"{name}: not run (--report-only)")
        return None
    root = roots[0] if roots else scene_root(settings, n)
    roots[:] = [root]
    _log_line(out, f"{name}: running (load average {os.getloadavg()[0]:.2f})")
    try:
        _spawn(variant, repeat, root, settings, path, timeout_s)
        cell = read_cell(path)
    except (PolarrefError, records.RecordError) as exc:
        _log_line(out, f"{name}: FAILED {exc}")
        return FailedCell(MethodRun(variant.method, status=RunStatus.FAILED, reason=str(exc)), n, variant.parallel,
                          repeat)
    _log_line(out, f"{name}: done, total {cell.total_s:.1f} s, peak {cell.run.peak_rss_mb:.0f} MiB, "
                   f"{cell.run.registered} registered, {cell.tie_points_2v} tie points (>= 2 views)")
    return cell


def run_bench(views: list[int], out: Path, settings: BenchSfMSettings = BenchSfMSettings(),
              methods: tuple[str, ...] = METHODS, overwrite: bool = False,
              cell_timeout_s: float | None = None, parallel: tuple[int, ...] = PARALLEL,
              repeats: int = 1, report_only: bool = False) -> SfMBench:
    """Run every (variant, views, repeat) cell not finished yet, then write bench.json/md/png from all cells.

    Repeats are interleaved: every variant and view count once, then all again, so a change of the
    machine's load spreads over all columns instead of falling on one. ``report_only``: run no
    cell, rebuild the outputs from the finished ones (a sweep stopped part-way)."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "cells").mkdir(exist_ok=True)
    cells, failed = [], []
    roots: dict[int, list[Path]] = {n: [] for n in views}
    for repeat in range(1, repeats + 1):
        for n in views:
            for variant in variants(methods, parallel):
                got = _one(out, variant, n, repeat, settings, overwrite, cell_timeout_s, roots[n], report_only)
                if got is not None:
                    (failed if isinstance(got, FailedCell) else cells).append(got)
    return write_outputs(out, cells, failed, settings)


if __name__ == "__main__":
    sys.exit(_child(sys.argv[1:]))
