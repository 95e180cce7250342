"""Landmark parameterizations and their conversions to and from world XYZ, with Jacobians.

All functions are vectorized over leading axes (anchors broadcast against the landmarks).

* **Inverse depth** (anchor camera ``cam_from_world = (R, t)``, normalized bearing, rho):
  ``params = (x, y, rho)``, ``X_cam = (x, y, 1) / rho`` in the anchor camera, so
  ``X = C + R^T (x, y, 1) / rho``; rho = 1 / depth along the anchor's principal axis.
* **Inverse distance** (Sola et al. 2012): ``params = (alpha, beta, rho)`` with anchor point
  ``p0``: ``X = p0 + d(alpha, beta) / rho``; rho = 1 / Euclidean distance from p0.
* **Parallax angle** (ParallaxBA, Zhao et al. 2015): ``params = (alpha, beta, omega)`` with main
  anchor centre ``C_m`` and associate anchor centre ``C_a``. ``d = d(alpha, beta)`` is the world
  direction from C_m toward the point, ``phi_a`` the angle between d and ``C_a - C_m``, omega
  the angle at the point between the rays from C_m and C_a; the distance from C_m is
  ``|C_a - C_m| sin(omega + phi_a) / sin(omega)`` (law of sines) and the unnormalized ray from
  any centre C_i is ``sin(omega) (C_m - C_i) + |C_a - C_m| sin(omega + phi_a) d``.

``d(alpha, beta)`` is :func:`polarref.core.angular.direction_from_azimuth_elevation`.

Points at infinity (rho = 0, omega = 0) are representable. The ``xyz_from_*`` functions return
``(X, X_D_params, at_infinity)``: X and its Jacobian are NaN where ``at_infinity`` is True (or
a ValueError with ``strict=True``); never a silent inf. The ``homogeneous_from_*`` functions are
finite everywhere. The parallax form is singular (phi_a undefined) when d is parallel to the
baseline; its Jacobians are NaN there.
"""

from __future__ import annotations

import numpy as np

from polarref.core.angular import (azimuth_elevation_from_direction, direction_from_azimuth_elevation,
                              direction_jacobian)
from polarref.core.angular import last_axis as _last

Array = np.ndarray
_ERR = dict(invalid="ignore", divide="ignore", over="ignore")


def _infinity(X: Array, J: Array, at_inf: Array, strict: bool, what: str):
    if strict and np.any(at_inf):
        raise ValueError(f"{what}: {int(np.sum(at_inf))} landmark(s) at infinity have no XYZ")
    X = np.where(at_inf[..., None], np.nan, X)
    J = np.where(at_inf[..., None, None], np.nan, J)
    return X, J, at_inf


