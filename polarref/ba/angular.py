"""Angular residuals: (theta, phi) of each observation, whitened by their propagated covariance.

Residual: ``A^-1 (theta - theta_obs, wrap(phi - phi_obs))`` with ``A = d(theta, phi)/d uv`` at
the observed pixel, i.e. whitened by the covariance ``sigma^2 A A^T`` that isotropic pixel
noise propagates into, expressed in px-equivalent units (sigma cancels against the pixel
residuals' unit weight). Near the optical axis phi carries no information and its
linearization fails: where ``Camera``'s first-order sigma_phi exceeds ``max_sigma_phi`` (for
``sigma_px`` pixel noise) phi is gated off. A gated observation then uses, by default
(``axis_residual="chart"``), the azimuthal-equidistant chart ``theta (cos phi, sin phi)``,
whitened the same way: the same angular information, but smooth through the axis. The
alternative ``axis_residual="theta"`` keeps only ``(theta - theta_obs) / |d theta / d uv|``,
a cone at the axis; on the ParallaxBA fake pile its 85 gated observations (of 26,050) stall
LM at 160x the optimal cost, the chart converges to it. With ``staged`` the solver first runs
theta only (every observation), then the residuals above jointly. Landmarks are
parallax-angle landmarks (see parallax.py).
"""

from __future__ import annotations

import numpy as np

from polarref.ba.angular_obs import (axis_chart_rows, observed_angles, observed_axis_chart,
                                     phi_rows, theta_rows, wrap)
from polarref.ba.options import BAOptions
from polarref.ba.parallax import Parallax
from polarref.ba.projection import camera_groups
from polarref.camera.noise import phi_sigma
from polarref.core.errors import PolarrefError


