"""Angular coordinates: directions from azimuth/elevation and the camera's angular observations.

Project convention (binding for every polarref module):

* A direction is ``d(alpha, beta) = (cos(beta) cos(alpha), cos(beta) sin(alpha), sin(beta))``:
  azimuth ``alpha`` from world +x toward +y, elevation ``beta`` from the x-y plane toward +z.
* Polar rotation angles (e_y, e_x, e_z) (the paper's camera rotations, applied in the order
  e_y -> e_x -> e_z) are passive intrinsic rotations about x, the new y, the new z::

      cam_from_world = Rz(e_z) @ Ry(e_x) @ Rx(e_y)          (a COLMAP rotation)
      world_from_cam = Rx(-e_y) @ Ry(-e_x) @ Rz(-e_z)       (rotation_from_polar_angles)

  with right-handed active ``Rx(t) = [[1, 0, 0], [0, cos t, -sin t], [0, sin t, cos t]]`` etc.
  At zero angles the camera axes equal the world axes, so the principal axis (camera +z) points
  up (world +z). The principal axis is ``(-sin e_x, sin e_y cos e_x, cos e_y cos e_x)``.
  This is the convention under which the paper's Eq. 3-10 hold (after replacing asin by acos
  in Eq. 3, with sigma_1 = -sigma_2); see ``reports/derivations.md``.
* The camera frame is COLMAP's: +x right, +y down, +z forward (principal axis). For a ray
  ``r`` in that frame, the view angle is ``theta = atan2(hypot(r_x, r_y), r_z)`` in [0, pi] and
  the polar angle is ``phi = atan2(r_y, r_x)`` in (-pi, pi], from image +x (right) toward
  image +y (down) -- the same definition as :mod:`polarref.camera`. On the axis (theta = 0)
  phi is reported as 0 and its Jacobian is NaN.

This module is hand-written runtime code; the SymPy derivations that prove and generate the
heavier formulas live in :mod:`derivations` and their output in :mod:`polarref._generated`.
SymPy is never imported here.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from polarref._generated.angles import polar_angle_with_jacobian, view_angle_with_jacobian
from polarref.core.geometry import axis_rotation

Array = NDArray[np.float64]


def _f64(x: ArrayLike) -> Array:
    return np.asarray(x, dtype=np.float64)


def last_axis(a: ArrayLike, n: int, name: str) -> Array:
    """``a`` as float64 with shape (..., n); ValueError naming ``name`` otherwise."""
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != n:
        raise ValueError(f"{name} must have shape (..., {n}), got {a.shape}")
    return a


def _nan_rows(out: Array, alpha: Array, beta: Array, trailing: int) -> Array:
    """Whole output rows NaN where any input is NaN (z = sin(beta) alone would hide a NaN alpha)."""
    bad = np.isnan(alpha) | np.isnan(beta)
    return np.where(bad.reshape(bad.shape + (1,) * trailing), np.nan, out)


def direction_from_azimuth_elevation(alpha: ArrayLike, beta: ArrayLike) -> Array:
    """Unit direction vector from azimuth and elevation.

    Args:
        alpha: (...) azimuth [rad], from +x toward +y.
        beta: (...) elevation [rad], from the x-y plane toward +z.

    Returns:
        (..., 3) unit vectors ``(cos b cos a, cos b sin a, sin b)``; leading axes broadcast.
        A NaN in alpha or beta makes the whole row NaN.
    """
    alpha, beta = np.broadcast_arrays(_f64(alpha), _f64(beta))
    cb = np.cos(beta)
    d = np.stack([cb * np.cos(alpha), cb * np.sin(alpha), np.sin(beta)], axis=-1)
    return _nan_rows(d, alpha, beta, 1)


def azimuth_elevation_from_direction(d: ArrayLike) -> tuple[Array, Array]:
    """Inverse of :func:`direction_from_azimuth_elevation`; ``d`` need not be unit length.

    Args:
        d: (..., 3) direction vectors (any positive length).

    Returns:
        ``(alpha, beta)``, each (...): alpha in (-pi, pi], beta in [-pi/2, pi/2]. At the poles
        (d parallel to +-z) alpha is 0 by convention. A zero vector or NaN component gives NaN
        for both angles.
    """
    d = _f64(d)
    if d.shape[-1:] != (3,):
        raise ValueError(f"direction must have shape (..., 3), got {d.shape}")
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    # Adding +0.0 turns a -0.0 y into +0.0, so atan2 returns +pi (never -pi) on the -x axis.
    alpha = np.arctan2(y + 0.0, x)
    rho = np.hypot(x, y)
    beta = np.arctan2(z, rho)
    zero = (rho == 0.0) & (z == 0.0)
    alpha = np.where(zero, np.nan, np.where(rho == 0.0, 0.0, alpha))
    beta = np.where(zero, np.nan, beta)
    return alpha, beta


def direction_jacobian(alpha: ArrayLike, beta: ArrayLike) -> Array:
    """Jacobian ``d_D_alpha_beta`` of :func:`direction_from_azimuth_elevation`.

    Args:
        alpha: (...) azimuth [rad].
        beta: (...) elevation [rad].

    Returns:
        (..., 3, 2): column 0 is dd/dalpha ``(-cb sa, cb ca, 0)``, column 1 is dd/dbeta
        ``(-sb ca, -sb sa, cb)``. Column 0 vanishes at the poles (|beta| = pi/2), where
        azimuth is undefined. A NaN in alpha or beta makes the whole (3, 2) block NaN.
    """
    alpha, beta = np.broadcast_arrays(_f64(alpha), _f64(beta))
    ca, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
    zero = np.zeros_like(alpha)
    col_a = np.stack([-cb * sa, cb * ca, zero], axis=-1)
    col_b = np.stack([-sb * ca, -sb * sa, cb], axis=-1)
    return _nan_rows(np.stack([col_a, col_b], axis=-1), alpha, beta, 2)


def rotation_from_polar_angles(e_y: ArrayLike, e_x: ArrayLike, e_z: ArrayLike) -> Array:
    """World-from-camera rotation for the polar rotation angles (see the module docstring).

    Args:
        e_y: (...) first rotation [rad] (passive, about x).
        e_x: (...) second rotation [rad] (passive, about the new y).
        e_z: (...) third rotation [rad] (passive, about the new z = principal axis).

    Returns:
        (..., 3, 3) ``world_from_cam = Rx(-e_y) Ry(-e_x) Rz(-e_z)``; its columns are the camera
        x (image right), y (image down) and z (principal axis) axes in world coordinates, and its
        transpose is the COLMAP ``cam_from_world`` rotation. NaN in any angle -> all-NaN matrix.
    """
    e_y, e_x, e_z = np.broadcast_arrays(_f64(e_y), _f64(e_x), _f64(e_z))
    # axis_rotation keeps the zeros exact for NaN angles; NaN-ness is restored below
    R = axis_rotation(0, -e_y) @ axis_rotation(1, -e_x) @ axis_rotation(2, -e_z)
    bad = np.isnan(e_y) | np.isnan(e_x) | np.isnan(e_z)
    return np.where(bad[..., None, None], np.nan, R)


def principal_axis(e_y: ArrayLike, e_x: ArrayLike) -> Array:
    """Principal axis (third column of :func:`rotation_from_polar_angles`); no e_z dependence.

    Returns:
        (..., 3) unit vector ``(-sin e_x, sin e_y cos e_x, cos e_y cos e_x)``.
    """
    e_y, e_x = np.broadcast_arrays(_f64(e_y), _f64(e_x))
    cx = np.cos(e_x)
    a = np.stack([-np.sin(e_x), np.sin(e_y) * cx, np.cos(e_y) * cx], axis=-1)
    return np.where((np.isnan(e_y) | np.isnan(e_x))[..., None], np.nan, a)


def tilt_and_axis_azimuth(e_y: ArrayLike, e_x: ArrayLike) -> tuple[Array, Array]:
    """Stable replacements for the paper's Eq. 4 (e) and Eq. 5 (v, with sigma_1, sigma_2).

    ``e`` is the angle of the principal axis from world +z (Eq. 4: cos e = cos e_y cos e_x) and
    ``psi`` is the principal axis' azimuth, so that the paper's
    ``sigma_2 cos(sigma_1 v + alpha) = cos(alpha - psi)``. Both use atan2 of the axis components,
    which stays accurate as e -> 0 (where Eq. 4's acos loses half the digits and Eq. 5 is 0/0)
    and at |e_y| = pi/2 (where Eq. 5 is inf/inf).

    Returns:
        ``(e, psi)``, each (...): e in [0, pi], psi in (-pi, pi] (psi = 0 where e = 0).
    """
    a = principal_axis(e_y, e_x)
    rho = np.hypot(a[..., 0], a[..., 1])
    e = np.arctan2(rho, a[..., 2])
    psi = np.arctan2(a[..., 1] + 0.0, a[..., 0])
    psi = np.where(rho == 0.0, 0.0, psi)
    return e, np.where(np.isnan(e), np.nan, psi)


def ray_angles(r_cam: ArrayLike) -> tuple[Array, Array]:
    """View and polar angle of camera-frame rays (any positive length).

    Args:
        r_cam: (..., 3) rays in the COLMAP camera frame.

    Returns:
        ``(theta, phi)``, each (...): theta = atan2(hypot(x, y), z) in [0, pi]; phi =
        atan2(y, x) in (-pi, pi] (0 on the axis). A zero or NaN ray gives NaN for both.
    """
    r = _f64(r_cam)
    if r.shape[-1:] != (3,):
        raise ValueError(f"ray must have shape (..., 3), got {r.shape}")
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    rho = np.hypot(x, y)
    theta = np.arctan2(rho, z)
    phi = np.where(rho == 0.0, 0.0, np.arctan2(y + 0.0, x))
    zero = (rho == 0.0) & (z == 0.0)
    return np.where(zero, np.nan, theta), np.where(zero | np.isnan(theta), np.nan, phi)


def view_angle(alpha: ArrayLike, beta: ArrayLike, e_y: ArrayLike, e_x: ArrayLike) -> Array:
    """View angle theta of landmark direction (alpha, beta) for a camera rotated (e_y, e_x, .).

    The verified form of the paper's Eq. 3 (which needs acos, not asin): theta is the angle
    between ``d(alpha, beta)`` and the principal axis ``a``, computed as
    ``atan2(|a x d|, a . d)`` so it is accurate to a few ulp everywhere, including theta near
    0 and pi. Independent of e_z (the paper's claim 7).

    Args:
        alpha, beta: (...) landmark azimuth and elevation [rad] relative to the camera centre.
        e_y, e_x: (...) first two polar rotation angles [rad].

    Returns:
        (...) theta in [0, pi]; NaN where any input is NaN.
    """
    a = principal_axis(e_y, e_x)
    d = direction_from_azimuth_elevation(alpha, beta)
    a, d = np.broadcast_arrays(a, d)
    return np.arctan2(np.linalg.norm(np.cross(a, d), axis=-1), np.sum(a * d, axis=-1))


def view_angle_jacobian(alpha: ArrayLike, beta: ArrayLike, e_y: ArrayLike, e_x: ArrayLike) -> Array:
    """``theta_D_angles``: d theta / d(alpha, beta, e_y, e_x), shape (..., 4).

    At theta = 0 or pi theta is not differentiable (cone point); the row is 0 there (a valid
    subgradient). NaN inputs give NaN rows.
    """
    return view_angle_with_jacobian(alpha, beta, e_y, e_x)[1]


def polar_angle(alpha: ArrayLike, beta: ArrayLike, e_y: ArrayLike, e_x: ArrayLike,
                e_z: ArrayLike) -> Array:
    """Polar angle phi of landmark direction (alpha, beta) for a camera rotated (e_y, e_x, e_z).

    ``phi = atan2(r_y, r_x)`` with ``r = cam_from_world d`` in the COLMAP camera frame: from
    image +x (right) toward image +y (down), in (-pi, pi]. Equivalently
    ``phi = atan2(q_y, q_x) + e_z`` (wrapped) with ``q = Ry(e_x) Rx(e_y) d``: e_z enters only as
    an additive offset.

    Returns:
        (...) phi; 0 where the ray lies on the principal axis; NaN where any input is NaN.
    """
    d = direction_from_azimuth_elevation(alpha, beta)
    R = rotation_from_polar_angles(e_y, e_x, e_z)
    r = np.einsum("...ji,...j->...i", R, d)  # cam_from_world = R^T
    return ray_angles(r)[1]


def polar_angle_jacobian(alpha: ArrayLike, beta: ArrayLike, e_y: ArrayLike, e_x: ArrayLike,
                         e_z: ArrayLike) -> Array:
    """``phi_D_angles``: d phi / d(alpha, beta, e_y, e_x, e_z), shape (..., 5).

    The e_z column is 1. On the principal axis (theta = 0 or pi) phi is undefined and the row is
    NaN; near it the entries grow like 1 / sin(theta).
    """
    return polar_angle_with_jacobian(alpha, beta, e_y, e_x, e_z)[1]
