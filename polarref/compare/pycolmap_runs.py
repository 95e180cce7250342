"""pycolmap (COLMAP 3.x/4.x) reconstructions on the same images, intrinsics held fixed.

Two feature sources x two mappers:

* ``sift``: pycolmap's own SIFT, exhaustive matching and geometric verification;
* ``ours``: our keypoints and verified matches imported into a fresh pycolmap database,
  so a difference between our SfM and COLMAP's mapper is not a difference in features;

then ``incremental`` (COLMAP) or ``global`` (GLOMAP) mapping. pycolmap 4.2.1 lets the focal
length drift even with a PINHOLE prior (fx 840 / fy 1660 seen here), so every refine flag is
switched off for both pipelines (see ``../shared/notes/pycolmap-4.2.1.md``).
"""

from __future__ import annotations

import logging
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from polarref.errors import PolarrefError

log = logging.getLogger(__name__)

MAPPERS = ("incremental", "global")


@dataclass(frozen=True)
class FixedCamera:
    """The known intrinsics every method uses (COLMAP pixel convention)."""

    model: str                 # COLMAP model name, e.g. "PINHOLE"
    width: int
    height: int
    params: tuple[float, ...]  # COLMAP parameter order for ``model``


@dataclass(frozen=True)
class PycolmapOptions:
    """Settings shared by all pycolmap runs of one comparison."""

    seed: int = 0              # mapper random seed (RANSAC, initial pair)
    num_threads: int = 2       # the target machine has 2 cores
    max_num_features: int = 8192   # SIFT features per image (COLMAP default)
    max_image_size: int = 3200     # SIFT downscales larger images (COLMAP default)


@dataclass
class PycolmapRun:
    """The largest reconstruction of one mapping run plus timings."""

    reconstruction: object | None      # pycolmap.Reconstruction, or None when nothing registered
    stage_runtime_s: dict[str, float] = field(default_factory=dict)
    num_models: int = 0
    verified_pairs: int = 0


def _pycolmap():
    import pycolmap
    return pycolmap


def _camera(cam: FixedCamera, camera_id: int = 1):
    pycolmap = _pycolmap()
    return pycolmap.Camera(model=cam.model, width=int(cam.width), height=int(cam.height),
                           params=np.asarray(cam.params, dtype=np.float64), camera_id=camera_id)


def count_verified_pairs(db_path: Path) -> int:
    """Image pairs with a geometrically verified model and >= 1 inlier.

    ``Database.num_verified_image_pairs()`` disagrees with the stored geometries on 4.2.1,
    so count from ``read_two_view_geometries()``.
    """
    pycolmap = _pycolmap()
    db = pycolmap.Database.open(str(db_path))
    try:
        pair_ids, geoms = db.read_two_view_geometries()
        return int(sum(1 for g in geoms if len(g.inlier_matches) > 0))
    finally:
        db.close()


def extract_and_match_sift(image_dir: Path, image_names: list[str], cam: FixedCamera,
                           db_path: Path, opts: PycolmapOptions) -> dict[str, float]:
    """pycolmap SIFT + exhaustive matching + verification into ``db_path``; returns timings."""
    pycolmap = _pycolmap()
    db_path.parent.mkdir(parents=True, exist_ok=True)
    if db_path.exists():
        db_path.unlink()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = cam.model
    reader.camera_params = ",".join(repr(float(p)) for p in cam.params)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = opts.num_threads
    extraction.max_image_size = opts.max_image_size
    extraction.sift.max_num_features = opts.max_num_features
    t0 = time.perf_counter()
    pycolmap.extract_features(str(db_path), str(image_dir), image_names=list(image_names),
                              camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=extraction, device=pycolmap.Device.cpu)
    t1 = time.perf_counter()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = opts.num_threads
    pycolmap.match_exhaustive(str(db_path), matching_options=matching, device=pycolmap.Device.cpu)
    t2 = time.perf_counter()
    return {"features": t1 - t0, "matching": t2 - t1}


