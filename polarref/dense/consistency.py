"""Dense stage 3: geometric-consistency filtering of the depth maps across views.

A reference pixel is kept when at least ``min_consistent`` of its source views agree with it:
its 3D point, projected into the source, lands on a source depth whose own 3D point projects
back within ``max_reproj_px`` of the reference pixel and within ``max_rel_depth`` in depth (the
forward-backward check of COLMAP's fusion and of Schoenberger et al. 2016, Sec. 4.3). Kept
pixels carry the mean of the agreeing 3D points, which averages out independent depth noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.dense.depth import DepthMap, backproject
from polarref.dense.views import DenseView


@dataclass(frozen=True)
class ConsistencyOptions:
    min_consistent: int = 2       # agreeing source views needed to keep a pixel
    max_reproj_px: float = 1.0
    max_rel_depth: float = 0.005


@dataclass
class FilteredView:
    """Surviving pixels of one view: points (P, 3) world, normals (P, 3) world unit,
    colors (P, 3) uint8, depth (H, W) float32 of the kept pixels (0 = dropped), support (P,) int."""

    points: np.ndarray
    normals: np.ndarray
    colors: np.ndarray
    depth: np.ndarray
    support: np.ndarray


def _project(view: DenseView, X_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    Xc = view.cam_from_world.apply(X_world)
    z = Xc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = Xc[..., :2] / z[..., None] @ view.K[:2, :2].T + view.K[:2, 2]
    return uv, z


def filter_view(i: int, views: list[DenseView], maps: list[DepthMap | None], sources: list[int],
                opt: ConsistencyOptions = ConsistencyOptions()) -> FilteredView:
    """Consistency-filter view ``i``'s depth map against the depth maps of ``sources``."""
    ref, dm = views[i], maps[i]
    h, w = ref.image.shape
    empty = FilteredView(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3), np.uint8),
                         np.zeros((h, w), np.float32), np.zeros(0, np.int64))
    if dm is None or not (dm.depth > 0).any():
        return empty
    vv, uu = np.nonzero(dm.depth > 0)
    world_from_ref = ref.cam_from_world.inverse()
    P = world_from_ref.apply(backproject(dm.depth, ref.K)[vv, uu])
    acc = P.copy()
    count = np.zeros(len(P), np.int64)
    uv_ref = np.stack([uu + 0.5, vv + 0.5], 1)
    for j in sources:
        sdm = maps[j]
        if sdm is None:
            continue
        src = views[j]
        sh, sw = src.image.shape
        uv, z = _project(src, P)
        col = np.floor(uv[:, 0]).astype(np.int64)
        row = np.floor(uv[:, 1]).astype(np.int64)
        inside = (z > 0) & (col >= 0) & (col < sw) & (row >= 0) & (row < sh)
        d_src = np.zeros(len(P), np.float32)
        d_src[inside] = sdm.depth[row[inside], col[inside]]
        has = d_src > 0
        # The source's own 3D point at the pixel it saw (its pixel centre, its depth).
        pix = np.stack([col + 0.5, row + 0.5], 1)
        Kinv = np.linalg.inv(src.K)
        rays = np.concatenate([pix, np.ones((len(P), 1))], 1) @ Kinv.T
        Q = src.cam_from_world.inverse().apply(rays * d_src[:, None])
        uv_back, z_back = _project(ref, Q)
        z_ref = dm.depth[vv, uu]
        ok = has & (np.linalg.norm(uv_back - uv_ref, axis=1) <= opt.max_reproj_px) \
            & (np.abs(z_back - z_ref) <= opt.max_rel_depth * z_ref)
        acc[ok] += Q[ok]
        count[ok] += 1
    keep = count >= opt.min_consistent
    pts = acc[keep] / (count[keep] + 1)[:, None]
    n_cam = dm.normal[vv[keep], uu[keep]].astype(np.float64)
    normals = n_cam @ ref.cam_from_world.R  # R^T n, row-wise
    depth = np.zeros((h, w), np.float32)
    depth[vv[keep], uu[keep]] = dm.depth[vv[keep], uu[keep]]
    return FilteredView(pts, normals, ref.color[vv[keep], uu[keep]], depth, count[keep])
