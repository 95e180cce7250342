"""Angular residuals: (theta, phi) of each observation, whitened by their propagated covariance.

Residual: ``A^-1 (theta - theta_obs, wrap(phi - phi_obs))`` with ``A = d(theta, phi)/d uv`` at
the observed pixel, i.e. whitened by the covariance ``sigma^2 A A^T`` that isotropic pixel
noise propagates into, expressed in px-equivalent units (sigma cancels against the pixel
residuals' unit weight). Near the optical axis phi carries no information and its
linearization fails: where ``Camera``'s first-order sigma_phi exceeds ``max_sigma_phi`` (for
``sigma_px`` pixel noise) phi is gated off and the residual is ``((theta - theta_obs) /
|d theta / d uv|, 0)``. With ``staged`` the solver first runs theta only (all phi gated),
then theta and phi jointly. Landmarks are parallax-angle landmarks (see parallax.py).
"""

from __future__ import annotations

import numpy as np

from polarref.ba.angular_obs import observed_angles, phi_rows, theta_rows, wrap
from polarref.ba.parallax import Parallax
from polarref.camera.noise import phi_sigma
from polarref.errors import PolarrefError


class Angular(Parallax):
    name = "angular"
    k = 2
    groups = ((0, 2),)

    def __init__(self, problem, options=None):
        super().__init__(problem, options)
        sigma = getattr(options, "sigma_px", 1.0)
        max_sphi = getattr(options, "max_sigma_phi", 0.05)
        ang, A = observed_angles(problem)
        if not np.isfinite(ang[:, 0]).all():
            raise PolarrefError("angular BA: observations outside the camera model's angular range")
        sphi = np.empty(len(ang))
        for i, cam in enumerate(problem.cameras):
            idx = np.flatnonzero(problem.obs_cam == i)
            if len(idx):
                sphi[idx] = phi_sigma(cam, problem.obs_uv[idx], sigma)
        self.phi_ok = np.isfinite(ang[:, 1]) & (sphi <= max_sphi) & np.isfinite(A).all((1, 2))
        self.obs_ang = np.nan_to_num(ang)
        Aok = np.where(self.phi_ok[:, None, None], A, np.eye(2))
        self.whiten = np.linalg.inv(Aok)  # (M, 2, 2): A^-1
        self.w_theta = 1.0 / np.linalg.norm(np.nan_to_num(A[:, 0, :]), axis=1).clip(1e-300)
        self.num_phi_gated = int((~self.phi_ok).sum())
        self.use_phi = self.phi_ok.copy()

    def set_stage(self, theta_only: bool) -> None:
        self.use_phi = np.zeros_like(self.phi_ok) if theta_only else self.phi_ok.copy()

    def residual_rows(self, Xc, jac):
        theta, Jt = theta_rows(Xc, jac)
        phi, Jf = phi_rows(Xc, jac)
        dt = theta - self.obs_ang[:, 0]
        df = wrap(phi - self.obs_ang[:, 1])
        use = self.use_phi
        res = np.empty((len(Xc), 2))
        Wm = self.whiten
        res[:, 0] = np.where(use, Wm[:, 0, 0] * dt + Wm[:, 0, 1] * df, dt * self.w_theta)
        res[:, 1] = np.where(use, Wm[:, 1, 0] * dt + Wm[:, 1, 1] * df, 0.0)
        if not jac:
            return res, None
        J = np.empty((len(Xc), 2, 3))
        u = use[:, None]
        J[:, 0] = np.where(u, Wm[:, 0, :1] * Jt + Wm[:, 0, 1:] * Jf, Jt * self.w_theta[:, None])
        J[:, 1] = np.where(u, Wm[:, 1, :1] * Jt + Wm[:, 1, 1:] * Jf, 0.0)
        return res, J