def import_features(db_path: Path, cam: FixedCamera, image_names: list[str],
                    keypoints: list[np.ndarray], matches: dict[tuple[int, int], np.ndarray],
                    verified: bool = True, poses: dict | None = None) -> dict[str, float]:
    """Write our keypoints and matches into a new pycolmap database.

    Args:
        image_names: N names (image i gets database id i + 1).
        keypoints: N arrays (K_i, 2), COLMAP pixel convention (corner origin).
        matches: {(i, j): (M, 2) keypoint indices}, i < j, 0-based image indices.
        verified: True when ``matches`` are already geometric inliers (written as CALIBRATED
            two-view geometries); False runs pycolmap's own verification on them.
        poses: optional {(i, j): Rigid3 cam_j_from_cam_i (unit baseline)} from our verification;
            stored as the geometry's relative pose and essential matrix (pycolmap's initial-pair
            choice and triangulation-angle checks read them).
    """
    pycolmap = _pycolmap()
    if len(keypoints) != len(image_names):
        raise PolarrefError(f"import_features: {len(image_names)} names but {len(keypoints)} keypoint arrays")
    db_path.parent.mkdir(parents=True, exist_ok=True)
    if db_path.exists():
        db_path.unlink()
    t0 = time.perf_counter()
    db = pycolmap.Database.open(str(db_path))
    try:
        cam_id = db.write_camera(_camera(cam))
        ids = []
        for name in image_names:
            ids.append(db.write_image(pycolmap.Image(name=name, camera_id=cam_id)))
        for image_id, kps in zip(ids, keypoints):
            db.write_keypoints(image_id, np.ascontiguousarray(np.asarray(kps)[:, :2], dtype=np.float32))
        for (i, j), m in sorted(matches.items()):
            m = np.ascontiguousarray(np.asarray(m, dtype=np.uint32).reshape(-1, 2))
            if i > j:
                i, j, m = j, i, np.ascontiguousarray(m[:, ::-1])
            db.write_matches(ids[i], ids[j], m)
            if verified:
                geom = pycolmap.TwoViewGeometry()
                geom.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
                geom.inlier_matches = m
                pose = (poses or {}).get((i, j))
                if pose is not None:
                    from polarref.geometry import skew

                    geom.cam2_from_cam1 = pycolmap.Rigid3d(pycolmap.Rotation3d(pose.R), pose.t)
                    geom.E = skew(pose.t) @ pose.R
                db.write_two_view_geometry(ids[i], ids[j], geom)
    finally:
        db.close()
    t1 = time.perf_counter()
    timings = {"import": t1 - t0}
    if not verified:
        pairs_txt = db_path.with_suffix(".pairs.txt")
        pairs_txt.write_text("".join(f"{image_names[i]} {image_names[j]}\n" for i, j in sorted(matches)))
        pycolmap.verify_matches(str(db_path), str(pairs_txt), pycolmap.TwoViewGeometryOptions())
        timings["verification"] = time.perf_counter() - t1
    return timings


def _incremental_options(opts: PycolmapOptions):
    pycolmap = _pycolmap()
    o = pycolmap.IncrementalPipelineOptions()
    o.num_threads = opts.num_threads
    o.random_seed = opts.seed
    o.multiple_models = False
    # Intrinsics are known: hold them fixed in every BA and in absolute pose estimation.
    o.ba_refine_focal_length = False
    o.ba_refine_principal_point = False
    o.ba_refine_extra_params = False
    o.mapper.abs_pose_refine_focal_length = False
    o.mapper.abs_pose_refine_extra_params = False
    return o


def _global_options(opts: PycolmapOptions):
    pycolmap = _pycolmap()
    o = pycolmap.GlobalPipelineOptions()
    o.num_threads = opts.num_threads
    o.random_seed = opts.seed
    ba = o.mapper.bundle_adjustment
    ba.refine_focal_length = False
    ba.refine_principal_point = False
    ba.refine_extra_params = False
    # Defaults are True and only warn on a CPU build; say what we mean.
    ba.ceres.use_gpu = False
    o.mapper.global_positioning.use_gpu = False
    return o


def run_mapper(db_path: Path, image_dir: Path, out_dir: Path, mapper: str,
               opts: PycolmapOptions) -> PycolmapRun:
    """Map from a prepared database; keep the reconstruction with most registered images."""
    pycolmap = _pycolmap()
    if mapper not in MAPPERS:
        raise PolarrefError(f"unknown pycolmap mapper {mapper!r} (choose from {', '.join(MAPPERS)})")
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    if mapper == "incremental":
        recs = pycolmap.incremental_mapping(str(db_path), str(image_dir), str(out_dir),
                                            options=_incremental_options(opts))
    else:
        recs = pycolmap.global_mapping(str(db_path), str(image_dir), str(out_dir),
                                       options=_global_options(opts))
    elapsed = time.perf_counter() - t0
    best = max(recs.values(), key=lambda r: r.num_reg_images(), default=None) if recs else None
    if best is not None:
        best.update_point_3d_errors()  # the mean error reads cached per-point errors
    return PycolmapRun(best, {"mapping": elapsed}, num_models=len(recs or {}),
                       verified_pairs=count_verified_pairs(db_path))


def copy_database(src: Path, dst: Path) -> Path:
    """Each mapper gets its own copy (mapping writes to the database)."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src, dst)
    return dst
