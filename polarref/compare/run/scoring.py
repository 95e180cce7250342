"""Score a reconstruction for the report: counts, reprojection error, GT accuracy, plot data.

Every figure comes from ``polarref.metrics`` (the one metrics module, shared with ``polarref
sfm``); this module maps them onto the report schema and keeps small plot samples.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from polarref.compare.schema import GtAccuracy, Histogram, MethodPlot
from polarref.metrics import ReconstructionMetrics

log = logging.getLogger(__name__)

MAX_PLOT_POINTS = 1000     # points kept per method for the point-cloud figure and surface histogram
HIST_BINS = 40


@dataclass
class Score:
    """What the report needs from one reconstruction: the one metrics record, plus report extras."""

    metrics: ReconstructionMetrics   # polarref.metrics.evaluate, as computed (not copied)
    gt: GtAccuracy | None            # the GT part in the report's units (absolute and relative)
    plot: MethodPlot
    notes: list[str] = field(default_factory=list)


def _hist(values: np.ndarray, upper: float | None = None) -> Histogram | None:
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return None
    hi = upper if upper is not None else float(np.quantile(values, 0.99))
    hi = hi if hi > 0 else 1.0
    counts, edges = np.histogram(np.clip(values, 0.0, hi), bins=HIST_BINS, range=(0.0, hi))
    return Histogram([round(float(e), 6) for e in edges], [int(c) for c in counts])


def _round(a, significant: int = 6) -> list[list[float]]:
    """Plot coordinates to ``significant`` digits (keeps metrics.json small)."""
    return [[float(f"{v:.{significant}g}") for v in row] for row in np.asarray(a, dtype=np.float64)]


def _finite(x) -> float | None:
    return float(x) if x is not None and np.isfinite(x) else None


def load_mesh(mesh_path: Path | None):
    if mesh_path is None:
        return None
    from synth.meshes import read_mesh

    return read_mesh(mesh_path)


def score(rec, gt, mesh, seed: int = 0) -> Score:
    """Score ``rec`` (polarref Reconstruction) against ``gt`` (or None) and ``mesh`` ((V, F) or None)."""
    from polarref import metrics as M

    errors = M.observation_errors(rec)
    alignment = M.align_to_gt(rec, gt) if gt is not None and len(rec.images) >= 2 else None
    m = M.evaluate(rec, gt=gt, mesh=mesh if gt is not None else None, num_images=None,
                   errors=errors, alignment=alignment)
    errs = errors[0]
    plot = MethodPlot(reproj_hist=_hist(errs))
    lengths = np.array([len(p.track) for p in rec.points3D.values()], dtype=np.int64)
    if lengths.size and lengths.max() >= 2:  # one bin per track length (2, 3, ...), the last bin holds the longer ones
        top = int(min(lengths.max(), 40))
        counts = np.bincount(np.minimum(lengths, top), minlength=top + 1)[2:]
        plot.track_length_hist = Histogram([float(k) for k in range(2, top + 2)], [int(c) for c in counts])
    notes = []
    if np.isinf(errs).any():
        notes.append(f"{int(np.isinf(errs).sum())} observations behind their camera (error inf, "
                     "left out of the mean)")
    gt_acc = None
    if m.gt is not None:
        g = m.gt
        sim, _, names, _ = alignment
        est_by_name = {im.name: im for im in rec.images.values()}
        gt_by_name = {im.name: im for im in gt.images.values()}
        plot.image_names = names
        plot.centers_est_aligned = _round([sim.apply(est_by_name[n].cam_from_world.center) for n in names])
        plot.centers_gt = _round([gt_by_name[n].cam_from_world.center for n in names])
        rot = np.array([g.per_image[n].rotation_error_deg for n in names])
        plot.rotation_err_hist = _hist(rot)
        plot.rotation_err_deg = [float(f"{r:.6g}") for r in rot]
        _, xyz = rec.points_array()
        if len(xyz):
            rng = np.random.default_rng(seed)
            keep = np.sort(rng.choice(len(xyz), size=min(len(xyz), MAX_PLOT_POINTS), replace=False))
            sample = sim.apply(xyz[keep])
            plot.points_sample = _round(sample)
            if mesh is not None:
                d = M.point_to_mesh_distance(sample, mesh[0], mesh[1])
                plot.surface_err_hist = _hist(d / g.scene_size)
        s = m.surface
        gt_acc = GtAccuracy(
            aligned_images=g.num_matched,
            rotation_error_deg_mean=g.rotation_error_deg_mean, rotation_error_deg_median=g.rotation_error_deg_median,
            rotation_error_deg_max=g.rotation_error_deg_max,
            center_error_mean=g.center_error_rel_mean * g.scene_size,
            center_error_max=g.center_error_rel_max * g.scene_size,
            center_error_rel_mean=g.center_error_rel_mean,
            point_to_surface_mean=None if s is None else _finite(s.mean),
            point_to_surface_median=None if s is None else _finite(s.median),
            point_to_surface_p90=None if s is None else _finite(s.p90),
            point_to_surface_rel_median=None if s is None else _finite(s.median_rel),
            points_scored=0 if s is None else int(s.num_points))
        if g.num_alignment_outliers:
            notes.append(f"{g.num_alignment_outliers} camera(s) left out of the Sim3 fit as outliers "
                         "(errors still reported for all)")
    return Score(m, gt_acc, plot, notes)
