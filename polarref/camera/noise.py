"""First-order propagation of isotropic pixel noise into angular pixel coordinates.

With pixel covariance ``sigma_px^2 I``, the (theta, phi) covariance is
``sigma_px^2 J J^T`` with ``J = Camera.to_angular_jacobian(uv)``. For fx == fy:
``sigma_theta = sigma_px theta'(rd) / f`` (about ``sigma_px / f`` near the centre) and
``sigma_phi = sigma_px / r_px`` with ``r_px`` the pixel distance from the principal point, so
phi carries no information near the principal point and first-order propagation fails there
(the Monte-Carlo distribution of phi becomes uniform once r_px ~ sigma_px).

Gating rule (for solvers): use the phi observation only where the first-order
``sigma_phi <= max_sigma_phi``. A sensible ``max_sigma_phi`` is a few times smaller than 1 rad
(e.g. 0.05 rad keeps the linearization valid; see tests/camera/test_camera_noise.py).
"""

from __future__ import annotations

import numpy as np

Array = np.ndarray


def angular_covariance(camera, uv, sigma_px: float) -> Array:
    """(theta, phi) covariance (..., 2, 2) [rad^2] of pixels (..., 2) with noise sigma_px [px].

    NaN at the principal point (phi undefined) and outside the model's reachable radius.
    """
    if not sigma_px >= 0:
        raise ValueError(f"sigma_px must be >= 0, got {sigma_px}")
    J = camera.to_angular_jacobian(uv)
    return sigma_px**2 * (J @ np.swapaxes(J, -1, -2))


def phi_sigma(camera, uv, sigma_px: float) -> Array:
    """First-order standard deviation of phi (...) [rad]; +inf at the principal point."""
    uv = np.asarray(uv, dtype=np.float64)
    if camera.model == "OPENCV":  # tangential terms: phi is not the pixel angle, use its gradient
        s = sigma_px * np.linalg.norm(camera.to_angular_jacobian(uv)[..., 1, :], axis=-1)
        return np.where(np.isfinite(s), s, np.inf)
    x = (uv[..., 0] - camera.principal_point[0]) / camera.fx
    y = (uv[..., 1] - camera.principal_point[1]) / camera.fy
    rd2 = x * x + y * y
    with np.errstate(divide="ignore", invalid="ignore"):
        # |grad_uv phi| = sqrt((y / fx)^2 + (x / fy)^2) / rd^2
        s = sigma_px * np.sqrt((y / camera.fx) ** 2 + (x / camera.fy) ** 2) / rd2
    return np.where(rd2 > 0, s, np.inf)


def phi_usable(camera, *, sigma_px: float, max_sigma_phi: float, uv=None, theta=None) -> Array:
    """Boolean mask (...): is phi informative enough to use as an observation?

    Give either ``uv`` (..., 2) (exact first-order sigma_phi) or ``theta`` (...) [rad] (the
    worst case over phi, ``sigma_px / (min(fx, fy) R(theta))``, exact for fx == fy; for OPENCV
    R is its radial part, ignoring the small tangential terms).
    Pixels/angles outside the model's valid range are reported unusable.
    """
    if (uv is None) == (theta is None):
        raise ValueError("phi_usable: give exactly one of uv or theta")
    if not (sigma_px >= 0 and max_sigma_phi > 0):
        raise ValueError(f"phi_usable: need sigma_px >= 0 and max_sigma_phi > 0, "
                         f"got {sigma_px}, {max_sigma_phi}")
    if uv is not None:
        s = phi_sigma(camera, uv, sigma_px)
        inside = np.isfinite(camera.to_angular(uv)[0])
    else:
        theta = np.asarray(theta, dtype=np.float64)
        inside = (theta >= 0) & (theta < camera.theta_max)
        rd = camera._radial.radius(np.where(inside, theta, 0.0))[0]
        with np.errstate(divide="ignore"):
            s = np.where(rd > 0, sigma_px / (min(camera.fx, camera.fy) * rd), np.inf)
    return inside & (s <= max_sigma_phi)


def phi_min_radius_px(sigma_px: float, max_sigma_phi: float) -> float:
    """Pixel radius (for fx == fy) below which :func:`phi_usable` rejects phi: ``sigma_px / max``."""
    if not (sigma_px >= 0 and max_sigma_phi > 0):
        raise ValueError(f"need sigma_px >= 0 and max_sigma_phi > 0, got {sigma_px}, {max_sigma_phi}")
    return sigma_px / max_sigma_phi
