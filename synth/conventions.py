"""The one place where Mitsuba's camera conventions meet COLMAP's.

Mitsuba's ``perspective`` sensor with ``to_world = M``: the camera looks down its local +z,
local +y is image-up and local +x points to the image *left* (a right-handed frame seen from
behind). COLMAP/OpenCV: +x right, +y down, +z forward. So the two camera frames differ by a
180 degree turn about z: ``world_from_cam_colmap.R = M[:3, :3] @ diag(-1, -1, 1)``.

Mitsuba's film maps pixel (i, j) to the square [i, i+1) x [j, j+1) with row 0 at the top,
exactly COLMAP's pixel-corner origin, and the principal point is the image centre. With
``fov_axis = "x"`` the horizontal field of view fixes ``fx = (W / 2) / tan(fov / 2)`` and pixels
are square (``fy = fx``). These statements are proven by the depth-reprojection test in
``tests/test_synth_geometry.py`` (a wrong flip fails it by tens of pixels).
"""

from __future__ import annotations

import math

import numpy as np

from polarref.core.geometry import Rigid3

_FLIP_XY = np.diag([-1.0, -1.0, 1.0])  # COLMAP camera axes expressed in Mitsuba's camera axes


def pinhole_params(width: int, height: int, fov_x_deg: float) -> np.ndarray:
    """COLMAP ``PINHOLE`` params ``(fx, fy, cx, cy)`` of a Mitsuba perspective sensor, (4,)."""
    f = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2.0)
    return np.array([f, f, 0.5 * width, 0.5 * height])


def mitsuba_to_world(cam_from_world: Rigid3) -> np.ndarray:
    """Mitsuba sensor ``to_world`` (4, 4) for a COLMAP ``cam_from_world`` pose."""
    M = np.eye(4)
    M[:3, :3] = cam_from_world.R.T @ _FLIP_XY
    M[:3, 3] = cam_from_world.center
    return M


def cam_from_world_from_mitsuba(to_world: np.ndarray) -> Rigid3:
    """Inverse of :func:`mitsuba_to_world`: COLMAP ``cam_from_world`` from a (4, 4) ``to_world``."""
    M = np.asarray(to_world, dtype=np.float64)
    R = (M[:3, :3] @ _FLIP_XY).T
    return Rigid3(R, -R @ M[:3, 3])


def look_at(center: np.ndarray, target: np.ndarray, up: np.ndarray, roll_deg: float = 0.0) -> Rigid3:
    """COLMAP ``cam_from_world`` of a camera at ``center`` looking at ``target``.

    Image-up is the projection of ``up`` (world, (3,)); then the camera turns by ``roll_deg``
    about its optical axis.
    """
    center = np.asarray(center, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - center
    z /= np.linalg.norm(z)
    down = -np.asarray(up, dtype=np.float64)
    y = down - z * (down @ z)
    n = np.linalg.norm(y)
    if n < 1e-9:  # looking along ``up``: any perpendicular will do
        y = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
        n = np.linalg.norm(y)
    y /= n
    x = np.cross(y, z)
    R = np.stack([x, y, z])  # rows: camera axes in world coordinates
    c, s = math.cos(math.radians(roll_deg)), math.sin(math.radians(roll_deg))
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ R
    return Rigid3(R, -R @ center)


def pixel_rays(params: np.ndarray, width: int, height: int) -> np.ndarray:
    """Unit-z ray directions (H, W, 3) in the COLMAP camera frame through every pixel centre."""
    fx, fy, cx, cy = params
    u = (np.arange(width) + 0.5 - cx) / fx
    v = (np.arange(height) + 0.5 - cy) / fy
    uu, vv = np.meshgrid(u, v)
    return np.stack([uu, vv, np.ones_like(uu)], -1)


def project(params: np.ndarray, cam_from_world: Rigid3, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points (..., 3) -> (pixels (..., 2) in COLMAP convention, z-depth (...))."""
    fx, fy, cx, cy = params
    Xc = cam_from_world.apply(X)
    z = Xc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([fx * Xc[..., 0] / z + cx, fy * Xc[..., 1] / z + cy], -1)
    return uv, z
