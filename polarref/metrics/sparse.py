"""The one metrics module every reconstruction is scored with (ours, pycolmap's, every BA variant).

Definitions (all in the JSON as written here):

* ``registered_images``: images with a pose; ``tie_points``: 3D points; ``reprojected_px``:
  observations (2D points attached to a 3D point).
* ``mean_reprojection_error_px``: mean over OBSERVATIONS of |uv - project(X)|.
  ``mean_reprojection_error_px_per_point``: mean over points of the mean error of each point's
  track (COLMAP's ``compute_mean_reprojection_error``).
* Ground truth: the estimate is mapped into the GT frame by a similarity (``gt ~ s R est + t``).
  With well-spread camera centres: Umeyama on the centres; when the centres are near-collinear
  (the rotation about their line is unobservable): R = chordal mean of ``R_gt_i^T R_est_i``, then
  s and t by least squares on the centres. Then, with >= 6 images, cameras with a centre residual
  above 3x the median are dropped and the fit repeated once (robust to a few bad poses; the
  errors below are still reported for ALL matched images).
* ``rotation_error_deg``: angle of ``R_est_i R^T R_gt_i^T`` per image (mean, median, max), R
  from the similarity above.
* ``rotation_error_rotalign_deg``: the same with R = chordal mean of ``R_gt_i^T R_est_i`` (the
  best common rotation, whatever the centres say). On narrow-field orbits the centre-based R
  is itself uncertain by ~0.1 deg, which then dominates the figure above; this one measures
  the relative rotations only (measured on the 12-view comet: 0.17 vs 0.10 deg, and 0.12 vs
  0.09 deg on a rerun with other settings).
* ``center_error_rel``: |c_gt - (s R c_est + t)| / scene_size, with scene_size the RMS distance
  of the GT camera centres from their centroid (falls back to the RMS distance of GT points
  from their centroid when all cameras coincide).
* Point-to-surface: exact Euclidean distance from each aligned 3D point to the triangle mesh
  (closest point on triangle, Ericson 2005, 5.1.5), reported in GT units and divided by
  scene_size.
* Dense surfaces (clouds, meshes): accuracy, completeness and F-score at tau (ETH3D / Tanks and
  Temples) in :mod:`polarref.metrics.surface`, re-exported here.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from polarref.core.geometry import Sim3, rotation_angle_deg, umeyama
from polarref.core import records
from polarref.core.atomic import atomic_write
from polarref.metrics.distance import point_to_mesh_distance
# The records live in the data model (so a MethodRun can embed them); scored here.
from polarref.model.scores import (SCHEMA_VERSION, GTErrors, ImageGTErrors,  # noqa: F401 (re-exported)
                                   ReconstructionMetrics, SurfaceErrors)

COLLINEAR_RATIO = 1e-3  # 2nd / 1st singular value of centred camera centres below this: near-collinear


# ---- reprojection ----------------------------------------------------------------------------
def observation_errors(rec) -> tuple[np.ndarray, np.ndarray]:
    """(errors (A,), point index (A,)) of every observation: :meth:`Reconstruction.observation_errors`
    (point index into ``sorted(rec.points3D)``; behind a camera or not finite: ``inf``)."""
    return rec.observation_errors()


def mean_error_per_point(errs: np.ndarray, pidx: np.ndarray, num_points: int) -> np.ndarray:
    """Mean of each point's finite observation errors, (num_points,); 0 for a point with none.

    Args:
        errs: (A,) and pidx: (A,) as returned by :func:`observation_errors`.
    """
    finite = np.isfinite(errs)
    return (np.bincount(pidx[finite], weights=errs[finite], minlength=num_points)
            / np.maximum(np.bincount(pidx[finite], minlength=num_points), 1))


# ---- alignment -------------------------------------------------------------------------------
def _chordal_mean(Rs: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(Rs.sum(0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _fit(R_est, c_est, R_gt, c_gt) -> tuple[Sim3, str]:
    cg = c_gt - c_gt.mean(0)
    ce = c_est - c_est.mean(0)
    sv_g, sv_e = np.linalg.svd(cg, compute_uv=False), np.linalg.svd(ce, compute_uv=False)
    spread = len(c_gt) >= 3 and sv_g[1] > COLLINEAR_RATIO * sv_g[0] and sv_e[1] > COLLINEAR_RATIO * sv_e[0]
    if spread:
        return umeyama(c_est, c_gt, with_scale=True), "umeyama_centers"
    # cam_from_est = cam_from_gt * gt_from_est  =>  R_est_i = R_gt_i R  =>  R = R_gt_i^T R_est_i
    R = _chordal_mean(np.swapaxes(R_gt, 1, 2) @ R_est)
    rc = ce @ R.T
    den = float((rc**2).sum())
    s = float((cg * rc).sum() / den) if den > 0 else 1.0
    t = c_gt.mean(0) - s * R @ c_est.mean(0)
    return Sim3(s, R, t), "rotations_then_centers"


def align_to_gt(rec, gt) -> tuple[Sim3, str, list[str], int]:
    """Similarity ``gt ~ s R est + t`` from images matched by name.

    Returns:
        (sim3, method, matched names, number of cameras excluded as outliers).
    Raises:
        ValueError: fewer than 2 matched images.
    """
    gt_by_name = {im.name: im for im in gt.images.values()}
    names = sorted(im.name for im in rec.images.values() if im.name in gt_by_name)
    if len(names) < 2:
        raise ValueError(f"need >= 2 images matched to ground truth by name, got {len(names)}")
    est_by_name = {im.name: im for im in rec.images.values()}
    R_est = np.array([est_by_name[n].cam_from_world.R for n in names])
    c_est = np.array([est_by_name[n].cam_from_world.center for n in names])
    R_gt = np.array([gt_by_name[n].cam_from_world.R for n in names])
    c_gt = np.array([gt_by_name[n].cam_from_world.center for n in names])
    sim, method = _fit(R_est, c_est, R_gt, c_gt)
    n_out = 0
    if len(names) >= 6:
        res = np.linalg.norm(sim.apply(c_est) - c_gt, axis=1)
        inl = res <= max(3.0 * float(np.median(res)), 1e-12)
        if (~inl).any() and inl.sum() >= 3:
            sim, method = _fit(R_est[inl], c_est[inl], R_gt[inl], c_gt[inl])
            n_out = int((~inl).sum())
    return sim, method, names, n_out


def scene_size(gt) -> float:
    c = gt.centers()
    size = float(np.sqrt(((c - c.mean(0)) ** 2).sum(1).mean())) if len(c) else 0.0
    if size <= 0 and gt.points3D:
        _, X = gt.points_array()
        size = float(np.sqrt(((X - X.mean(0)) ** 2).sum(1).mean()))
    return size if size > 0 else 1.0


def gt_errors(rec, gt, alignment: tuple[Sim3, str, list[str], int] | None = None) -> GTErrors:
    """Pose errors of ``rec`` against ``gt``; ``alignment``: a result of :func:`align_to_gt` to reuse."""
    sim, method, names, n_out = alignment if alignment is not None else align_to_gt(rec, gt)
    size = scene_size(gt)
    gt_by_name = {im.name: im for im in gt.images.values()}
    est_by_name = {im.name: im for im in rec.images.values()}
    rot, cen = [], []
    for n in names:
        aligned = sim.transform_pose(est_by_name[n].cam_from_world)
        g = gt_by_name[n].cam_from_world
        r = float(rotation_angle_deg(aligned.R, g.R))
        c = float(np.linalg.norm(aligned.center - g.center) / size)
        rot.append(r)
        cen.append(c)
    rot, cen = np.array(rot), np.array(cen)
    R_est = np.array([est_by_name[n].cam_from_world.R for n in names])
    R_gt = np.array([gt_by_name[n].cam_from_world.R for n in names])
    R_al = _chordal_mean(np.swapaxes(R_gt, 1, 2) @ R_est)
    rot2 = rotation_angle_deg(R_est @ R_al.T, R_gt)
    per = {n: ImageGTErrors(float(r), float(c), float(r2)) for n, r, c, r2 in zip(names, rot, cen, rot2)}
    return GTErrors(len(names), method, n_out, float(sim.s), size,
                    float(rot.mean()), float(np.median(rot)), float(rot.max()),
                    float(cen.mean()), float(np.median(cen)), float(cen.max()),
                    float(rot2.mean()), float(rot2.max()), per)


def surface_errors(rec, sim: Sim3, vertices: np.ndarray, faces: np.ndarray, size: float) -> SurfaceErrors:
    _, X = rec.points_array()
    d = point_to_mesh_distance(sim.apply(X), vertices, faces) if len(X) else np.zeros(0)
    if not len(d):
        return SurfaceErrors(0, float("nan"), float("nan"), float("nan"), float("nan"), float("nan"))
    return SurfaceErrors(len(d), float(d.mean()), float(np.median(d)), float(np.percentile(d, 90)),
                         float(d.mean() / size), float(np.median(d) / size))


# ---- all together ----------------------------------------------------------------------------
def evaluate(rec, gt=None, mesh: tuple[np.ndarray, np.ndarray] | None = None,
             num_images: int | None = None, *,
             errors: tuple[np.ndarray, np.ndarray] | None = None,
             alignment: tuple[Sim3, str, list[str], int] | None = None) -> ReconstructionMetrics:
    """Score a :class:`polarref.model.Reconstruction`.

    Args:
        gt: ground-truth Reconstruction (images matched by name), optional.
        mesh: (vertices (V, 3), faces (F, 3)) in GT coordinates, optional (needs gt).
        num_images: input image count (default: images in rec).
        errors: a result of :func:`observation_errors` for ``rec`` to reuse.
        alignment: a result of :func:`align_to_gt` for ``rec`` and ``gt`` to reuse.
    """
    errs, pidx = errors if errors is not None else observation_errors(rec)
    n_pts = len(rec.points3D)
    finite = np.isfinite(errs)
    per_point = mean_error_per_point(errs, pidx, n_pts)
    m = ReconstructionMetrics(
        num_images=int(num_images if num_images is not None else len(rec.images)),
        registered_images=len(rec.images),
        tie_points=n_pts,
        reprojected_px=int(len(errs)),
        mean_reprojection_error_px=float(errs[finite].mean()) if finite.any() else float("nan"),
        mean_reprojection_error_px_per_point=float(per_point.mean()) if n_pts else float("nan"),
        median_reprojection_error_px=float(np.median(errs[finite])) if finite.any() else float("nan"),
        mean_track_length=float(len(errs) / n_pts) if n_pts else 0.0,
    )
    if gt is not None and len(rec.images) >= 2:
        alignment = alignment if alignment is not None else align_to_gt(rec, gt)
        m.gt = gt_errors(rec, gt, alignment)
        if mesh is not None:
            m.surface = surface_errors(rec, alignment[0], mesh[0], mesh[1], m.gt.scene_size)
    return m


def read_metrics(data: dict, *, label: str = "metrics.json") -> ReconstructionMetrics:
    """The :class:`ReconstructionMetrics` under ``"metrics"`` of a parsed ``polarref sfm``
    metrics.json, read strictly (``polarref compare``'s: ``polarref.compare.schema.load``, whose
    ``MethodResult.metrics`` is the same record).

    Raises:
        polarref.core.records.RecordError: wrong schema version, no metrics, or a key that is not a
            ReconstructionMetrics field.
    """
    version = data.get("schema_version") if isinstance(data, dict) else None
    if version != SCHEMA_VERSION or isinstance(version, bool):
        raise records.RecordError(f"{label}: unsupported schema_version {version!r} (this polarref "
                                  f"reads {SCHEMA_VERSION} for polarref sfm output)")
    if not isinstance(data.get("metrics"), dict):
        raise records.RecordError(f"{label}: no metrics object")
    return records.from_dict(ReconstructionMetrics, data["metrics"], label=label, where="metrics")


def write_json(path: str | Path, data: dict) -> None:
    atomic_write(path, json.dumps(data, indent=2, default=_jsonable) + "\n")


def _jsonable(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if hasattr(o, "__dataclass_fields__"):
        return asdict(o)
    return str(o)
