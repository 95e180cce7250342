"""Our SfM (``polarref.sfm``) as comparison methods, sharing one feature/match stage.

Features and verified matches are computed once per comparison (timed) into a cache folder
inside the run directory; every ``ours-*`` method and the ``pycolmap-*-ours`` imports then
read that cache, and the shared stage's time is added to each method's runtime, exactly as
pycolmap's shared SIFT database is for its two mappers. The scene comparison and the twins run
these same functions (through :mod:`polarref.compare.run.jobs`); the twins match a pairs file.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from polarref.camera import Camera
from polarref.compare.run import presets
from polarref.core.memory import own_peak_mb
from polarref.model.run import MethodRun, TracePoint
from polarref.peers.colmap_sfm import count_verified_pairs
from polarref.sfm.config import PRESETS, SfMConfig

# Timing keys of polarref.sfm that are not part of reconstructing (or double count).
_NOT_STAGES = {"total", "metrics", "export", "features_cached", "matches_cached"}
# features/matching/verification of a method come from the shared cache: their real cost is the shared stage's
_SHARED_STAGES = ("features", "matching", "verification")
CACHED = "{} (loaded from an earlier run's cache)"
MEASURED = "{} (measured when the cache was made)"
FEATURES_CACHED = CACHED.format("features")


def sfm_config(preset: str, cache_dir: Path, pairs_file: str = "", track_conflicts: str | None = None) -> SfMConfig:
    """The pipeline settings of a comparison under the compare preset named ``preset``
    with the shared cache; ``pairs_file`` matches only its pairs; ``track_conflicts`` None keeps
    the pipeline's default."""
    base = PRESETS[presets.get(preset).sfm_preset]
    config = dataclasses.replace(base, use_cache=True, cache_dir=str(cache_dir),
                                 track_conflicts=track_conflicts or base.track_conflicts)
    if pairs_file:
        config = dataclasses.replace(config, matching=dataclasses.replace(config.matching, pairing="file",
                                                                          pairs_file=str(pairs_file)))
    return config


def _features_and_matches(image_dir: Path, cam: Camera, config: SfMConfig):
    from polarref.sfm.pipeline import load_images_and_features, match_and_verify
    from polarref.sfm.stages import StageClock

    clock = StageClock()
    feats, skipped, key = load_images_and_features(image_dir, config, clock)
    matches = match_and_verify(feats, [cam], np.zeros(len(feats), np.int64), config, key, clock)
    return matches, skipped, clock, key


def prepare_features(image_dir: Path, cam: Camera, config: SfMConfig) -> MethodRun:
    """Compute (and cache) features and verified matches; returns the timed stages."""
    return prepare_features_staged(image_dir, cam, config)[0]


def prepare_features_staged(image_dir: Path, cam: Camera, config: SfMConfig) -> tuple[MethodRun, tuple]:
    """:func:`prepare_features` and its stage costs (``polarref.sfm.stages.StageCost``: wall, CPU,
    peak memory, cached) for the twin campaign's cells."""
    matches, skipped, clock, key = _features_and_matches(image_dir, cam, config)
    stages: dict[str, float] = {}
    for s in clock.stages:
        if s.stage not in _SHARED_STAGES:
            continue
        if not s.cached:
            stages[s.stage] = s.wall_s
            continue
        # the time to load them, not to compute them: say so, and count what computing them took
        stages[CACHED.format(s.stage)] = s.wall_s
        if s.measured_s is not None:
            stages[MEASURED.format(s.stage)] = s.measured_s
    return MethodRun("ours-features", stage_runtime_s=stages, verified_pairs=len(matches.geometries),
                     skipped_images=list(skipped),
                     feature_file=str(Path(config.cache_dir) / f"features-{key}.npz"),
                     peak_rss_mb=own_peak_mb()), tuple(clock.stages)


def import_into_database(image_dir: Path, cam: Camera, config: SfMConfig, db_path: Path) -> MethodRun:
    """Our keypoints, putative matches and verified geometries as a pycolmap database (no re-verification)."""
    from polarref.sfm.export import write_colmap_database

    matches, _, _, _ = _features_and_matches(image_dir, cam, config)
    t0 = time.perf_counter()
    write_colmap_database(db_path, matches, [cam], np.zeros(len(matches.names), np.int64), overwrite=True)
    return MethodRun("db-ours", stage_runtime_s={"import": time.perf_counter() - t0},
                     verified_pairs=count_verified_pairs(db_path), peak_rss_mb=own_peak_mb())


def _final_trace(bas) -> list[TracePoint] | None:
    """Accepted steps of the last global BA that kept a trace, starting at its initial cost."""
    final = next((b for b in reversed(bas) if b.kind == "global" and b.trace), None)
    if final is None:
        return None
    return [TracePoint(0, 0.0, float(final.initial_cost))] + [
        TracePoint(int(r.iteration), float(r.wall_s), float(r.cost)) for r in final.trace if r.accepted]


def run(image_dir: Path, cam: Camera, ba: str, work_dir: Path, config: SfMConfig) -> MethodRun:
    """``polarref.sfm.run_sfm`` with BA ``ba``; model in ``work_dir/sfm/model``."""
    return run_staged(image_dir, cam, ba, work_dir, config)[0]


def run_staged(image_dir: Path, cam: Camera, ba: str, work_dir: Path, config: SfMConfig) -> tuple[MethodRun, tuple]:
    """:func:`run` and its stage costs (``polarref.sfm.stages.StageCost``) for the twin campaign."""
    from polarref.sfm.pipeline import run_sfm, with_ba

    t0 = time.perf_counter()
    result = run_sfm(image_dir, work_dir / "sfm", with_ba(config, ba), camera=cam, overwrite=True)
    wall = time.perf_counter() - t0
    stages = {k: float(v) for k, v in result.report.runtime_s.items()
              if k not in _NOT_STAGES and k not in _SHARED_STAGES and not isinstance(v, bool)}
    ba_s = stages.pop("ba", 0.0)
    if "mapping" in stages:
        stages["mapping (excl. BA)"] = max(0.0, stages.pop("mapping") - ba_s)
    stages["bundle adjustment"] = ba_s
    bas = list(result.report.ba or [])
    return MethodRun(f"ours-{ba}", form=ba, stage_runtime_s=stages, wall_s=wall,
                     model_dir=str(work_dir / "sfm" / "model"), num_ba_runs=len(bas),
                     final_ba_trace=_final_trace(bas), peak_rss_mb=own_peak_mb()), tuple(result.stages)
