"""The one job set of ``polarref compare``, for a scene and for the twins alike.

Every job is run in its own process by :func:`polarref.core.isolated.run_isolated`: a
module-level function (passed to the runner as the callable itself) that takes JSON-able keyword
arguments (paths as ``str``) and returns a :class:`polarref.model.run.MethodRun`; the runner
stores it as ``<tag>.result.json`` and reads it back strictly (``polarref.core.records``).
Models are written to disk in COLMAP text format and scored by the parent with
``polarref.metrics``, the same code for every method. The twins add a pairs file (the pairs
chosen once from the pose priors), pycolmap's feature budget and resumable incremental mapping
through the same jobs' optional arguments.
"""

from __future__ import annotations

from pathlib import Path

from polarref.camera import Camera
from polarref.compare.run import ours
from polarref.core.memory import own_peak_mb
from polarref.model.run import MethodRun
from polarref.peers.colmap_sfm import (ColmapSfMOptions, copy_database, count_verified_pairs,
                                       extract_and_match_sift, run_mapper)


def camera_to_json(cam: Camera) -> dict:
    """The fixed camera as a JSON-able job argument (read back by :func:`camera_from_json`)."""
    return {"model": cam.model, "width": cam.width, "height": cam.height, "params": cam.params.tolist()}


def camera_from_json(camera: dict) -> Camera:
    return Camera(camera["model"], int(camera["width"]), int(camera["height"]),
                  [float(p) for p in camera["params"]])


def _options(seed: int, num_threads: int, max_num_features: int | None) -> ColmapSfMOptions:
    if max_num_features is None:
        return ColmapSfMOptions(seed=seed, num_threads=num_threads)
    return ColmapSfMOptions(seed=seed, num_threads=num_threads, max_num_features=max_num_features)


def pycolmap_sift_db(image_dir: str, image_names: list[str], camera: dict, db_path: str,
                     seed: int, num_threads: int = 1, pairs_file: str = "",
                     max_num_features: int | None = None) -> MethodRun:
    """pycolmap SIFT + exhaustive matching (or the pairs of ``pairs_file``) + verification into ``db_path``."""
    sift = extract_and_match_sift(Path(image_dir), camera_from_json(camera), Path(db_path),
                                  _options(seed, num_threads, max_num_features), image_names=image_names,
                                  overwrite=True, pairs_file=Path(pairs_file) if pairs_file else None)
    return MethodRun("pycolmap-features", stage_runtime_s={"features": sift.features, "matching": sift.matching},
                     verified_pairs=count_verified_pairs(Path(db_path)), peak_rss_mb=own_peak_mb())


def ours_features(image_dir: str, camera: dict, preset: str, cache_dir: str, pairs_file: str = "") -> MethodRun:
    """Our features and verified matches, computed once per comparison into ``cache_dir``."""
    return ours.prepare_features(Path(image_dir), camera_from_json(camera),
                                 ours.sfm_config(preset, Path(cache_dir), pairs_file))


def ours_db(image_dir: str, camera: dict, preset: str, cache_dir: str, db_path: str) -> MethodRun:
    """Our keypoints and verified matches (from the shared cache) as a pycolmap database."""
    return ours.import_into_database(Path(image_dir), camera_from_json(camera), ours.sfm_config(preset, Path(cache_dir)),
                                     Path(db_path))


def pycolmap_map(db_path: str, image_dir: str, work_dir: str, mapper: str, seed: int,
                 num_threads: int = 1, snapshot_every: int = 0) -> MethodRun:
    """Map a copy of a prepared database; the largest model goes to ``work_dir/model``.

    Incremental with ``snapshot_every`` > 0 resumes an interrupted run from its last snapshot
    (:mod:`polarref.peers.colmap_resume`; the twins' hour-long mappings)."""
    work = Path(work_dir)
    opts = ColmapSfMOptions(seed=seed, num_threads=num_threads)
    counted, segments = None, 1
    if mapper == "incremental" and snapshot_every > 0:
        from polarref.peers.colmap_resume import map_incremental_resumable

        run, ledger = map_incremental_resumable(Path(db_path), Path(image_dir), work, opts, snapshot_every)
        counted, segments = ledger.counted_s, len(ledger.segments)
    else:
        db = copy_database(Path(db_path), work / "database.db")
        run = run_mapper(db, Path(image_dir), work / "sparse", mapper, opts)
    model = write_largest_model(run, work, mapper)
    return MethodRun(f"pycolmap-{mapper}", form="ceres",
                     stage_runtime_s={k: float(v) for k, v in run.stage_runtime_s.items()},
                     model_dir=str(model), num_models=int(run.num_models), verified_pairs=int(run.verified_pairs),
                     registered=int(run.reconstruction.num_reg_images()), counted_wall_s=counted,
                     segments=segments, peak_rss_mb=own_peak_mb())


def write_largest_model(run, work: Path, mapper: str) -> Path:
    """``work/model`` (COLMAP text) of a pycolmap mapping run; a run that registered nothing fails."""
    rec = run.reconstruction
    if rec is None or rec.num_reg_images() == 0:
        raise RuntimeError(f"pycolmap {mapper} mapping registered no images "
                           f"({run.num_models} models, {run.verified_pairs} verified pairs)")
    model = work / "model"
    model.mkdir(parents=True, exist_ok=True)
    rec.write_text(str(model))
    return model


def ours_sfm(image_dir: str, camera: dict, ba: str, work_dir: str, preset: str, cache_dir: str,
             pairs_file: str = "", track_conflicts: str | None = None) -> MethodRun:
    """Our incremental SfM (``polarref.sfm``) with one BA parameterization on the shared cache.

    ``track_conflicts``: None keeps the pipeline default; "split" is the variant measured by
    ``scripts/twin_variant.py`` (tracks and mapping only: the caches do not depend on it)."""
    config = ours.sfm_config(preset, Path(cache_dir), pairs_file, track_conflicts)
    return ours.run(Path(image_dir), camera_from_json(camera), ba, Path(work_dir), config)
