"""Our SfM (``polarref.sfm``) as comparison methods, sharing one feature/match stage.

Features and verified matches are computed once per comparison (timed) into a cache folder
inside the run directory; every ``ours-*`` method and the ``pycolmap-*-ours`` imports then
read that cache, and the shared stage's time is added to each method's runtime, exactly as
pycolmap's shared SIFT database is for its two mappers.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from polarref.camera import Camera
from polarref.compare.job_results import MethodJobResult, SharedStageResult
from polarref.io.scene_folder import SkippedImage
from polarref.compare.schema import TracePoint
from polarref.peers.colmap_sfm import count_verified_pairs

# Timing keys of polarref.sfm that are not part of reconstructing (or double count).
_NOT_STAGES = {"total", "metrics", "export", "features_cached", "matches_cached"}


def sfm_config(preset: str, cache_dir: Path):
    from polarref.sfm.pipeline import PRESETS

    base = PRESETS["small" if preset == "small" else "default"]
    return dataclasses.replace(base, use_cache=True, cache_dir=str(cache_dir))


def _features_and_matches(image_dir: Path, cam: Camera, preset: str, cache_dir: Path):
    from polarref.sfm.pipeline import load_images_and_features, match_and_verify

    config = sfm_config(preset, cache_dir)
    timings: dict = {}
    feats, skipped, key = load_images_and_features(image_dir, config, timings)
    matches = match_and_verify(feats, [cam], np.zeros(len(feats), np.int64), config, key, timings)
    return matches, skipped, timings


def prepare_features(image_dir: Path, cam: Camera, preset: str, cache_dir: Path) -> SharedStageResult:
    """Compute (and cache) features and verified matches; returns the timed stages."""
    matches, skipped, timings = _features_and_matches(image_dir, cam, preset, cache_dir)
    return SharedStageResult({k: float(timings[k]) for k in ("features", "matching", "verification")
                              if k in timings}, len(matches.geometries),
                             [SkippedImage(str(s["name"]), str(s["reason"])) for s in skipped])


def import_into_database(image_dir: Path, cam: Camera, preset: str, cache_dir: Path,
                         db_path: Path) -> SharedStageResult:
    """Our keypoints, putative matches and verified geometries as a pycolmap database (no re-verification)."""
    from polarref.sfm.export import write_colmap_database

    matches, _, _ = _features_and_matches(image_dir, cam, preset, cache_dir)
    t0 = time.perf_counter()
    write_colmap_database(db_path, matches, [cam], np.zeros(len(matches.names), np.int64), overwrite=True)
    return SharedStageResult({"import": time.perf_counter() - t0}, count_verified_pairs(db_path))


def run(image_dir: Path, cam: Camera, ba: str, work_dir: Path, preset: str, cache_dir: Path) -> MethodJobResult:
    """``polarref.sfm.run_sfm`` with BA ``ba``; model in ``work_dir/sfm/model``."""
    from polarref.sfm.pipeline import run_sfm, with_ba

    config = with_ba(sfm_config(preset, cache_dir), ba)
    t0 = time.perf_counter()
    result = run_sfm(image_dir, work_dir / "sfm", config, camera=cam, overwrite=True)
    wall = time.perf_counter() - t0
    t = result.report.runtime_s
    stages = {k: float(v) for k, v in t.items() if k not in _NOT_STAGES and not isinstance(v, bool)}
    # features/matching/verification came from the shared cache: their real cost is the shared stage's.
    for k in ("features", "matching", "verification"):
        stages.pop(k, None)
    ba_s = stages.pop("ba", 0.0)
    if "mapping" in stages:
        stages["mapping (excl. BA)"] = max(0.0, stages.pop("mapping") - ba_s)
    stages["bundle adjustment"] = ba_s
    bas = list(result.report.ba or [])
    final = next((b for b in reversed(bas) if b.kind == "global" and b.trace), None)
    trace = None
    if final is not None:  # accepted steps, starting at the initial cost
        trace = [TracePoint(0, 0.0, float(final.initial_cost))] + [
            TracePoint(int(r.iteration), float(r.wall_s), float(r.cost)) for r in final.trace if r.accepted]
    return MethodJobResult(str(work_dir / "sfm" / "model"), stages, wall_s=wall, num_ba_runs=len(bas),
                           final_ba_trace=trace)
