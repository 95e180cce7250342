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


def _ar1(sequence: np.ndarray, rho: float) -> np.ndarray:
    k = np.asarray(sequence, float)
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
                        rotation_sigma_rad: float | None = None,
                        sequence: np.ndarray | None = None) -> PredictedRMSE:
    """Expected check-point RMSE of a priors-only datum.

    Args:
        centres: (N, 3) true camera centres, in image order (the order of the AR(1) drift).
        centre_sigma: (N, 3) 1-sigma of each centre prior, world axes.
        check: (G, 3) check points.
        correlation: lag-one correlation of the prior errors along the image order.
        rotations: (N, 3, 3) cam_from_world, when attitude priors (camera-frame error) are used.
        rotation_sigma_rad: their 1-sigma per axis.
        sequence: (N,) each view's index in the flight the drift was drawn along (default 0..N-1);
            a sub-block of a twin (synth.subblock) skips the twin's views between its lines.
    """
    n = len(centres)
    blocks = _blocks(centres, centre_sigma, rotations, rotation_sigma_rad)
    corr = np.kron(_ar1(np.arange(n) if sequence is None else sequence, correlation), np.eye(3))
    sd = [centre_sigma.reshape(-1), np.full(3 * n, rotation_sigma_rad or 0.0)]
    H = sum(Ab.T @ (wb[:, None] * Ab) for Ab, wb in blocks)
    Hi = np.linalg.inv(H)
    # cov(theta) = H^-1 (sum_b A_b' W_b S_b W_b A_b) H^-1: the errors are uncorrelated across blocks;
    # S_b: component k of views i and j correlate by rho^|s_i - s_j| (s: the sequence)
    M = sum((Ab.T * wb) @ (corr * np.outer(s, s)) @ (wb[:, None] * Ab) for (Ab, wb), s in zip(blocks, sd))
    cov = Hi @ M @ Hi
    J = _datum_rows(np.asarray(check, float), centres.mean(0))
    var = np.einsum("gij,jk,gik->gi", J, cov, J).mean(0)
    rx, ry, rz = np.sqrt(var)
    return PredictedRMSE(float(rx), float(ry), float(rz), float(np.hypot(rx, ry)))


def datum_error(centres: np.ndarray, centre_sigma: np.ndarray, check: np.ndarray, centre_error: np.ndarray,
                rotations: np.ndarray | None = None, rotation_sigma_rad: float | None = None,
                rotation_error: np.ndarray | None = None) -> np.ndarray:
    """(G, 3) check-point error the linear model gives for one draw of prior errors:
    ``centre_error`` (N, 3) prior - true centre; ``rotation_error`` (N, 3) the camera-frame
    rotation vector d of ``R_prior = exp(d) R_true``."""
    blocks = _blocks(centres, centre_sigma, rotations, rotation_sigma_rad)
    # a datum rotation omega turns camera i by -R_i omega in its own frame: the attitude rows
    # (+R_i) observe -d
    errs = [centre_error.reshape(-1)] + ([] if len(blocks) == 1 else [-rotation_error.reshape(-1)])
    H = sum(Ab.T @ (wb[:, None] * Ab) for Ab, wb in blocks)
    theta = np.linalg.solve(H, sum(Ab.T @ (wb * e) for (Ab, wb), e in zip(blocks, errs)))
    return np.einsum("gij,j->gi", _datum_rows(np.asarray(check, float), centres.mean(0)), theta)


def _blocks(centres, centre_sigma, rotations, rotation_sigma_rad):
    """[(A (3N, 7), weights (3N,))] of the centre priors and, if any, the attitude priors."""
    n = len(centres)
    blocks = [(_datum_rows(centres, centres.mean(0)).reshape(3 * n, 7), 1.0 / centre_sigma.reshape(-1) ** 2)]
    if rotations is not None and rotation_sigma_rad:
        Aa = np.zeros((n, 3, 7))
        Aa[:, :, 3:6] = rotations  # camera-frame image of the datum rotation
        blocks.append((Aa.reshape(3 * n, 7), np.full(3 * n, rotation_sigma_rad**-2.0)))
    return blocks
