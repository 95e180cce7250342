"""The twin campaign's jobs: the twins' four stages with their per-stage costs and settings.

Each function runs in its own process (:func:`polarref.core.isolated.run_isolated`, like the jobs
of :mod:`polarref.compare.run.jobs`, which they wrap) and returns a :class:`StagedRun`: the job's
``MethodRun``, every sub-stage's wall and CPU seconds and peak memory (``StageCost``; a stage read
from a cache is marked so, with the time measured when the cache was made), and the method's
settings beside them (``MethodSettings``, the SfM bench's record: feature budget, threads, pairing,
two-view tracks, every option). The campaign's seed goes into every random choice: ours'
verification and registration RANSAC, pycolmap's mappers.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from polarref.model.settings import MethodSettings, flatten_settings
from polarref.compare.run import jobs, ours
from polarref.core.memory import own_peak_mb
from polarref.model.colmap import global_options, incremental_options
from polarref.model.run import MethodRun
from polarref.peers.colmap_sfm import ColmapSfMOptions, count_verified_pairs, extract_sift, match_sift, sift_options
from polarref.sfm.config import SfMConfig
from polarref.sfm.stages import StageClock, StageCost


@dataclass(frozen=True)
class StagedRun:
    """One job of a cell: its record, its sub-stages' costs and the method's settings."""

    run: MethodRun
    stages: tuple[StageCost, ...]
    settings: MethodSettings


def seeded_config(preset: str, cache_dir: str, pairs_file: str, seed: int, threads: int) -> SfMConfig:
    """The twins' pipeline settings with the campaign's seed in both RANSACs and ``threads`` front-end threads."""
    c = ours.sfm_config(preset, Path(cache_dir), pairs_file)
    register = dataclasses.replace(c.mapper.register, seed=seed)
    return dataclasses.replace(c, threads=threads, verification=dataclasses.replace(c.verification, seed=seed),
                               mapper=dataclasses.replace(c.mapper, register=register))


def _ours_settings(config: SfMConfig, threads: int) -> MethodSettings:
    return MethodSettings("ours", threads, threads, config.features.max_num_features, config.features.max_image_size,
                          False, f"{config.matching.pairing}: {Path(config.matching.pairs_file).name}",
                          flatten_settings(dataclasses.asdict(config)))


def ours_front(image_dir: str, camera: dict, preset: str, cache_dir: str, pairs_file: str, seed: int,
               threads: int) -> StagedRun:
    """Our features, matches and verification of the pairs (into the shared cache)."""
    config = seeded_config(preset, cache_dir, pairs_file, seed, threads)
    run, stages = ours.prepare_features_staged(Path(image_dir), jobs.camera_from_json(camera), config)
    return StagedRun(run, stages, _ours_settings(config, threads))


def ours_map(image_dir: str, camera: dict, ba: str, work_dir: str, preset: str, cache_dir: str, pairs_file: str,
             seed: int, threads: int) -> StagedRun:
    """Our SfM with BA ``ba`` on the shared cache (its front-end stages come back marked cached)."""
    config = seeded_config(preset, cache_dir, pairs_file, seed, threads)
    run, stages = ours.run_staged(Path(image_dir), jobs.camera_from_json(camera), ba, Path(work_dir), config)
    return StagedRun(run, stages, _ours_settings(config, threads))


def _colmap_settings(opts: ColmapSfMOptions, mapper: str, pairing: str) -> MethodSettings:
    extraction, matching = sift_options(opts)
    mapping = incremental_options(opts) if mapper == "incremental" else global_options(opts)
    # the global mapper keeps every track it triangulates; the incremental one drops two-view tracks
    ignore = bool(mapping.triangulation.ignore_two_view_tracks) if mapper == "incremental" else False
    tree = {"colmap_sfm_options": dataclasses.asdict(opts), f"{mapper}_options": mapping.todict(),
            "extraction_options": extraction.todict(), "matching_options": matching.todict()}
    return MethodSettings(f"pycolmap-{mapper}", opts.num_threads, opts.num_threads, opts.max_num_features,
                          opts.max_image_size, ignore, pairing, flatten_settings(tree))


def pycolmap_front(image_dir: str, image_names: list[str], camera: dict, db_path: str, seed: int, threads: int,
                   pairs_file: str, max_num_features: int) -> StagedRun:
    """pycolmap SIFT (``max_num_features``, our budget) and matching of exactly our pairs, timed apart."""
    opts = ColmapSfMOptions(seed=seed, num_threads=threads, max_num_features=max_num_features)
    clock = StageClock()
    clock.start("features")
    extract_sift(Path(image_dir), jobs.camera_from_json(camera), Path(db_path), opts, image_names, overwrite=True)
    clock.stop()
    clock.start("matching")   # pycolmap verifies inside its matching
    match_sift(Path(db_path), opts, Path(pairs_file))
    clock.stop()
    run = MethodRun("pycolmap-features", stage_runtime_s={s.stage: s.wall_s for s in clock.stages},
                    verified_pairs=count_verified_pairs(Path(db_path)), peak_rss_mb=own_peak_mb())
    return StagedRun(run, tuple(clock.stages), _colmap_settings(opts, "incremental", f"file: {Path(pairs_file).name}"))


def pycolmap_mapping(db_path: str, image_dir: str, work_dir: str, mapper: str, seed: int, threads: int,
                     snapshot_every: int, pairing: str, max_num_features: int) -> StagedRun:
    """pycolmap's ``mapper`` (incremental resumes from snapshots) on a copy of the database."""
    clock = StageClock()
    clock.start("mapping")
    run = jobs.pycolmap_map(db_path, image_dir, work_dir, mapper, seed, threads, snapshot_every)
    clock.stop()
    opts = ColmapSfMOptions(seed=seed, num_threads=threads, max_num_features=max_num_features)  # the database's budget
    return StagedRun(run, tuple(clock.stages), _colmap_settings(opts, mapper, pairing))
