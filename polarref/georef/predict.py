"""What pose-prior noise predicts for check points when the priors alone fix the datum.

With priors only, the block's shape comes from the images (centimetres) and its datum (7
parameters of a similarity) from the priors (metres): the check-point error is, to first order,
the datum error mapped to each point. Linearised at the true block, the datum error is the
weighted least-squares similarity fitted to the prior errors, with the weights the adjustment
uses (independent, 1/sigma^2) and the errors' true covariance (AR(1) along the image order, as
the twins draw them; ``correlation = 0`` for independent priors). Attitude priors (rotation error
in the camera frame) enter as observations of the datum rotation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.core.geometry import skew


@dataclass(frozen=True)
class PredictedRMSE:
    """Expected check-point RMSE (square root of the mean variance over the points), metres."""

    rmse_x: float
    rmse_y: float
    rmse_z: float
    rmse_horizontal: float


def _ar1(n: int, rho: float) -> np.ndarray:
    k = np.arange(n)
    return rho ** np.abs(k[:, None] - k[None, :])


def _datum_rows(points: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """(N, 3, 7) Jacobian of a point's displacement by the small similarity (t, omega, log s)."""
    d = points - origin
    rows = np.zeros((len(points), 3, 7))
    rows[:, :, :3] = np.eye(3)
    rows[:, :, 3:6] = -skew(d)
    rows[:, :, 6] = d
    return rows


def predict_priors_only(centres: np.ndarray, centre_sigma: np.ndarray, check: np.ndarray,
                        correlation: float = 0.0, rotations: np.ndarray | None = None,
                        rotation_sigma_rad: float | None = None) -> PredictedRMSE:
    """Expected check-point RMSE of a priors-only datum.

    Args:
        centres: (N, 3) true camera centres, in image order (the order of the AR(1) drift).
        centre_sigma: (N, 3) 1-sigma of each centre prior, world axes.
        check: (G, 3) check points.
        correlation: lag-one correlation of the prior errors along the image order.
        rotations: (N, 3, 3) cam_from_world, when attitude priors (camera-frame error) are used.
        rotation_sigma_rad: their 1-sigma per axis.
    """
    n = len(centres)
    origin = centres.mean(0)
    A = _datum_rows(centres, origin).reshape(3 * n, 7)   # row 3i+k: axis k of camera i
    w = 1.0 / centre_sigma.reshape(-1) ** 2
    corr = _ar1(n, correlation)
    # Sigma of the centre errors: axis k of cameras i and j correlate by rho^|i-j|
    S = np.kron(corr, np.eye(3)) * np.outer(centre_sigma.reshape(-1), centre_sigma.reshape(-1))
    blocks = [(A, w, S)]
    if rotations is not None and rotation_sigma_rad:
        Aa = np.zeros((n, 3, 7))
        Aa[:, :, 3:6] = rotations                            # camera-frame image of the datum rotation
        Sa = np.kron(corr, np.eye(3)) * rotation_sigma_rad**2
        blocks.append((Aa.reshape(3 * n, 7), np.full(3 * n, rotation_sigma_rad**-2.0), Sa))
    H = sum(Ab.T @ (wb[:, None] * Ab) for Ab, wb, _ in blocks)
    Hi = np.linalg.inv(H)
    # cov(theta) = H^-1 (sum_b A_b' W_b S_b W_b A_b) H^-1: the errors are uncorrelated across blocks
    M = sum((Ab.T * wb) @ Sb @ (wb[:, None] * Ab) for Ab, wb, Sb in blocks)
    cov = Hi @ M @ Hi
    J = _datum_rows(np.asarray(check, float), origin)
    var = np.einsum("gij,jk,gik->gi", J, cov, J).mean(0)
    rx, ry, rz = np.sqrt(var)
    return PredictedRMSE(float(rx), float(ry), float(rz), float(np.hypot(rx, ry)))
