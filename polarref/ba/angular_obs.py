"""Observed view angle theta and polar angle phi per observation, and their pixel Jacobians.

Observed angles are computed once per problem with ``Camera.to_angular_with_jacobian``
(grouped by camera), so lens distortion is undone through the camera model.

Predicted angles are taken on the *projective* ray ``sign(Z) Xc``: a perspective camera maps
``Xc`` and ``-Xc`` to the same pixel, and the pixel residual of the Euclidean form (like Ceres'
BAL example) does not enforce cheirality. Without the flip, a point behind its camera (31
observations of BAL Ladybug-49 at the initial estimate) gives a view-angle residual near
``pi - 2 theta`` (> 1000 px-equivalent) that dominated the polar and angular objectives and
dragged the solution away (polar diverged to 8.5 px RMS). With the flip every form minimizes
the same data in the same way; the count of such observations is reported (``behind_camera``).
"""

from __future__ import annotations

import numpy as np

from polarref.ba.problem import BAProblem
from polarref.ba.projection import camera_groups


def observed_angles(problem: BAProblem) -> tuple[np.ndarray, np.ndarray]:
    """(theta, phi) (M, 2) of the observed pixels and ``angular_D_uv`` (M, 2, 2)."""
    M = problem.num_observations
    ang = np.full((M, 2), np.nan)
    J = np.full((M, 2, 2), np.nan)
    for cam, idx in _camera_object_groups(problem):
        ang[idx], J[idx] = cam.to_angular_with_jacobian(problem.obs_uv[idx])
    return ang, J


def observed_view_angles(problem: BAProblem) -> tuple[np.ndarray, np.ndarray]:
    """theta (M,) of the observed pixels and ``theta_D_uv`` (M, 2): :func:`observed_angles`'
    first rows, bitwise, without phi (the polar form's set-up reads only these)."""
    M = problem.num_observations
    theta = np.full(M, np.nan)
    grad = np.full((M, 2), np.nan)
    for cam, idx in _camera_object_groups(problem):
        theta[idx], grad[idx] = cam.view_angle_with_gradient(problem.obs_uv[idx])
    return theta, grad


def _camera_object_groups(problem: BAProblem):
    """(camera, observation indices) per distinct camera object: one call per camera object,
    not per image (a mapper's local BA has ~26 images of one camera, and 26 calls were a
    sixth of the polar form's set-up there)."""
    reps, index = [], {}
    model_of = np.full(len(problem.cameras) + 1, -1, np.int64)  # [-1]: no camera
    for i, c in enumerate(problem.cameras):
        if id(c) not in index:
            index[id(c)] = len(reps)
            reps.append(c)
        model_of[i] = index[id(c)]
    if len(reps) == 1 and (problem.obs_cam >= 0).all():  # no sort to find the one group
        return [(reps[0], slice(None))]
    obs_model = model_of[np.where(problem.obs_cam >= 0, problem.obs_cam, -1)]
    return camera_groups(reps, obs_model)


def _projective(Xc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sign(Z) Xc, sign(Z)) with sign(0) = +1."""
    s = np.where(Xc[:, 2] < 0, -1.0, 1.0)
    return Xc * s[:, None], s


def theta_rows(Xc: np.ndarray, jac: bool):
    """Predicted theta (M,) of the projective ray and ``theta_D_Xc`` (M, 3)."""
    Xc, sgn = _projective(Xc)
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
    return theta, J * sgn[:, None]


def phi_rows(Xc: np.ndarray, jac: bool):
    """Predicted phi (M,) of the projective ray and ``phi_D_Xc`` (M, 3)."""
    Xc, sgn = _projective(Xc)
    phi = np.arctan2(Xc[:, 1], Xc[:, 0])
    if not jac:
        return phi, None
    rho2 = np.maximum(Xc[:, 0] ** 2 + Xc[:, 1] ** 2, 1e-300)
    J = np.zeros((len(Xc), 3))
    J[:, 0] = -Xc[:, 1] / rho2
    J[:, 1] = Xc[:, 0] / rho2
    return phi, J * sgn[:, None]


def wrap(a: np.ndarray) -> np.ndarray:
    """Angle difference wrapped to (-pi, pi]."""
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def axis_chart_rows(Xc: np.ndarray, jac: bool):
    """Azimuthal-equidistant chart ``e = theta (cos phi, sin phi)`` (M, 2) of the projective
    ray and ``e_D_Xc`` (M, 2, 3).

    Carries the same information as (theta, phi) but is smooth through the optical axis,
    where phi is undefined and theta alone is a cone: ``e = (theta / rho) (X, Y)`` with
    ``rho = |(X, Y)|`` (limit ``1 / Z`` on the axis).
    """
    Xc, sgn = _projective(Xc)
    x, y, z = Xc[:, 0], Xc[:, 1], Xc[:, 2]
    rho = np.hypot(x, y)
    theta = np.arctan2(rho, z)
    t = rho / np.where(z > 0, z, 1.0)
    near = (z > 0) & (t < 1e-3)
    with np.errstate(invalid="ignore", divide="ignore"):
        g = np.where(near, 1.0 / np.where(z > 0, z, 1.0), theta / np.where(near, 1.0, rho))
    e = np.stack([g * x, g * y], axis=1)
    if not jac:
        return e, None
    n2 = rho * rho + z * z
    with np.errstate(invalid="ignore", divide="ignore"):
        # q = (d g / d rho) / rho; its closed form cancels badly near the axis: series there
        q = np.where(near, (-2.0 / 3.0 + 0.8 * t * t) / np.where(near, z, 1.0) ** 3,
                     (rho * z / n2 - theta) / np.where(near, 1.0, rho) ** 3)
    J = np.empty((len(Xc), 2, 3))
    J[:, 0, 0] = g + q * x * x
    J[:, 0, 1] = J[:, 1, 0] = q * x * y
    J[:, 1, 1] = g + q * y * y
    J[:, 0, 2] = -x / n2
    J[:, 1, 2] = -y / n2
    return e, J * sgn[:, None, None]


def observed_axis_chart(problem: BAProblem, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Chart values (n, 2) of the observed pixels ``idx`` and ``e_D_uv`` (n, 2, 2), through
    ``Camera.unproject_with_jacobian`` (lens distortion included)."""
    e = np.full((len(idx), 2), np.nan)
    B = np.full((len(idx), 2, 2), np.nan)
    for cam, sel in camera_groups(problem.cameras, problem.obs_cam[idx]):
        ray, dray = cam.unproject_with_jacobian(problem.obs_uv[idx[sel]])
        e[sel], Je = axis_chart_rows(ray, True)
        B[sel] = Je @ dray
    return e, B
