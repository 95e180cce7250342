"""pycolmap (COLMAP 4.x / GLOMAP) structure from motion, intrinsics fixed unless ``refine``.

The one place in polarref that drives pycolmap's SfM: used by ``polarref compare`` (as the
reference methods), by ``polarref.sfm.export`` (our matches into a COLMAP database) and by the
tests (pycolmap as an independent implementation). Stages, each usable on its own:

* :func:`extract_and_match_sift`: pycolmap's SIFT, exhaustive matching and verification;
* :func:`import_features`: OUR keypoints / matches / verified two-view geometries into a new
  database, so pycolmap's mapper sees exactly our correspondences;
* :func:`run_mapper`: ``incremental`` (COLMAP) or ``global`` (GLOMAP) mapping of a database;
* :func:`run_sift_sfm`: the first and third chained (what the tests use).

Two pycolmap 4.2.1 traps make the intrinsics drift although they are known (both measured
here, see ``shared/notes/pycolmap-4.2.1.md``):

1. the mappers refine focal length and principal point by default (fx 840 / fy 1660 seen on a
   PINHOLE prior): every refine flag is switched off, once, in
   :func:`polarref.model.colmap.incremental_options` and :func:`~polarref.model.colmap.global_options`;
2. a database camera without ``has_prior_focal_length`` gets its focal length re-estimated by
   the incremental mapper even with those flags off (small comet: 386.3 -> 310.5 px and 3.4 deg
   mean rotation error, vs 0.2 deg with the flag): :func:`import_features` sets it on every
   camera. (pycolmap's own feature extraction sets it when given the camera parameters.)
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from polarref.core.errors import PolarrefError
# the pipeline option builders live with every other pycolmap conversion
from polarref.model.colmap import global_options, incremental_options, two_view_geometry

if TYPE_CHECKING:
    import pycolmap

MAPPERS = ("incremental", "global")

Pair = tuple[int, int]


@dataclass(frozen=True)
class ColmapSfMOptions:
    """Settings of one pycolmap SfM run (extraction, matching, mapping)."""

    seed: int = 0                  # random seed of the mappers (RANSAC, initial pair); >= 0
    num_threads: int = 1           # threads for every stage; 1 = reproducible reference runs
    max_num_features: int = 8192   # SIFT features per image (COLMAP's default)
    max_image_size: int = 3200     # SIFT downscales larger images to this side (COLMAP's default)
    multiple_models: bool = False  # incremental: keep mapping the leftovers into further models
    # intrinsics groups the mappers' BAs refine (focal, pp, dist; issue 19), () = held fixed;
    # set it to what polarref's mapper refines so both start from and estimate the same things
    refine: tuple = ()

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0 (pycolmap treats < 0 as 'seed from the clock'), got {self.seed}")
        if self.num_threads == 0 or self.num_threads < -1:
            raise ValueError(f"num_threads must be >= 1 or -1 (all cores), got {self.num_threads}")
        if self.max_num_features <= 0 or self.max_image_size <= 0:
            raise ValueError("max_num_features and max_image_size must be > 0, got "
                             f"{self.max_num_features}, {self.max_image_size}")


@dataclass
class ColmapSfMRun:
    """The largest reconstruction of one mapping run, with timings."""

    reconstruction: pycolmap.Reconstruction | None   # the largest model; None when nothing registered
    stage_runtime_s: dict[str, float] = field(default_factory=dict)
    num_models: int = 0                # reconstructions the mapper returned
    verified_pairs: int = 0            # image pairs with >= 1 verified inlier in the database


def _pycolmap():
    import pycolmap

    return pycolmap


def _fresh_database(db_path: Path, overwrite: bool) -> Path:
    db_path = Path(db_path)
    if db_path.exists():
        if not overwrite:
            raise PolarrefError(f"database {db_path} already exists; not touching it (pass overwrite=True)")
        db_path.unlink()
    db_path.parent.mkdir(parents=True, exist_ok=True)
    return db_path


# ---- databases ---------------------------------------------------------------------------------
def count_verified_pairs(db_path: Path) -> int:
    """Image pairs with a verified two-view geometry of >= 1 inlier.

    ``Database.num_verified_image_pairs()`` disagrees with the stored geometries on 4.2.1,
    so this counts from ``read_two_view_geometries()``.
    """
    pycolmap = _pycolmap()
    db = pycolmap.Database.open(str(db_path))
    try:
        _, geoms = db.read_two_view_geometries()
        return int(sum(1 for g in geoms if len(g.inlier_matches) > 0))
    finally:
        db.close()


def sift_options(opts: ColmapSfMOptions):
    """pycolmap's (FeatureExtractionOptions, FeatureMatchingOptions) for ``opts`` (thread count,
    image size and feature budget), the ones :func:`extract_and_match_sift` runs with."""
    pycolmap = _pycolmap()
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = opts.num_threads
    extraction.max_image_size = opts.max_image_size
    extraction.sift.max_num_features = opts.max_num_features
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = opts.num_threads
    return extraction, matching


@dataclass(frozen=True)
class SiftTimes:
    """Wall seconds of pycolmap's SIFT stages (matching includes its verification)."""

    features: float
    matching: float


