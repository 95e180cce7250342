"""The paper's method: parallax landmarks, pixel residuals plus the view-angle residual.

Per observation the residual is ``(u - u_obs, v - v_obs, (theta - theta_obs) / s_theta)`` with
``s_theta = |d theta / d uv|`` at the observed pixel: the view-angle residual is weighted by
the theta noise that 1 px of isotropic pixel noise propagates into, so it is in px-equivalent
units like the pixel residuals. The robust loss acts on the pixel block and the theta block
separately (two residual blocks per observation, as two Ceres cost functions would).
"""

from __future__ import annotations

import numpy as np

from polarref.ba.angular_obs import observed_view_angles, theta_rows
from polarref.ba.parallax import Parallax
from polarref.core.errors import PolarrefError


class Polar(Parallax):
    name = "polar"
    k = 3
    groups = ((0, 2), (2, 3))
    row_arrays = ("theta_obs", "w_theta", "cs_theta")

    def __init__(self, problem, options=None):
        super().__init__(problem, options)
        # the solver's factored Jacobians carry the view-angle row as a map of the pixel rows
        # (row_map.py): two rows per observation in the chain rule and the normal equations
        self.map_rows = self.fast and options.view_angle_row == "mapped"
        theta, w_theta, cs = self._observed(problem)
        self.theta_obs, self.w_theta = theta, w_theta
        # (M, 2) cos, sin of theta_obs: the mapped row's offset without arctan2 (row_map_jit.py)
        self.cs_theta = cs if self.map_rows else np.empty((len(theta), 2))

    def _observed(self, problem):
        """theta_obs (M,), its weight ``1 / |theta_D_uv|`` (M,) and (cos, sin) theta_obs
        (M, 2): compiled in one pass for pinhole cameras, else through the camera model."""
        K = self.proj.K if self.proj.compiled else None
        if K is not None and not K[:, 4:].any():
            from polarref.ba import kernels
            rd, w, cs, n_bad = kernels.pinhole_view_angles(K, problem.obs_uv)
            theta = np.arctan(rd)
        else:
            theta, grad = observed_view_angles(problem)
            s_theta = np.linalg.norm(grad, axis=1)
            ok = np.isfinite(theta) & np.isfinite(s_theta) & (s_theta > 0)
            n_bad = int((~ok).sum())
            w = 1.0 / s_theta
            cs = np.stack([np.cos(theta), np.sin(theta)], axis=1) if self.map_rows else None
        if n_bad:
            raise PolarrefError(f"polar BA: {n_bad} observations outside the camera model's "
                                "angular range")
        return theta, w, cs

    def fused_obs(self, R, C, terms):
        """With mapped rows (BAOptions.view_angle_row): the factored evaluation with two
        Jacobian rows and the row map (row_map.py) in one compiled pass, else None."""
        # proj.compiled per call: self-calibration swaps in its own projector and observed
        # angles (intrinsics.py), and then the explicit rows run
        if not (self.map_rows and self.proj.compiled):
            return None
        from polarref.ba import kernels
        p = self.p
        Cm, d, sw, cw, hd, dh_dw, _, dv_dab = terms
        return kernels.polar_obs_mapped(R, C, p.obs_cam, p.obs_pt, Cm, d, sw, cw, hd, dh_dw,
                                        dv_dab, self.proj.K, p.obs_uv, self.theta_obs,
                                        self.cs_theta, self.w_theta)

    def residual_rows(self, Xc, jac):
        if self.map_rows and not jac and self.proj.compiled:  # the fused kernel's residuals
            from polarref.ba import kernels
            return kernels.polar_residuals_mapped(np.ascontiguousarray(Xc), self.proj.K,
                                                  self.p.obs_uv, self.theta_obs, self.cs_theta,
                                                  self.w_theta), None
        if self.fast:  # the view-angle row compiled (kernels.py), written beside the
            # pixel rows in place: no (M, 2) / (M, 2, 3) pixel arrays copied into (M, 3)
            from polarref.ba import kernels
            Xc = np.ascontiguousarray(Xc)
            res, J = self.proj.residuals(Xc, self.p.obs_uv, 3, jac)
            kernels.theta_row_into(Xc, self.theta_obs, self.w_theta, res,
                                   J if jac else np.empty((0, 3, 3)), jac)
            return res, J
        res, J = self.proj.residuals(Xc, self.p.obs_uv, 3, jac)
        theta, Jt = theta_rows(Xc, jac)
        res[:, 2] = (theta - self.theta_obs) * self.w_theta
        if jac:
            J[:, 2] = Jt * self.w_theta[:, None]
        return res, J
