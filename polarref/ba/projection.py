"""Pinhole + radial (k1, k2) projection kernel, vectorized over observations.

The hot path of the bundle adjuster: COLMAP's SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL and RADIAL
models are all ``u = fx x (1 + k1 r^2 + k2 r^4) + cx`` with ``(x, y) = (X, Y) / Z``, so one
kernel with per-observation (fx, fy, cx, cy, k1, k2) covers them. Other models go through
``Camera.project_with_jacobian`` (see :func:`intrinsics_table`). Points behind the camera are
projected anyway (finite residual), like Ceres' BAL example; COLMAP instead zeroes them.
"""

from __future__ import annotations

import copy

import numpy as np

RADIAL_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "PERSPECTIVE")


def radial_params(camera) -> np.ndarray | None:
    """(6,) fx, fy, cx, cy, k1, k2 of a Camera, or None when the model is not pinhole+radial."""
    p = np.asarray(camera.params, dtype=np.float64)
    m = camera.model
    if m in ("SIMPLE_PINHOLE", "PERSPECTIVE"):
        return np.array([p[0], p[0], p[1], p[2], 0.0, 0.0])
    if m == "PINHOLE":
        return np.array([p[0], p[1], p[2], p[3], 0.0, 0.0])
    if m == "SIMPLE_RADIAL":
        return np.array([p[0], p[0], p[1], p[2], p[3], 0.0])
    if m == "RADIAL":
        return np.array([p[0], p[0], p[1], p[2], p[3], p[4]])
    return None


def camera_groups(cameras, obs_cam: np.ndarray) -> list[tuple[object, np.ndarray]]:
    """(cameras[c], indices of the observations of camera c, ascending) per observed camera c.

    For work done camera by camera (camera models without the fast kernel, pixel lookups per
    image). cameras: a sequence indexed by camera index; obs_cam (M,) camera index per
    observation, negative = no camera.
    """
    order = np.argsort(obs_cam, kind="stable")
    cams, starts = np.unique(obs_cam[order], return_index=True)
    ends = np.r_[starts[1:], len(order)]
    return [(cameras[int(c)], order[a:b]) for c, a, b in zip(cams, starts, ends) if c >= 0]


def project(Xc: np.ndarray, K: np.ndarray, jac: bool = True):
    """Project camera-frame points.

    Args:
        Xc: (M, 3) camera-frame points.
        K: (M, 6) per-observation fx, fy, cx, cy, k1, k2.
        jac: also return ``uv_D_Xc``.

    Returns:
        uv (M, 2) and, if jac, uv_D_Xc (M, 2, 3).
    """
    fx, fy, cx, cy, k1, k2 = K.T
    X, Y, Z = Xc.T
    iz = 1.0 / Z
    x, y = X * iz, Y * iz
    r2 = x * x + y * y
    dist = 1.0 + r2 * (k1 + k2 * r2)
    uv = np.empty((len(Xc), 2))
    uv[:, 0] = fx * x * dist + cx
    uv[:, 1] = fy * y * dist + cy
    if not jac:
        return uv
    a = 2.0 * (k1 + 2.0 * k2 * r2)  # d dist / d r2, doubled
    # d(xd, yd)/d(x, y) = dist I + a (x, y)(x, y)^T, then d(x, y)/dXc = [I/Z, -(x, y)/Z]
    dxx, dxy, dyy = dist + a * x * x, a * x * y, dist + a * y * y
    J = np.empty((len(Xc), 2, 3))
    J[:, 0, 0] = fx * dxx * iz
    J[:, 0, 1] = fx * dxy * iz
    J[:, 0, 2] = -(J[:, 0, 0] * x + J[:, 0, 1] * y)
    J[:, 1, 0] = fy * dxy * iz
    J[:, 1, 1] = fy * dyy * iz
    J[:, 1, 2] = -(J[:, 1, 0] * x + J[:, 1, 1] * y)
    return uv, J


class Projector:
    """Projects observations with their camera's model: the fast kernel or Camera's own."""

    def __init__(self, cameras: list, obs_cam: np.ndarray, compiled: bool = False):
        """cameras: one Camera per problem camera (index = camera index); obs_cam (M,);
        compiled: :meth:`residuals` through the numba kernel (kernels.py) where it applies."""
        # one row per camera object: a mapper's BA has hundreds of images of one camera
        rows: dict[int, np.ndarray | None] = {}
        for c in cameras:
            if id(c) not in rows:
                rows[id(c)] = radial_params(c)
        table = [rows[id(c)] for c in cameras]
        self.fast = all(t is not None for t in table)
        self.compiled = compiled and self.fast
        if self.fast:
            self.K = np.array(table).reshape(-1, 6)[obs_cam]
        else:
            self.groups = camera_groups(cameras, obs_cam)

    def rows(self, m0: int, m1: int) -> "Projector":
        """This projector restricted to observations m0:m1 (fast kernel only)."""
        if not self.fast:
            raise ValueError("Projector.rows needs the pinhole+radial kernel")
        out = copy.copy(self)
        out.K = self.K[m0:m1]
        return out

    def residuals(self, Xc: np.ndarray, obs_uv: np.ndarray, k: int = 2, jac: bool = True):
        """Pixel residuals ``uv - obs_uv`` in rows 0:2 of an (M, k) array and, with jac,
        ``uv_D_Xc`` in rows 0:2 of an (M, k, 3) array (else None); rows 2: are left unset
        for the caller's own residual rows. The same values as :meth:`__call__`."""
        if self.compiled:
            from polarref.ba import kernels
            res, J = kernels.pixel_rows(np.ascontiguousarray(Xc), self.K, obs_uv, k, jac)
            return res, (J if jac else None)
        res = np.empty((len(Xc), k))
        if not jac:
            res[:, :2] = self(Xc, jac=False) - obs_uv
            return res, None
        uv, Juv = self(Xc)
        res[:, :2] = uv - obs_uv
        J = np.empty((len(Xc), k, 3))
        J[:, :2] = Juv
        return res, J

    def __call__(self, Xc: np.ndarray, jac: bool = True):
        if self.fast:
            return project(Xc, self.K, jac)
        uv = np.empty((len(Xc), 2))
        J = np.empty((len(Xc), 2, 3))
        for cam, idx in self.groups:
            uv[idx], J[idx] = cam.project_with_jacobian(Xc[idx])
        return (uv, J) if jac else uv