def extract_sift(image_dir: Path, camera, db_path: Path, opts: ColmapSfMOptions = ColmapSfMOptions(),
                 image_names: Sequence[str] | None = None, overwrite: bool = False) -> Path:
    """pycolmap SIFT of ``image_dir`` (one shared camera with fixed intrinsics) into a new database."""
    pycolmap = _pycolmap()
    db_path = _fresh_database(db_path, overwrite)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera.to_pycolmap().model.name
    # Given the parameters, the reader also sets has_prior_focal_length (trap 2 above).
    reader.camera_params = ",".join(repr(float(p)) for p in np.asarray(camera.params))
    extraction, _ = sift_options(opts)
    names = {} if image_names is None else {"image_names": list(image_names)}
    pycolmap.extract_features(str(db_path), str(image_dir), camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=extraction,
                              device=pycolmap.Device.cpu, **names)
    return db_path


def match_sift(db_path: Path, opts: ColmapSfMOptions = ColmapSfMOptions(), pairs_file: Path | None = None) -> None:
    """Exhaustive matching (or the pairs of ``pairs_file``, a COLMAP match list, e.g. from
    :mod:`polarref.sfm.pairing`, via ``match_image_pairs``) and verification of a SIFT database."""
    pycolmap = _pycolmap()
    _, matching = sift_options(opts)
    if pairs_file is None:
        pycolmap.match_exhaustive(str(db_path), matching_options=matching, device=pycolmap.Device.cpu)
    else:  # exactly the pairs every other method matches
        pairing = pycolmap.ImportedPairingOptions()
        pairing.match_list_path = str(pairs_file)
        pycolmap.match_image_pairs(str(db_path), matching_options=matching, pairing_options=pairing,
                                   device=pycolmap.Device.cpu)


def extract_and_match_sift(image_dir: Path, camera, db_path: Path, opts: ColmapSfMOptions = ColmapSfMOptions(),
                           image_names: Sequence[str] | None = None, overwrite: bool = False,
                           pairs_file: Path | None = None) -> SiftTimes:
    """:func:`extract_sift` then :func:`match_sift` into a new database.

    Args:
        image_dir: folder of the images.
        camera: :class:`polarref.camera.Camera` shared by all images (fixed intrinsics).
        db_path: database to create.
        image_names: the images to use (default: every image in ``image_dir``).
        overwrite: replace an existing ``db_path`` (otherwise PolarrefError).
        pairs_file: match only these pairs (default: exhaustive).
    """
    t0 = time.perf_counter()
    extract_sift(image_dir, camera, db_path, opts, image_names, overwrite)
    t1 = time.perf_counter()
    match_sift(db_path, opts, pairs_file)
    return SiftTimes(t1 - t0, time.perf_counter() - t1)


@dataclass(frozen=True)
class ImportedFeatures:
    """What :func:`import_features` wrote: image ids in input order, seconds per step."""

    image_ids: tuple[int, ...]
    import_s: float
    verification_s: float | None = None   # pycolmap's own verification (only without ``verified``)


def _match_array(m, i: int, j: int) -> tuple[int, int, np.ndarray]:
    m = np.asarray(m).reshape(-1, 2)
    if m.size and m.min() < 0:
        raise PolarrefError(f"import_features: negative keypoint index in the matches of pair {(i, j)}")
    if i > j:
        i, j, m = j, i, m[:, ::-1]
    return i, j, np.ascontiguousarray(m, dtype=np.uint32)


