"""Observed view angle theta and polar angle phi per observation, and their pixel Jacobians.

Computed once per problem with ``Camera.to_angular_with_jacobian`` (grouped by camera).
"""

from __future__ import annotations

import numpy as np

from polarref.ba.problem import BAProblem


def observed_angles(problem: BAProblem) -> tuple[np.ndarray, np.ndarray]:
    """(theta, phi) (M, 2) of the observed pixels and ``angular_D_uv`` (M, 2, 2)."""
    M = problem.num_observations
    ang = np.full((M, 2), np.nan)
    J = np.full((M, 2, 2), np.nan)
    for i, cam in enumerate(problem.cameras):
        idx = np.flatnonzero(problem.obs_cam == i)
        if len(idx):
            ang[idx], J[idx] = cam.to_angular_with_jacobian(problem.obs_uv[idx])
    return ang, J


def theta_rows(Xc: np.ndarray, jac: bool):
    """Predicted theta (M,) = atan2(rho, Z) and ``theta_D_Xc`` (M, 3)."""
    rho2 = Xc[:, 0] ** 2 + Xc[:, 1] ** 2
    rho = np.sqrt(rho2)
    theta = np.arctan2(rho, Xc[:, 2])
    if not jac:
        return theta, None
    n2 = rho2 + Xc[:, 2] ** 2
    rho_s = np.maximum(rho, 1e-300)  # theta is a cone at the axis; any subgradient will do
    J = np.empty((len(Xc), 3))
    f = Xc[:, 2] / (rho_s * n2)
    J[:, 0] = Xc[:, 0] * f
    J[:, 1] = Xc[:, 1] * f
    J[:, 2] = -rho / n2
    return theta, J


def phi_rows(Xc: np.ndarray, jac: bool):
    """Predicted phi (M,) = atan2(Y, X) and ``phi_D_Xc`` (M, 3)."""
    phi = np.arctan2(Xc[:, 1], Xc[:, 0])
    if not jac:
        return phi, None
    rho2 = np.maximum(Xc[:, 0] ** 2 + Xc[:, 1] ** 2, 1e-300)
    J = np.zeros((len(Xc), 3))
    J[:, 0] = -Xc[:, 1] / rho2
    J[:, 1] = Xc[:, 0] / rho2
    return phi, J


def wrap(a: np.ndarray) -> np.ndarray:
    """Angle difference wrapped to (-pi, pi]."""
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)
