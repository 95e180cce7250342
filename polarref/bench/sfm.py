"""``polarref bench sfm``: our SfM vs pycolmap incremental on the same images and pairs, vs views.

One *cell* is one method on one view count. Every cell runs in its own child process (one
thread: BLAS, OpenCV and pycolmap), so its peak memory (``getrusage(RUSAGE_SELF).ru_maxrss``
and ``VmHWM`` of the child) belongs to that method alone, and writes ``OUT/cells/<method>-v<N>.json``
with its stage times, peak memory, tie points, GT errors and every setting. A finished cell is
reused on the next run (resume after an interruption); a cell made with other settings is
refused unless ``--overwrite``. ``bench.json``, ``bench.md`` and ``bench.png`` are rebuilt from
the cells (:mod:`polarref.bench.sfm_report`).

Same input for both: the rendered images, the fixed GT intrinsics and the image pairs our
pairing selects (default sequential, overlap 10), which pycolmap imports as its pair list
(``match_image_pairs``): each method extracts and matches its own SIFT on those pairs. The
SHA-256 of the pair list is stored in both cells.
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
from typing import Any

from polarref.bench.records import (BenchSfMSettings, FailedCell, PeakMemory, SfMBench, SfMCell, read_cell,
                                    write)
from polarref.bench.sfm_report import STAGES, write_outputs  # noqa: F401 (STAGES re-exported)
from polarref.core import records
from polarref.core.errors import PolarrefError
from polarref.core.provenance import collect_record
from polarref.core.status import RunStatus
from polarref.model import Reconstruction
from polarref.model.colmap import from_pycolmap, read_model

log = logging.getLogger(__name__)

METHODS = ("ours", "pycolmap")
# pipeline stages timed per method (scoring against GT and writing files are not counted)
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@dataclass(frozen=True)
class _MethodOutput:
    """What one method's run hands to the cell (in the cell's process)."""

    stages_s: dict[str, float]
    rec: Reconstruction
    gt: Reconstruction
    num_images: int
    pairs: int
    pairs_sha256: str
    settings: dict[str, Any]   # the method's option objects as they print


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
    r = resource.getrusage(resource.RUSAGE_SELF)
    return float(r.ru_utime + r.ru_stime)


def peak_memory_mb() -> PeakMemory:
    """Peak resident memory of this process: ru_maxrss and /proc VmHWM (MiB; None if unknown)."""
    hwm = None
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                hwm = int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return PeakMemory(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, hwm)


# ---- one cell (child process) ------------------------------------------------------------------
def _scene(root: Path):
    from polarref.sfm import features as F
    from synth.scene import load_scene

    loaded = load_scene(root)
    names = [p.name for p in F.list_images(root / "images")]
    return names, loaded.polarref_camera(), read_model(loaded.gt_dir)


def _ours_config(settings: BenchSfMSettings):
    from polarref.sfm.pipeline import PRESETS

    base = PRESETS["default"]
    return dataclasses.replace(base, use_cache=False, matching=dataclasses.replace(
        base.matching, pairing=settings.pairing, sequential_overlap=settings.overlap))


def _run_ours(root: Path, settings: BenchSfMSettings) -> _MethodOutput:
    from polarref.sfm.pipeline import run_sfm

    names, camera, gt = _scene(root)
    config = _ours_config(settings)
    res = run_sfm(root / "images", None, config, camera=camera, gt=gt)
    t = res.report.runtime_s
    stages = {s: float(t.get(s, 0.0)) for s in STAGES["ours"]}
    stages["ba"] = float(t.get("ba", 0.0))  # part of mapping
    pairs = pairs_for(len(names), settings)
    return _MethodOutput(stages, res.reconstruction, gt, len(names), len(pairs), _pairs_digest(names, pairs),
                         dataclasses.asdict(config))


def _run_pycolmap(root: Path, settings: BenchSfMSettings, work: Path) -> _MethodOutput:
    from polarref.peers.colmap_sfm import (ColmapSfMOptions, extract_and_match_sift, incremental_options,
                                           run_mapper, sift_options)

    names, camera, gt = _scene(root)
    pairs = pairs_for(len(names), settings)
    opts = ColmapSfMOptions(seed=settings.seed, num_threads=settings.threads)
    db = work / "database.db"
    pairs_txt = work / "pairs.txt"
    pairs_txt.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
    # The same extraction and imported-pair matching as the twin comparison (one code path).
    t = extract_and_match_sift(root / "images", camera, db, opts, image_names=names, overwrite=True,
                               pairs_file=pairs_txt)
    extraction, matching = sift_options(opts)
    run = run_mapper(db, root / "images", work / "sparse", "incremental", opts)
    stages = {"features": t["features"], "matching": t["matching"], "mapping": run.stage_runtime_s["mapping"]}
    if run.reconstruction is None:
        raise PolarrefError("pycolmap incremental mapping registered no images")
    settings_out = {"colmap_sfm_options": dataclasses.asdict(opts),
                    "incremental_options": incremental_options(opts).todict(),
                    "extraction_options": extraction.todict(), "matching_options": matching.todict(),
                    "pairing": f"imported pair list ({settings.pairing}, overlap {settings.overlap})"}
    return _MethodOutput(stages, from_pycolmap(run.reconstruction), gt, len(names), len(pairs),
                         _pairs_digest(names, pairs), settings_out)


def run_cell(method: str, root: Path, settings: BenchSfMSettings, work: Path) -> SfMCell:
    """Run one method on one scene here and return the cell record."""
    from polarref import metrics as M

    t0 = time.perf_counter()
    got = _run_ours(root, settings) if method == "ours" else _run_pycolmap(root, settings, work)
    wall = time.perf_counter() - t0
    m = M.evaluate(got.rec, gt=got.gt, num_images=got.num_images)
    return SfMCell(
        method=method, views=got.num_images, status=RunStatus.OK, stages_s=got.stages_s,
        total_s=float(sum(got.stages_s[s] for s in STAGES[method])), wall_s=wall, peak_memory_mb=peak_memory_mb(),
        # CPU seconds of the whole cell process (imports and scoring included): on a loaded
        # machine a steadier figure than wall time (one thread each)
        cpu_s=_cpu_seconds(),
        registered_images=m.registered_images, tie_points=m.tie_points, observations=m.reprojected_px,
        mean_track_length=m.mean_track_length, mean_reprojection_error_px=m.mean_reprojection_error_px,
        rotation_error_deg_mean=None if m.gt is None else m.gt.rotation_error_deg_mean,
        center_error_rel_mean=None if m.gt is None else m.gt.center_error_rel_mean,
        pairs=got.pairs, pairs_sha256=got.pairs_sha256, bench_settings=settings, method_settings=got.settings,
        scene_root=str(root), environment=collect_record(seeds={"seed": settings.seed},
                                                         threads={"all_stages": settings.threads}))


def _child(argv: list[str]) -> int:
    """``python -m polarref.bench.sfm METHOD SCENE_ROOT SETTINGS_JSON OUT_JSON`` (one cell)."""
    import tempfile

    import cv2

    method, root, settings_json, out = argv
    cv2.setNumThreads(1)
    settings = records.from_dict(BenchSfMSettings, json.loads(settings_json), label="bench settings")
    with tempfile.TemporaryDirectory(prefix="bench-sfm-") as work:
        cell = run_cell(method, Path(root), settings, Path(work))
    write(cell, Path(out))
    return 0


# ---- the sweep (parent) ------------------------------------------------------------------------
def cell_path(out: Path, method: str, views: int) -> Path:
    return out / "cells" / f"{method}-v{views}.json"


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


def _spawn(method: str, root: Path, settings: BenchSfMSettings, path: Path, timeout_s: float | None) -> None:
    env = dict(os.environ, **{v: str(settings.threads) for v in THREAD_VARS})
    cmd = [sys.executable, "-m", "polarref.bench.sfm", method, str(root),
           json.dumps(dataclasses.asdict(settings)), str(path)]
    try:
        r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired as exc:
        raise PolarrefError(f"bench cell {method} ran past {timeout_s:.0f} s") from exc
    if r.returncode != 0:
        tail = (r.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise PolarrefError(f"bench cell {method} on {root.name} failed: {tail}")


def run_bench(views: list[int], out: Path, settings: BenchSfMSettings = BenchSfMSettings(),
              methods: tuple[str, ...] = METHODS, overwrite: bool = False,
              cell_timeout_s: float | None = None) -> SfMBench:
    """Run every (method, views) cell not finished yet, then write bench.json/md/png from all cells."""

    out.mkdir(parents=True, exist_ok=True)
    (out / "cells").mkdir(exist_ok=True)
    cells, failed = [], []
    for n in views:
        root = None
        for method in methods:
            path = cell_path(out, method, n)
            cell = None if overwrite else load_cell(path, settings)
            if cell is not None:
                _log_line(out, f"{method} v{n}: finished cell reused ({cell.total_s:.1f} s)")
                cells.append(cell)
                continue
            root = root or scene_root(settings, n)
            _log_line(out, f"{method} v{n}: running")
            try:
                _spawn(method, root, settings, path, cell_timeout_s)
            except PolarrefError as exc:
                _log_line(out, f"{method} v{n}: FAILED {exc}")
                failed.append(FailedCell(method, n, str(exc)))
                continue
            try:
                cell = read_cell(path)
            except records.RecordError as exc:
                _log_line(out, f"{method} v{n}: FAILED {exc}")
                failed.append(FailedCell(method, n, str(exc)))
                continue
            _log_line(out, f"{method} v{n}: done, total {cell.total_s:.1f} s, peak "
                           f"{cell.peak_memory_mb.ru_maxrss_mb:.0f} MiB, {cell.registered_images} registered, "
                           f"{cell.tie_points} tie points")
            cells.append(cell)
    return write_outputs(out, cells, failed, settings)


if __name__ == "__main__":
    sys.exit(_child(sys.argv[1:]))