def import_features(db_path: Path, cameras, image_names: Sequence[str], keypoints: Sequence[np.ndarray],
                    matches: Mapping[Pair, np.ndarray], *, camera_of_image: Sequence[int] | None = None,
                    verified: Mapping[Pair, object] | None = None, descriptors: Sequence[np.ndarray] | None = None,
                    overwrite: bool = False) -> ImportedFeatures:
    """Write our features into a new pycolmap database.

    Image ``i`` is written in list order (COLMAP assigns the ids); every camera gets
    ``has_prior_focal_length = True`` so that the mapper keeps its focal length.

    Args:
        db_path: database to create.
        cameras: one :class:`polarref.camera.Camera` or a sequence of them.
        image_names: N names.
        keypoints: N arrays (K_i, 2+), COLMAP pixel convention (corner origin); columns beyond
            2 are ignored.
        matches: {(i, j): (M, 2) keypoint indices} putative matches, 0-based image indices;
            (j, i) keys are flipped.
        camera_of_image: (N,) index into ``cameras`` (default: all 0).
        verified: {(i, j): geometry with ``.inliers`` (M', 2) and ``.cam2_from_cam1`` (Rigid3
            or None, unit baseline)}: written as CALIBRATED two-view geometries. None runs
            pycolmap's own verification on ``matches`` instead.
        descriptors: optional N arrays (K_i, 128) float (unit-norm SIFT, scaled by 512 to uint8).
        overwrite: replace an existing ``db_path`` (otherwise PolarrefError).

    Returns:
        the COLMAP image ids (in ``image_names`` order) and the seconds of each step.
    """
    pycolmap = _pycolmap()
    cams = list(cameras) if isinstance(cameras, (list, tuple)) else [cameras]
    n = len(image_names)
    if len(keypoints) != n:
        raise PolarrefError(f"import_features: {n} image names but {len(keypoints)} keypoint arrays")
    cam_idx = np.zeros(n, np.int64) if camera_of_image is None else np.asarray(camera_of_image, np.int64)
    if cam_idx.shape != (n,) or (n and (cam_idx.min() < 0 or cam_idx.max() >= len(cams))):
        raise PolarrefError(f"import_features: camera_of_image must be ({n},) indices into {len(cams)} camera(s)")
    # Checked before the database exists, so bad input leaves no partial file behind.
    pairs = [_match_array(m, i, j) for (i, j), m in sorted(matches.items())]
    geoms = []
    for (i, j), g in sorted((verified or {}).items()):
        pose = getattr(g, "cam2_from_cam1", None)
        if i > j and pose is not None:
            pose = pose.inverse()
        geoms.append((*_match_array(g.inliers, i, j), pose))
    db_path = _fresh_database(db_path, overwrite)
    t0 = time.perf_counter()
    db = pycolmap.Database.open(str(db_path))
    try:
        cam_ids = []
        for cam in cams:
            pc = cam.to_pycolmap()
            pc.has_prior_focal_length = True  # trap 2 in the module docstring
            cam_ids.append(db.write_camera(pc))
        ids: list[int] = []
        for k, (name, kps) in enumerate(zip(image_names, keypoints)):
            image_id = db.write_image(pycolmap.Image(name=name, camera_id=int(cam_ids[cam_idx[k]])))
            ids.append(image_id)
            db.write_keypoints(image_id, np.ascontiguousarray(np.asarray(kps)[:, :2], dtype=np.float32))
            if descriptors is not None:
                d = np.clip(np.round(np.asarray(descriptors[k], np.float32) * 512.0), 0, 255).astype(np.uint8)
                db.write_descriptors(image_id, d)
        for i, j, m in pairs:
            db.write_matches(ids[i], ids[j], m)
        for i, j, inl, pose in geoms:
            db.write_two_view_geometry(ids[i], ids[j], two_view_geometry(inl, pose))
    finally:
        db.close()
    t1 = time.perf_counter()
    verification_s = None
    if verified is None:
        pairs_txt = db_path.with_suffix(".pairs.txt")
        pairs = sorted({(min(i, j), max(i, j)) for i, j in matches})
        pairs_txt.write_text("".join(f"{image_names[i]} {image_names[j]}\n" for i, j in pairs))
        pycolmap.verify_matches(str(db_path), str(pairs_txt), pycolmap.TwoViewGeometryOptions())
        verification_s = time.perf_counter() - t1
    return ImportedFeatures(tuple(int(i) for i in ids), t1 - t0, verification_s)


