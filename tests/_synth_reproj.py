"""Depth-map reprojection between two views of a rendered scene (test helper)."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import map_coordinates

from polarref.core.geometry import Rigid3
from synth.conventions import pixel_rays, project
from synth.scene import Scene


def depth_reprojection(scene: Scene, i: int, j: int, flip: bool = False, rel_tol: float = 0.002):
    """Round-trip pixel error of view i's depth through view j's depth, for co-visible pixels.

    Back-project every pixel centre of view i with its depth, project into view j, read j's depth
    there (bilinear), back-project, project into i again, and return the pixel distances (K,)
    for pixels whose projected depth agrees with j's depth within ``rel_tol`` (co-visible and
    unoccluded) and whose 2x2 depth neighbourhood in j is all surface and smooth (spread below
    ``2 * rel_tol``: no silhouette or grazing surface, where a bilinear depth read is meaningless). ``flip=True`` applies a
    deliberately wrong convention (camera x and y not flipped) to show that the test can fail.
    """
    cam = scene.camera
    params = cam.params
    di, dj = scene.depth(i), scene.depth(j)
    Pi, Pj = scene.views[i].cam_from_world, scene.views[j].cam_from_world
    if flip:
        F = np.diag([-1.0, -1.0, 1.0])
        Pi, Pj = Rigid3(F @ Pi.R, F @ Pi.t), Rigid3(F @ Pj.R, F @ Pj.t)
    rays = pixel_rays(params, cam.width, cam.height)
    ok_i = di > 0
    Xw = Pi.inverse().apply(rays[ok_i] * di[ok_i][:, None].astype(np.float64))
    uv_j, z_j = project(params, Pj, Xw)
    x, y = uv_j[:, 0] - 0.5, uv_j[:, 1] - 0.5  # array coordinates of pixel centres
    inside = (z_j > 0) & (x >= 0) & (y >= 0) & (x <= cam.width - 1) & (y <= cam.height - 1)
    x, y, z_j, src = x[inside], y[inside], z_j[inside], np.argwhere(ok_i)[inside]
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, cam.width - 1), np.minimum(y0 + 1, cam.height - 1)
    quad = np.stack([dj[y0, x0], dj[y0, x1], dj[y1, x0], dj[y1, x1]]).astype(np.float64)
    full = (quad.min(0) > 0) & (np.ptp(quad, axis=0) < 2 * rel_tol * z_j)
    d_samp = map_coordinates(dj.astype(np.float64), [y, x], order=1)
    vis = full & (np.abs(d_samp - z_j) < rel_tol * z_j)
    # Back through j's depth map into i.
    ray_j = np.stack([(x[vis] + 0.5 - params[2]) / params[0], (y[vis] + 0.5 - params[3]) / params[1],
                      np.ones(vis.sum())], 1)
    Xw2 = Pj.inverse().apply(ray_j * d_samp[vis][:, None])
    uv_i, _ = project(params, Pi, Xw2)
    uv_src = src[vis][:, ::-1] + 0.5
    return np.linalg.norm(uv_i - uv_src, axis=1), int(ok_i.sum())