def _az_el_jacobian(v: Array) -> Array:
    """Jacobian (..., 2, 3) of (alpha, beta) = azimuth_elevation_from_direction(v)."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    rho2 = x * x + y * y
    rho = np.sqrt(rho2)
    n2 = rho2 + z * z
    with np.errstate(**_ERR):
        row_a = np.stack([-y / rho2, x / rho2, np.zeros_like(x)], -1)
        row_b = np.stack([-z * x / (rho * n2), -z * y / (rho * n2), rho / n2], -1)
    return np.stack([row_a, row_b], -2)


def _angle_between(p: Array, q: Array) -> tuple[Array, Array, Array]:
    """Angle (...) between vectors and its gradients w.r.t. p and q (..., 3) each."""
    cr = np.cross(p, q)
    s = np.linalg.norm(cr, axis=-1)
    c = np.sum(p * q, axis=-1)
    ang = np.arctan2(s, c)
    pn, qn = np.linalg.norm(p, axis=-1), np.linalg.norm(q, axis=-1)
    with np.errstate(**_ERR):
        ph, qh = p / pn[..., None], q / qn[..., None]
        cos, sin = np.cos(ang)[..., None], np.sin(ang)[..., None]
        d_p = (ph * cos - qh) / (pn[..., None] * sin)
        d_q = (qh * cos - ph) / (qn[..., None] * sin)
    return ang, d_p, d_q


# ---- inverse depth --------------------------------------------------------------------------

def homogeneous_from_inverse_depth(params, R, t) -> Array:
    """Homogeneous world point (..., 4) ``(R^T (x, y, 1) + rho C, rho)``; finite at infinity."""
    params = _last(params, 3, "params")
    R, t = np.asarray(R, float), np.asarray(t, float)
    m = np.concatenate([params[..., :2], np.ones(params.shape[:-1] + (1,))], -1)
    C = -np.einsum("...ji,...j->...i", R, t)
    return np.concatenate([np.einsum("...ji,...j->...i", R, m) + params[..., 2:3] * C,
                           params[..., 2:3]], -1)


def xyz_from_inverse_depth(params, R, t, *, strict: bool = False):
    """Inverse depth ``(x, y, rho)`` (..., 3) in anchor ``cam_from_world = (R (..., 3, 3), t (..., 3))``
    -> ``(X (..., 3), X_D_params (..., 3, 3), at_infinity (...))``."""
    params = _last(params, 3, "params")
    R, t = np.asarray(R, float), np.asarray(t, float)
    rho = params[..., 2]
    at_inf = rho == 0
    with np.errstate(**_ERR):
        irho = 1.0 / rho
        m = np.concatenate([params[..., :2], np.ones(rho.shape + (1,))], -1)
        Rt = np.swapaxes(R, -1, -2)
        X = np.einsum("...ij,...j->...i", Rt, m * irho[..., None] - t)
        J = np.concatenate([Rt[..., :, :2] * irho[..., None, None],
                            -np.einsum("...ij,...j->...i", Rt, m)[..., None] * (irho**2)[..., None, None]],
                           -1)
    return _infinity(X, J, at_inf, strict, "xyz_from_inverse_depth")


def inverse_depth_from_xyz(X, R, t) -> tuple[Array, Array]:
    """World points (..., 3) -> ``(params (..., 3), params_D_X (..., 3, 3))`` in the anchor camera.

    Points with anchor-frame z <= 0 (at or behind the anchor's image plane) give NaN.
    """
    X = _last(X, 3, "X")
    R, t = np.asarray(R, float), np.asarray(t, float)
    Xc = np.einsum("...ij,...j->...i", R, X) + t
    z = Xc[..., 2]
    ok = z > 0
    with np.errstate(**_ERR):
        iz = 1.0 / z
        params = np.stack([Xc[..., 0] * iz, Xc[..., 1] * iz, iz], -1)
        zero = np.zeros_like(z)
        dp = np.stack([np.stack([iz, zero, -Xc[..., 0] * iz**2], -1),
                       np.stack([zero, iz, -Xc[..., 1] * iz**2], -1),
                       np.stack([zero, zero, -iz**2], -1)], -2)
        J = dp @ R
    return np.where(ok[..., None], params, np.nan), np.where(ok[..., None, None], J, np.nan)


# ---- inverse distance -------------------------------------------------------------------------

def homogeneous_from_inverse_distance(params, p0) -> Array:
    """Homogeneous world point (..., 4) ``(d + rho p0, rho)``; finite at infinity."""
    params = _last(params, 3, "params")
    d = direction_from_azimuth_elevation(params[..., 0], params[..., 1])
    rho = params[..., 2:3]
    return np.concatenate([d + rho * np.asarray(p0, float), rho], -1)


def xyz_from_inverse_distance(params, p0, *, strict: bool = False):
    """``(alpha, beta, rho)`` (..., 3) with anchor p0 (..., 3) ->
    ``(X (..., 3), X_D_params (..., 3, 3), at_infinity (...))``."""
    params = _last(params, 3, "params")
    alpha, beta, rho = params[..., 0], params[..., 1], params[..., 2]
    at_inf = rho == 0
    d = direction_from_azimuth_elevation(alpha, beta)
    D = direction_jacobian(alpha, beta)
    with np.errstate(**_ERR):
        irho = 1.0 / rho
        X = np.asarray(p0, float) + d * irho[..., None]
        J = np.concatenate([D * irho[..., None, None], (-d * (irho**2)[..., None])[..., None]], -1)
    return _infinity(X, J, at_inf, strict, "xyz_from_inverse_distance")


def inverse_distance_from_xyz(X, p0) -> tuple[Array, Array]:
    """World points (..., 3) -> ``(params (..., 3), params_D_X (..., 3, 3))``; NaN where X == p0."""
    X = _last(X, 3, "X")
    v = X - np.asarray(p0, float)
    alpha, beta = azimuth_elevation_from_direction(v)
    n = np.linalg.norm(v, axis=-1)
    with np.errstate(**_ERR):
        rho = np.where(n > 0, 1.0 / n, np.nan)
        J = np.concatenate([_az_el_jacobian(v), (-v / n[..., None] ** 3)[..., None, :]], -2)
    return np.stack([alpha, beta, rho], -1), J


# ---- parallax angle ----------------------------------------------------------------------

def _parallax_parts(params, C_m, C_a):
    params = _last(params, 3, "params")
    alpha, beta, omega = params[..., 0], params[..., 1], params[..., 2]
    C_m, C_a = np.asarray(C_m, float), np.asarray(C_a, float)
    base = C_a - C_m
    b = np.linalg.norm(base, axis=-1)
    d = direction_from_azimuth_elevation(alpha, beta)
    D = direction_jacobian(alpha, beta)
    with np.errstate(**_ERR):
        u = base / b[..., None]
        c = np.sum(d * u, axis=-1)
        s = np.linalg.norm(np.cross(d, u), axis=-1)
        phi = np.arctan2(s, c)
        # phi = acos(d . u) on the unit sphere: dphi/d(alpha, beta) = -(u^T D) / sin(phi)
        dphi = -np.einsum("...i,...ij->...j", u, D) / s[..., None]
    return omega, b, u, d, D, phi, dphi


def parallax_ray(params, C_m, C_a, C_i) -> tuple[Array, Array]:
    """Unnormalized ray (..., 3) from centre C_i toward the point, and its Jacobian (..., 3, 3)
    w.r.t. ``(alpha, beta, omega)``; finite for omega = 0 (the ray is then ``b sin(phi_a) d``)."""
    omega, b, u, d, D, phi, dphi = _parallax_parts(params, C_m, C_a)
    C_m, C_i = np.asarray(C_m, float), np.asarray(C_i, float)
    so = np.sin(omega)
    sp = np.sin(omega + phi)
    cp = np.cos(omega + phi)
    ray = so[..., None] * (C_m - C_i) + (b * sp)[..., None] * d
    J_ab = (b * sp)[..., None, None] * D + (b * cp)[..., None, None] * d[..., :, None] * dphi[..., None, :]
    J_om = np.cos(omega)[..., None] * (C_m - C_i) + (b * cp)[..., None] * d
    return ray, np.concatenate([J_ab, J_om[..., None]], -1)


def homogeneous_from_parallax(params, C_m, C_a) -> Array:
    """Homogeneous world point (..., 4) ``(sin(w) C_m + b sin(w + phi_a) d, sin(w))``."""
    omega, b, u, d, D, phi, dphi = _parallax_parts(params, C_m, C_a)
    so = np.sin(omega)[..., None]
    return np.concatenate([so * np.asarray(C_m, float) + (b * np.sin(omega + phi))[..., None] * d,
                           so], -1)


def xyz_from_parallax(params, C_m, C_a, *, strict: bool = False):
    """``(alpha, beta, omega)`` (..., 3) with anchor centres C_m, C_a (..., 3) ->
    ``(X (..., 3), X_D_params (..., 3, 3), at_infinity (...))``; at infinity when omega == 0."""
    omega, b, u, d, D, phi, dphi = _parallax_parts(params, C_m, C_a)
    at_inf = omega == 0
    with np.errstate(**_ERR):
        so = np.sin(omega)
        dist = b * np.sin(omega + phi) / so
        ddist_dphi = b * np.cos(omega + phi) / so
        ddist_domega = -b * np.sin(phi) / so**2
        X = np.asarray(C_m, float) + dist[..., None] * d
        J_ab = dist[..., None, None] * D + d[..., :, None] * (ddist_dphi[..., None] * dphi)[..., None, :]
        J = np.concatenate([J_ab, (ddist_domega[..., None] * d)[..., None]], -1)
    return _infinity(X, J, at_inf, strict, "xyz_from_parallax")


def parallax_from_xyz(X, C_m, C_a) -> tuple[Array, Array]:
    """World points (..., 3) -> ``(params (..., 3), params_D_X (..., 3, 3))`` for given anchors.

    omega is the angle at X between the rays from C_m and C_a, in [0, pi]. NaN where X
    coincides with an anchor centre.
    """
    X = _last(X, 3, "X")
    vm = X - np.asarray(C_m, float)
    va = X - np.asarray(C_a, float)
    alpha, beta = azimuth_elevation_from_direction(vm)
    omega, d_vm, d_va = _angle_between(vm, va)
    bad = (np.linalg.norm(vm, axis=-1) == 0) | (np.linalg.norm(va, axis=-1) == 0)
    J = np.concatenate([_az_el_jacobian(vm), (d_vm + d_va)[..., None, :]], -2)
    params = np.stack([alpha, beta, np.where(bad, np.nan, omega)], -1)
    return params, np.where(bad[..., None, None], np.nan, J)


def choose_associate_anchor(bearings_world: Array, main_index: int = 0) -> int:
    """Index of the observation whose world bearing makes the largest angle with the main
    anchor's (ParallaxBA's choice of associate anchor); ``bearings_world`` is (L, 3), L >= 2."""
    b = _last(bearings_world, 3, "bearings_world")
    if len(b) < 2:
        raise ValueError("choose_associate_anchor: need at least two observations")
    bn = b / np.linalg.norm(b, axis=-1, keepdims=True)
    ang = np.arccos(np.clip(bn @ bn[main_index], -1.0, 1.0))
    ang[main_index] = -1.0
    return int(np.argmax(ang))
