"""Method jobs, each run in its own process by :func:`polarref.compare.runner.run_isolated`.

Every job is a module-level function (passed to the runner as the callable itself) that takes
JSON-able keyword arguments (paths as ``str``) and returns one of the typed records below; the
runner stores it as ``<tag>.result.json`` and reads it back strictly (``polarref.core.records``).
Models are written to disk in COLMAP text format and scored by the parent with
``polarref.metrics``, the same code for every method.
"""

from __future__ import annotations

from pathlib import Path

from polarref.core import records
from polarref.camera import Camera
from polarref.compare.experiment_records import DerivationEvidence, Experiments
from polarref.compare import ours
from polarref.compare.job_results import MethodJobResult, SharedStageResult  # noqa: F401 (re-exported)
from polarref.peers.colmap_sfm import (ColmapSfMOptions, copy_database, count_verified_pairs,
                                       extract_and_match_sift, run_mapper)


def camera_to_json(cam: Camera) -> dict:
    """The fixed camera as a JSON-able job argument (read back by :func:`_camera`)."""
    return {"model": cam.model, "width": cam.width, "height": cam.height, "params": cam.params.tolist()}


def _camera(camera: dict) -> Camera:
    return Camera(camera["model"], int(camera["width"]), int(camera["height"]),
                  [float(p) for p in camera["params"]])


def pycolmap_sift_db(image_dir: str, image_names: list[str], camera: dict, db_path: str,
                     seed: int, num_threads: int = 1) -> SharedStageResult:
    """pycolmap SIFT + exhaustive matching + verification into ``db_path``."""
    opts = ColmapSfMOptions(seed=seed, num_threads=num_threads)
    stages = extract_and_match_sift(Path(image_dir), _camera(camera), Path(db_path), opts,
                                    image_names=image_names, overwrite=True)
    return SharedStageResult({k: float(v) for k, v in stages.items()}, count_verified_pairs(Path(db_path)))


def ours_features(image_dir: str, camera: dict, preset: str, cache_dir: str) -> SharedStageResult:
    """Our features and verified matches, computed once per comparison into ``cache_dir``."""
    return ours.prepare_features(Path(image_dir), _camera(camera), preset, Path(cache_dir))


def ours_db(image_dir: str, camera: dict, preset: str, cache_dir: str, db_path: str) -> SharedStageResult:
    """Our keypoints and verified matches (from the shared cache) as a pycolmap database."""
    return ours.import_into_database(Path(image_dir), _camera(camera), preset, Path(cache_dir), Path(db_path))


def pycolmap_map(db_path: str, image_dir: str, work_dir: str, mapper: str, seed: int,
                 num_threads: int = 1) -> MethodJobResult:
    """Map a copy of a prepared database; the largest model goes to ``work_dir/model``."""
    work = Path(work_dir)
    db = copy_database(Path(db_path), work / "database.db")
    run = run_mapper(db, Path(image_dir), work / "sparse", mapper,
                     ColmapSfMOptions(seed=seed, num_threads=num_threads))
    model = write_largest_model(run, work, mapper)
    return MethodJobResult(str(model), {k: float(v) for k, v in run.stage_runtime_s.items()},
                           num_models=int(run.num_models), verified_pairs=int(run.verified_pairs),
                           registered=int(run.reconstruction.num_reg_images()))


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


def ours_sfm(image_dir: str, camera: dict, ba: str, work_dir: str, preset: str, cache_dir: str) -> MethodJobResult:
    """Our incremental SfM (``polarref.sfm``) with one BA parameterization."""
    return ours.run(Path(image_dir), _camera(camera), ba, Path(work_dir), preset, Path(cache_dir))


def claim_experiments(seed: int, budget_s: float, out_json: str) -> Experiments:
    """Controlled BA experiments for the scorecard (conditioning, correlation, robustness)."""
    from polarref.compare import experiments

    return experiments.run_all(seed=seed, budget_s=budget_s, out_json=Path(out_json))


def derivation_evidence(n: int, out_json: str) -> DerivationEvidence:
    """Numeric evidence on the printed view-angle equation and claim 7, from ``derivations.paper``.

    Runs in its own process: the derivations package imports SymPy/mpmath, which runtime code
    must not import.
    """
    import dataclasses

    from derivations import paper

    cases = [dataclasses.asdict(c) for c in paper.all_case_evidence(n=n)]
    result = records.coerce(DerivationEvidence, {"cases": cases, "samples_per_case": n, "seed": paper.SEED})
    records.save(result, out_json)
    return result
