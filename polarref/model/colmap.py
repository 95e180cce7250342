"""Every conversion to and from pycolmap, and every pycolmap option builder, in one place.

* :func:`to_pycolmap` / :func:`from_pycolmap`: :class:`~polarref.model.reconstruction.Reconstruction`
  <-> ``pycolmap.Reconstruction``; :func:`rigid_to_pycolmap` / :func:`rigid_from_pycolmap` for
  one pose; :func:`two_view_geometry` for a verified pair written into a database.
* :func:`bundle_adjustment_options` / :func:`bundle_adjustment_config`: the one pycolmap
  bundle-adjuster set-up, used by the BA peer (``polarref.ba.peers``) and by the mapper's
  ``ba="colmap"`` (``polarref.sfm.bundle``).
* :func:`incremental_options` / :func:`global_options`: the SfM pipeline options
  (``polarref.peers.colmap_sfm``).

Robust loss: Ceres' Huber / Cauchy take one scale ``a`` (the knee at ``|r| = a`` on a residual
block's norm) and so do ours (``polarref.ba.losses``, ``rho(s)`` on ``s = |r|^2``, Ceres'
convention). The one mapping therefore passes the loss name AND its scale, so COLMAP minimises
the same objective as ours. (The mapper's copy used to leave the scale at pycolmap's default; it
called us with the default scale 1.0 too, so no result changes: the mapping now cannot drift
when a caller sets another scale.) "trivial" is set explicitly rather than left to the default.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from dataclasses import dataclass

import numpy as np

from polarref.camera import Camera
from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3
from polarref.model.colmap_text import check_text_model
from polarref.model.reconstruction import Image, Point3D, Reconstruction

LOSS_TYPES = ("trivial", "huber", "cauchy")


# ---- poses and reconstructions ----------------------------------------------------------------
def rigid_to_pycolmap(pose: Rigid3):
    """``pycolmap.Rigid3d`` of a :class:`polarref.core.geometry.Rigid3`."""
    import pycolmap

    return pycolmap.Rigid3d(pycolmap.Rotation3d(np.asarray(pose.R, np.float64)),
                            np.asarray(pose.t, np.float64))


def rigid_from_pycolmap(pose) -> Rigid3:
    """:class:`polarref.core.geometry.Rigid3` of a ``pycolmap.Rigid3d``."""
    return Rigid3(pose.rotation.matrix(), pose.translation)


def to_pycolmap(rec):
    """A ``pycolmap.Reconstruction`` of ``rec`` (trivial rigs and frames; our ids kept)."""
    import pycolmap

    rec.check_cameras()
    out = pycolmap.Reconstruction()
    for cam_id, cam in rec.cameras.items():
        try:
            out.add_camera_with_trivial_rig(cam.to_pycolmap(int(cam_id)))
        except ValueError as exc:
            raise PolarrefError(f"camera {cam_id}: {exc}") from exc
    for img in rec.images.values():
        pimg = pycolmap.Image(name=img.name, keypoints=np.asarray(img.keypoints, dtype=np.float64),
                              camera_id=int(img.camera_id), image_id=int(img.image_id))
        out.add_image_with_trivial_frame(pimg, rigid_to_pycolmap(img.cam_from_world))
    for pid, p in sorted(rec.points3D.items()):
        track = pycolmap.Track()
        for image_id, idx in p.track:
            track.add_element(int(image_id), int(idx))
        point = pycolmap.Point3D(xyz=np.asarray(p.xyz, dtype=np.float64), track=track,
                                 color=np.asarray(p.color, dtype=np.uint8))
        out.add_point3D_with_id(int(pid), point)  # keeps our ids; links the images' points2D
    return out


def from_pycolmap(rec):
    """Copy a ``pycolmap.Reconstruction`` into a Reconstruction; only posed images are kept."""
    out = Reconstruction()
    for cam_id, c in rec.cameras.items():
        try:
            out.cameras[int(cam_id)] = Camera.from_pycolmap(c)
        except ValueError as exc:
            raise PolarrefError(f"camera {cam_id}: {exc}") from exc
    for image_id, im in rec.images.items():
        if not im.has_pose:
            continue
        kps = np.array([p.xy for p in im.points2D], dtype=np.float64).reshape(-1, 2)
        ids = np.array([p.point3D_id if p.has_point3D() else -1 for p in im.points2D],
                       dtype=np.int64)
        out.images[int(image_id)] = Image(int(image_id), im.name, int(im.camera_id),
                                          rigid_from_pycolmap(im.cam_from_world()), kps, ids)
    for pid, p in rec.points3D.items():
        track = np.array([(e.image_id, e.point2D_idx) for e in p.track.elements],
                         dtype=np.int64).reshape(-1, 2)
        out.points3D[int(pid)] = Point3D(np.array(p.xyz, dtype=np.float64), track,
                                         float(p.error), np.array(p.color, dtype=np.uint8))
    return out


def two_view_geometry(inliers: np.ndarray, cam2_from_cam1: Rigid3 | None):
    """A CALIBRATED ``pycolmap.TwoViewGeometry`` of inlier matches (K, 2) and, when known, the
    relative pose (pycolmap's initial-pair choice and triangulation-angle checks read it)."""
    import pycolmap

    from polarref.core.geometry import skew

    g = pycolmap.TwoViewGeometry()
    g.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
    g.inlier_matches = inliers
    if cam2_from_cam1 is not None:
        R, t = np.asarray(cam2_from_cam1.R, float), np.asarray(cam2_from_cam1.t, float)
        g.cam2_from_cam1 = pycolmap.Rigid3d(pycolmap.Rotation3d(R), t)
        g.E = skew(t) @ R
    return g


# ---- bundle adjustment ------------------------------------------------------------------------
@dataclass(frozen=True)
class CeresSettings:
    """Stopping rules and threads of one pycolmap (Ceres) configuration."""

    name: str = "colmap-defaults"
    function_tolerance: float = 0.0      # COLMAP's defaults (pycolmap 4.2.1 BundleAdjustmentOptions)
    gradient_tolerance: float = 1e-4
    parameter_tolerance: float = 0.0
    max_num_iterations: int = 100
    num_threads: int = -1                # -1: all cores
    # Ceres runs single-threaded below this many residuals whatever num_threads says (COLMAP: 50,000)
    min_residuals_for_multithreading: int = 50_000
    # Ceres linear solver and preconditioner by name ("DENSE_SCHUR", "SCHUR_JACOBI", ...);
    # "" keeps COLMAP's own choice by problem size (auto_select_solver_type)
    linear_solver: str = ""
    preconditioner: str = ""
    max_solver_time_s: float = 0.0       # > 0: Ceres' max_solver_time_in_seconds (a cap, recorded)

    def with_iterations(self, n: int) -> "CeresSettings":
        return dataclasses.replace(self, max_num_iterations=int(n))


def loss_function_type(loss: str):
    """``pycolmap.LossFunctionType`` of one of :data:`LOSS_TYPES`."""
    import pycolmap

    if loss not in LOSS_TYPES:
        raise ValueError(f"unknown loss {loss!r}; choose one of {', '.join(LOSS_TYPES)}")
    return getattr(pycolmap.LossFunctionType, loss.upper())


def bundle_adjustment_options(ceres: CeresSettings, loss: str = "trivial", loss_scale: float = 1.0,
                              refine: tuple = ()):
    """``pycolmap.BundleAdjustmentOptions``: the intrinsics groups ``refine`` (focal, pp, dist)
    refined, rigs held, the robust loss with its scale (module docstring), ``ceres``' stopping
    rules and threads."""
    import pycolmap

    opts = pycolmap.BundleAdjustmentOptions()
    opts.refine_focal_length = "focal" in refine
    opts.refine_principal_point = "pp" in refine
    opts.refine_extra_params = "dist" in refine
    opts.refine_sensor_from_rig = False  # trivial rigs: nothing to refine
    opts.print_summary = False
    opts.ceres.loss_function_type = loss_function_type(loss)
    opts.ceres.loss_function_scale = float(loss_scale)
    so = opts.ceres.solver_options
    so.max_num_iterations = ceres.max_num_iterations
    so.function_tolerance = ceres.function_tolerance
    so.gradient_tolerance = ceres.gradient_tolerance
    so.parameter_tolerance = ceres.parameter_tolerance
    so.num_threads = ceres.num_threads
    opts.ceres.min_num_residuals_for_cpu_multi_threading = ceres.min_residuals_for_multithreading
    if ceres.linear_solver:  # a fixed solver: COLMAP's size rule would override it
        opts.ceres.auto_select_solver_type = False
        so.linear_solver_type = getattr(type(so.linear_solver_type), ceres.linear_solver)
    if ceres.preconditioner:
        so.preconditioner_type = getattr(type(so.preconditioner_type), ceres.preconditioner)
    if ceres.max_solver_time_s > 0:
        so.max_solver_time_in_seconds = float(ceres.max_solver_time_s)
    return opts


def bundle_adjustment_config(prec, image_ids, fixed_image_ids=(), constant_intrinsics: bool = False):
    """``pycolmap.BundleAdjustmentConfig`` over ``image_ids`` of the pycolmap reconstruction
    ``prec``; the poses of ``fixed_image_ids`` held; with fewer than two fixed images the 7 gauge
    DoF are fixed COLMAP's way (two camera poses, TWO_CAMS_FROM_WORLD); with
    ``constant_intrinsics`` every camera's intrinsics are held in the config."""
    import pycolmap

    config = pycolmap.BundleAdjustmentConfig()
    for image_id in image_ids:
        config.add_image(int(image_id))
    for image_id in fixed_image_ids:
        config.set_constant_rig_from_world_pose(prec.images[int(image_id)].frame_id)
    if constant_intrinsics:
        for cam_id in prec.cameras:
            config.set_constant_cam_intrinsics(cam_id)
    if len(fixed_image_ids) < 2:
        config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    return config


# ---- SfM pipelines ----------------------------------------------------------------------------
def incremental_options(opts):
    """``pycolmap.IncrementalPipelineOptions`` of a ``polarref.peers.colmap_sfm.ColmapSfMOptions``
    with intrinsics held fixed everywhere (except the groups ``opts.refine`` in the BAs)."""
    import pycolmap

    o = pycolmap.IncrementalPipelineOptions()
    o.num_threads = opts.num_threads
    o.random_seed = opts.seed
    o.mapper.random_seed = opts.seed
    o.multiple_models = opts.multiple_models
    # Intrinsics known: held fixed in every BA and in absolute pose estimation; with
    # opts.refine the BAs refine those groups (absolute pose still holds them, like polarref).
    o.ba_refine_focal_length = "focal" in opts.refine
    o.ba_refine_principal_point = "pp" in opts.refine
    o.ba_refine_extra_params = "dist" in opts.refine
    o.mapper.abs_pose_refine_focal_length = False
    o.mapper.abs_pose_refine_extra_params = False
    return o


def global_options(opts):
    """``pycolmap.GlobalPipelineOptions`` of a ``ColmapSfMOptions``: intrinsics held fixed
    (except ``opts.refine``), CPU only."""
    import pycolmap

    o = pycolmap.GlobalPipelineOptions()
    o.num_threads = opts.num_threads
    o.random_seed = opts.seed
    o.mapper.random_seed = opts.seed
    ba = o.mapper.bundle_adjustment
    ba.refine_focal_length = "focal" in opts.refine
    ba.refine_principal_point = "pp" in opts.refine
    ba.refine_extra_params = "dist" in opts.refine
    # Default True; on this CPU build they only warn. Say what we mean.
    ba.ceres.use_gpu = False
    o.mapper.global_positioning.use_gpu = False
    return o


def read_model(path: str | Path) -> Reconstruction:
    """Read a COLMAP model folder (text or binary) into a Reconstruction."""
    import pycolmap

    path = Path(path)
    if not path.is_dir():
        raise PolarrefError(f"COLMAP model folder not found: {path}")
    names = {p.name for p in path.iterdir()}
    if not ({"cameras.txt", "images.txt"} <= names or {"cameras.bin", "images.bin"} <= names):
        raise PolarrefError(f"not a COLMAP model (no cameras/images .txt or .bin): {path}")
    binary = {"cameras.bin", "images.bin", "points3D.bin"} <= names
    if not binary:  # pycolmap reads the binary files when all three are there, else the text
        check_text_model(path)
    try:
        rec = pycolmap.Reconstruction(str(path))
        # inside the try: names that are not UTF-8 fail only when converted
        return from_pycolmap(rec)
    except Exception as exc:  # pycolmap raises generic errors on malformed files
        raise PolarrefError(f"cannot read COLMAP model {path}: {_reader_failure(exc, binary)}") from exc


def _reader_failure(exc: Exception, binary: bool) -> str:
    """pycolmap's failure in our words: its ``Check failed: <C++ expression>`` names neither
    the file nor the line, so only the file it was reading is kept."""
    text = " ".join(str(exc).split())
    if isinstance(exc, PolarrefError):  # ours, converting what pycolmap read: already our words
        return text
    if "Check failed" not in text:
        return f"malformed or truncated model files (pycolmap: {text[:120]})"
    low = text.lower()
    kind = "points3D" if "point3d" in low else "images" if "image" in low else \
        "cameras" if "camera" in low else "model"
    ext = "bin" if binary else "txt"
    return (f"{kind}.{ext} is malformed or truncated" if kind != "model"
            else f"the {ext} files are malformed or truncated")
