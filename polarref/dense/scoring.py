"""Dense stage 6: score the fused cloud, the mesh and the depth maps against the synthetic GT.

The GT surface is ``mesh.ply`` of a rendered scene; its samples are restricted to the part at
least two GT views saw (a sample is seen by a view when it projects inside the image with a
z within ``vis_rel_tol`` of the rendered GT depth there): the reconstruction cannot be complete
where no image looked. Depth maps are compared with ``depth/*.npy`` after scaling the estimate
into GT units by the alignment's scale (z-depth scales with the similarity).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.metrics.surface import SurfaceScore, mesh_diameter, sample_mesh, score_cloud, score_mesh


@dataclass
class DepthError:
    """Per-view depth error vs the rendered GT depth (GT units) at the working resolution."""

    name: str
    coverage: float             # share of GT-surface pixels with an estimate
    median_abs: float           # median |depth - GT depth| over pixels with both
    within_tau: float           # share of those within tau


@dataclass
class GTScores:
    tau_rel: float
    tau: float
    diameter: float
    num_gt_samples: int
    alignment: str              # "identity (gt model)" or the metrics alignment's method
    alignment_scale: float
    cloud: SurfaceScore | None = None
    mesh: SurfaceScore | None = None
    depth: list[DepthError] | None = None
    depth_median_abs: float = float("nan")   # median over views
    depth_within_tau: float = float("nan")   # mean over views


def visible_samples(samples: np.ndarray, gt_views: list[tuple], min_views: int = 2,
                    vis_rel_tol: float = 0.005) -> np.ndarray:
    """Mask (S,) of samples seen by >= ``min_views`` of ``gt_views`` = [(cam_from_world, K, depth)]."""
    count = np.zeros(len(samples), np.int64)
    for pose, K, depth in gt_views:
        h, w = depth.shape
        Xc = pose.apply(samples)
        z = Xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = Xc[:, :2] / z[:, None] @ K[:2, :2].T + K[:2, 2]
        col = np.floor(np.nan_to_num(uv[:, 0], nan=-1)).astype(np.int64)
        row = np.floor(np.nan_to_num(uv[:, 1], nan=-1)).astype(np.int64)
        inside = (z > 0) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
        d = np.zeros(len(samples))
        d[inside] = depth[row[inside], col[inside]]
        count += inside & (d > 0) & (np.abs(z - d) <= vis_rel_tol * d)
    return count >= min_views


def gt_samples(vertices: np.ndarray, faces: np.ndarray, gt_views: list[tuple], n: int, seed: int) -> np.ndarray:
    S = sample_mesh(vertices, faces, n, seed)
    return S[visible_samples(S, gt_views)]


def depth_error(name: str, est: np.ndarray, gt_full: np.ndarray, scale: float, s: float, tau: float) -> DepthError:
    """``est`` (h, w) at ``scale`` x the GT depth map's (H, W) resolution, model units x ``s`` = GT units."""
    h, w = est.shape
    rows = np.minimum(((np.arange(h) + 0.5) / scale).astype(np.int64), gt_full.shape[0] - 1)
    cols = np.minimum(((np.arange(w) + 0.5) / scale).astype(np.int64), gt_full.shape[1] - 1)
    gt = gt_full[np.ix_(rows, cols)]
    surf = gt > 0
    both = surf & (est > 0)
    err = np.abs(est[both] * s - gt[both])
    return DepthError(name, float(both.sum() / max(surf.sum(), 1)),
                      float(np.median(err)) if len(err) else float("nan"),
                      float((err <= tau).mean()) if len(err) else float("nan"))


def score(cloud_gt, mesh_gt, gt_vertices, gt_faces, gt_views, tau_rel: float, alignment: str,
          s: float, depth_maps: list[tuple[str, np.ndarray, np.ndarray, float]], seed: int,
          num_samples: int = 60_000) -> GTScores:
    """Score the GT-frame cloud and mesh; ``depth_maps`` = [(name, est, gt_full, working scale)]."""
    diameter = mesh_diameter(gt_vertices)
    tau = tau_rel * diameter
    S = gt_samples(gt_vertices, gt_faces, gt_views, num_samples, seed)
    out = GTScores(tau_rel, tau, diameter, len(S), alignment, s)
    if cloud_gt is not None:
        out.cloud = score_cloud(cloud_gt.points, gt_vertices, gt_faces, S, tau, diameter, seed=seed)
    if mesh_gt is not None:
        out.mesh = score_mesh(mesh_gt.vertices, mesh_gt.faces, gt_vertices, gt_faces, S, tau, diameter,
                              num_samples=min(num_samples, 50_000), seed=seed)
    out.depth = [depth_error(n, est, g, sc, s, tau) for n, est, g, sc in depth_maps]
    med = [d.median_abs for d in out.depth if np.isfinite(d.median_abs)]
    wt = [d.within_tau for d in out.depth if np.isfinite(d.within_tau)]
    out.depth_median_abs = float(np.median(med)) if med else float("nan")
    out.depth_within_tau = float(np.mean(wt)) if wt else float("nan")
    return out
