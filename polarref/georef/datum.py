"""The similarity that places a model onto its priors, each prior weighted as the BA weights it.

Why not only the unweighted similarity of the centres (Umeyama): with the priors on, the BA's
optimum for a block whose shape the tie points hold is the similarity that minimises the prior
blocks of polarref.ba.priors (centres whitened by their sigmas, attitudes, control points), and
that can lie metres from the centres' unweighted fit (anisotropic sigmas, attitude priors). The
BA alone does not get there reliably: moving the whole block is a direction the tie points do not
resist but the Jacobi-scaled LM damping does (it is scaled by the image terms), so the first
steps are short, and on a large block their decrease is below the function tolerance
(|d cost| / cost < 1e-6 of a cost the tie points dominate): LM stops where it started. Starting
from this similarity leaves the BA only the block's shape to adjust.

Minimised over ``x -> s Q x + t`` (Gauss-Newton, analytic Jacobians, from Umeyama's fit):
``W_k (s Q C_k + t - c_k)`` per centre prior, ``log(R_a Q^T R0_a^T) / sigma_a`` per attitude
prior, ``W_g (s Q X_g + t - x_g)`` per control point triangulated in the model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.ba.priors import so3_left_jacobian_inv
from polarref.core.geometry import Sim3, skew, so3_exp, so3_log, umeyama

MAX_ITERATIONS = 50
STEP_TOLERANCE = 1e-12  # relative to the model's size (translation) and in radians / log-scale


@dataclass(frozen=True)
class DatumPriors:
    """What places the model: points of the model ``src`` (P, 3) with their priors ``dst`` (P, 3)
    and whitening ``W`` (P, 3, 3) (camera centres, control points); cameras' cam_from_world
    ``R`` (A, 3, 3) in the model with attitude priors ``R0`` (A, 3, 3), ``sigma_rad`` (A,)."""

    src: np.ndarray
    dst: np.ndarray
    W: np.ndarray
    R: np.ndarray
    R0: np.ndarray
    sigma_rad: np.ndarray

    def residuals(self, sim: Sim3) -> np.ndarray:
        """The whitened residuals (3P + 3A,) of the model moved by ``sim``."""
        rp = np.einsum("pij,pj->pi", self.W, sim.apply(self.src) - self.dst)
        ra = so3_log(self.R @ sim.R.T @ self.R0.transpose(0, 2, 1)) / self.sigma_rad[:, None]
        return np.concatenate([rp.ravel(), ra.ravel()])

    def jacobian(self, sim: Sim3) -> np.ndarray:
        """(3P + 3A, 7) Jacobian in ``(dtheta, dt, dlog_s)`` of ``Q <- exp(dtheta) Q``,
        ``t <- t + dt``, ``s <- s exp(dlog_s)``."""
        y = sim.s * self.src @ sim.R.T  # (P, 3): s Q x, what the rotation and scale act on
        Jp = np.empty((len(y), 3, 7))
        Jp[:, :, :3] = -skew(y)
        Jp[:, :, 3:6] = np.eye(3)
        Jp[:, :, 6] = y
        Jp = self.W @ Jp
        # R Q^T exp(-dtheta) R0^T = Phi exp(-R0 dtheta): a right perturbation of Phi, whose
        # log moves by J_r^-1(phi) = J_l^-1(-phi)
        phi = so3_log(self.R @ sim.R.T @ self.R0.transpose(0, 2, 1))
        Ja = np.zeros((len(phi), 3, 7))
        Ja[:, :, :3] = -so3_left_jacobian_inv(-phi) @ self.R0 / self.sigma_rad[:, None, None]
        return np.concatenate([Jp.reshape(-1, 7), Ja.reshape(-1, 7)])


def _moved(sim: Sim3, d: np.ndarray) -> Sim3:
    return Sim3(sim.s * float(np.exp(d[6])), so3_exp(d[:3]) @ sim.R, sim.t + d[3:6])


def weighted_similarity(dp: DatumPriors) -> Sim3:
    """The similarity minimising the priors' whitened residuals (see the module's text), from
    Umeyama's fit of ``src`` onto ``dst``; Gauss-Newton with step halving on a cost increase."""
    sim = umeyama(dp.src, dp.dst)
    cost = float((dp.residuals(sim) ** 2).sum())
    size = float(np.abs(dp.dst - dp.dst.mean(0)).max(initial=1.0))
    for _ in range(MAX_ITERATIONS):
        J, r = dp.jacobian(sim), dp.residuals(sim)
        d = np.linalg.lstsq(J, -r, rcond=None)[0]
        for _ in range(30):
            trial = _moved(sim, d)
            c = float((dp.residuals(trial) ** 2).sum())
            if c <= cost:
                break
            d = 0.5 * d
        else:
            return sim
        sim, cost = trial, c
        if max(np.abs(d[[0, 1, 2, 6]]).max(), np.abs(d[3:6]).max() / size) < STEP_TOLERANCE:
            break
    return sim