class Angular(Parallax):
    name = "angular"
    k = 2
    groups = ((0, 2),)
    # the compiled rows' per-observation inputs (refresh_kernel_rows): the chunked build
    # (chunked.py) slices them; the numpy path's chart rows are indexed over all observations,
    # but rows are only evaluated with the kernels (Parallax.supports_rows)
    row_arrays = ("k_obs", "k_cs", "k_whiten", "w_theta", "mode")

    def __init__(self, problem, options=None):
        super().__init__(problem, options)
        options = BAOptions(param=self.name) if options is None else options
        sigma, max_sphi = options.sigma_px, options.max_sigma_phi
        ang, A = observed_angles(problem)
        if not np.isfinite(ang[:, 0]).all():
            raise PolarrefError("angular BA: observations outside the camera model's angular range")
        sphi = np.empty(len(ang))
        for cam, idx in camera_groups(problem.cameras, problem.obs_cam):
            sphi[idx] = phi_sigma(cam, problem.obs_uv[idx], sigma)
        self.phi_ok = np.isfinite(ang[:, 1]) & (sphi <= max_sphi) & np.isfinite(A).all((1, 2))
        self.obs_ang = np.nan_to_num(ang)
        Aok = np.where(self.phi_ok[:, None, None], A, np.eye(2))
        self.whiten = np.linalg.inv(Aok)  # (M, 2, 2): A^-1
        self.w_theta = 1.0 / np.linalg.norm(np.nan_to_num(A[:, 0, :]), axis=1).clip(1e-300)
        self.num_phi_gated = int((~self.phi_ok).sum())
        self.chart_idx = np.zeros(0, np.int64)
        if options.axis_residual == "chart" and self.num_phi_gated:
            idx = np.flatnonzero(~self.phi_ok)
            e_obs, B = observed_axis_chart(problem, idx)
            good = np.isfinite(e_obs).all(1) & np.isfinite(B).all((1, 2))
            good[good] &= np.abs(np.linalg.det(B[good])) > 0
            self.chart_idx = idx[good]
            self.chart_obs = e_obs[good]
            self.chart_whiten = np.linalg.inv(B[good])  # (n, 2, 2)
        self.set_stage(theta_only=False)

    def pixel_part(self, res):
        """None: the angular residuals hold no pixel rows (solver.py evaluates them)."""
        return None

    def set_stage(self, theta_only: bool) -> None:
        self.use_phi = np.zeros_like(self.phi_ok) if theta_only else self.phi_ok.copy()
        self.use_chart = not theta_only and len(self.chart_idx) > 0
        self.refresh_kernel_rows()

    def refresh_kernel_rows(self) -> None:
        """The compiled rows' inputs per observation (forms_jit._angle_rows, _chart_row) from the stage and
        the observed angles: ``mode``, and the chart's observation and whitening in place of
        (theta, phi)'s where the chart is used (``k_obs``, ``k_whiten``), and cos, sin of the
        observed (theta, phi) (``k_cs`` (M, 4): the kernels' offsets without arctan2). Call
        again after changing ``obs_ang`` or ``chart_obs`` (intrinsics.py does)."""
        if not self.fast:
            return
        from polarref.ba import kernels
        self.mode = np.where(self.use_phi, kernels.THETA_PHI, kernels.THETA_ONLY).astype(np.int8)
        self.k_obs, self.k_whiten = self.obs_ang, self.whiten
        if self.use_chart:
            ci = self.chart_idx
            self.mode[ci] = kernels.CHART
            self.k_obs, self.k_whiten = self.obs_ang.copy(), self.whiten.copy()
            self.k_obs[ci], self.k_whiten[ci] = self.chart_obs, self.chart_whiten
        ang = self.obs_ang  # the chart's rows do not read theirs
        self.k_cs = np.stack([np.cos(ang[:, 0]), np.sin(ang[:, 0]), np.cos(ang[:, 1]),
                              np.sin(ang[:, 1])], axis=1)

    def residual_rows(self, Xc, jac):
        if self.fast:
            return self._residual_rows_kernels(Xc, jac)
        theta, Jt = theta_rows(Xc, jac)
        phi, Jf = phi_rows(Xc, jac)
        dt = theta - self.obs_ang[:, 0]
        df = wrap(phi - self.obs_ang[:, 1])
        use = self.use_phi
        res = np.empty((len(Xc), 2))
        Wm = self.whiten
        res[:, 0] = np.where(use, Wm[:, 0, 0] * dt + Wm[:, 0, 1] * df, dt * self.w_theta)
        res[:, 1] = np.where(use, Wm[:, 1, 0] * dt + Wm[:, 1, 1] * df, 0.0)
        if self.use_chart:
            ci = self.chart_idx
            e, Je = axis_chart_rows(Xc[ci], jac)
            res[ci] = np.matmul(self.chart_whiten, (e - self.chart_obs)[:, :, None])[:, :, 0]
        if not jac:
            return res, None
        J = np.empty((len(Xc), 2, 3))
        u = use[:, None]
        J[:, 0] = np.where(u, Wm[:, 0, :1] * Jt + Wm[:, 0, 1:] * Jf, Jt * self.w_theta[:, None])
        J[:, 1] = np.where(u, Wm[:, 1, :1] * Jt + Wm[:, 1, 1:] * Jf, 0.0)
        if self.use_chart:
            J[ci] = np.matmul(self.chart_whiten, Je)
        return res, J

    def _residual_rows_kernels(self, Xc, jac):
        """:meth:`residual_rows` compiled (forms_jit.angular_rows), axis-chart rows included."""
        from polarref.ba import kernels
        res, J = kernels.angular_rows(np.ascontiguousarray(Xc), self.k_obs, self.k_cs,
                                      self.k_whiten, self.w_theta, self.mode, jac)
        return res, (J if jac else None)

    def fused_obs(self, R, C, terms):
        from polarref.ba import kernels
        p = self.p
        Cm, d, sw, cw, hd, dh_dw, _, dv_dab = terms
        return (*kernels.angular_obs(R, C, p.obs_cam, p.obs_pt, Cm, d, sw, cw, hd, dh_dw, dv_dab,
                                     self.k_obs, self.k_cs, self.k_whiten, self.w_theta,
                                     self.mode), None)