def copy_database(src: Path, dst: Path) -> Path:
    """A private copy for one mapper (mapping writes to the database)."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    for side in (dst.with_name(dst.name + "-wal"), dst.with_name(dst.name + "-shm")):
        side.unlink(missing_ok=True)  # SQLite would replay an older run's journal into the new copy
    shutil.copyfile(src, dst)
    return dst


# ---- mapping ------------------------------------------------------------------------------------
def run_mapper(db_path: Path, image_dir: Path, out_dir: Path, mapper: str = "incremental",
               opts: ColmapSfMOptions = ColmapSfMOptions()) -> ColmapSfMRun:
    """Map a prepared database; keeps the reconstruction with most registered images.

    pycolmap also writes every model to ``out_dir/0``, ``out_dir/1``, ...
    """
    pycolmap = _pycolmap()
    if mapper not in MAPPERS:
        raise PolarrefError(f"unknown pycolmap mapper {mapper!r} (choose from {', '.join(MAPPERS)})")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    if mapper == "incremental":
        recs = pycolmap.incremental_mapping(str(db_path), str(image_dir), str(out_dir),
                                            options=incremental_options(opts))
    else:
        recs = pycolmap.global_mapping(str(db_path), str(image_dir), str(out_dir), options=global_options(opts))
    return largest_model(recs, db_path, time.perf_counter() - t0)


def largest_model(recs, db_path: Path, mapping_s: float) -> ColmapSfMRun:
    """The run record of a mapper's output ``{index: Reconstruction}`` (None/empty: nothing mapped)."""
    recs = recs or {}
    best = max(recs.values(), key=lambda r: r.num_reg_images(), default=None)
    if best is not None:
        best.update_point_3d_errors()  # the mean error reads cached per-point errors
    return ColmapSfMRun(best, {"mapping": mapping_s}, num_models=len(recs),
                        verified_pairs=count_verified_pairs(db_path))


def run_sift_sfm(image_dir: Path, camera, work_dir: Path, opts: ColmapSfMOptions = ColmapSfMOptions(),
                 mapper: str = "incremental", image_names: Sequence[str] | None = None,
                 overwrite: bool = False) -> ColmapSfMRun:
    """pycolmap SIFT + exhaustive matching + mapping; database ``work_dir/database.db``, models in
    ``work_dir/sparse``. Timings of all stages are in the result."""
    work_dir = Path(work_dir)
    db = work_dir / "database.db"
    sift = extract_and_match_sift(image_dir, camera, db, opts, image_names=image_names, overwrite=overwrite)
    run = run_mapper(db, image_dir, work_dir / "sparse", mapper, opts)
    run.stage_runtime_s = {"features": sift.features, "matching": sift.matching, **run.stage_runtime_s}
    return run


# ---- pycolmap as a user runs it on photos -------------------------------------------------------
@dataclass
class DefaultSfMRun:
    """Every model of one pycolmap run with its defaults, largest first."""

    models: list = field(default_factory=list)    # pycolmap.Reconstruction, most registered first
    stage_runtime_s: dict[str, float] = field(default_factory=dict)
    verified_pairs: int = 0


def run_default_sfm(image_dir: Path, work_dir: Path, max_image_size: int = 3200, seed: int = 0,
                    num_threads: int = 1, overwrite: bool = False) -> DefaultSfMRun:
    """pycolmap on a folder of photos with its defaults: cameras from EXIF (``CameraMode.AUTO``,
    focal guessed where EXIF lacks it, refined), SIFT (8192 features), exhaustive matching,
    incremental mapping with several models. Only the image size, the seed and the thread
    count are set. Database ``work_dir/database.db``, models ``work_dir/sparse/<k>``."""
    pycolmap = _pycolmap()
    work_dir = Path(work_dir)
    db = _fresh_database(work_dir / "database.db", overwrite)
    extraction, matching = sift_options(ColmapSfMOptions(num_threads=num_threads, max_image_size=max_image_size))
    t0 = time.perf_counter()
    pycolmap.extract_features(str(db), str(image_dir), camera_mode=pycolmap.CameraMode.AUTO,
                              extraction_options=extraction, device=pycolmap.Device.cpu)
    t1 = time.perf_counter()
    pycolmap.match_exhaustive(str(db), matching_options=matching, device=pycolmap.Device.cpu)
    t2 = time.perf_counter()
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = num_threads
    opts.random_seed = seed
    opts.mapper.random_seed = seed
    out = work_dir / "sparse"
    out.mkdir(parents=True, exist_ok=True)
    recs = pycolmap.incremental_mapping(str(db), str(image_dir), str(out), options=opts) or {}
    models = sorted(recs.values(), key=lambda r: -r.num_reg_images())
    for r in models:
        r.update_point_3d_errors()
    return DefaultSfMRun(models, {"features": t1 - t0, "matching": t2 - t1, "mapping": time.perf_counter() - t2},
                         count_verified_pairs(db))
