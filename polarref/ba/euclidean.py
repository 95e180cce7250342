"""Euclidean parameterization: XYZ points, pixel residuals ``uv(R (X - C)) - uv_obs``."""

from __future__ import annotations

import numpy as np

from polarref.ba.kernels import use_kernels
from polarref.ba.problem import BAProblem
from polarref.ba.projection import Projector


def rot_columns(Xc: np.ndarray, Juv: np.ndarray) -> np.ndarray:
    """``Juv @ d Xc / d dtheta`` for R <- exp(dtheta) R: (M, k, 3).

    With dXc = dtheta x Xc = -[Xc]x dtheta, the row ``a^T (-[Xc]x)`` equals ``Xc x a``
    (written out: 2x faster than ``np.cross`` on these shapes).
    """
    out = np.empty(Juv.shape)
    x, y, z = Xc[:, 0, None], Xc[:, 1, None], Xc[:, 2, None]
    a0, a1, a2 = Juv[:, :, 0], Juv[:, :, 1], Juv[:, :, 2]
    out[:, :, 0] = y * a2 - z * a1
    out[:, :, 1] = z * a0 - x * a2
    out[:, :, 2] = x * a1 - y * a0
    return out


class Euclidean:
    """XYZ landmarks; one camera slot per observation (the observing camera)."""

    name = "euclidean"
    k = 2
    groups = ((0, 2),)

    def __init__(self, problem: BAProblem, options=None):
        self.p = problem
        self.fast = options is not None and use_kernels(options.kernels)  # kernels.py
        self.proj = Projector(problem.cameras, problem.obs_cam, compiled=self.fast)
        self.slot_cams = problem.obs_cam[None, :]
        self.slot_cols = ((0, 6),)  # the observing camera: rotation and centre

    def init_points(self) -> np.ndarray:
        return self.p.X.copy()

    def camera_frame(self, R, C, pts):
        p = self.p
        if self.fast:
            from polarref.ba import kernels
            return None, kernels.euclidean_rays(R, C, pts, p.obs_cam, p.obs_pt)
        Ri = R[p.obs_cam]
        Xc = np.einsum("mij,mj->mi", Ri, pts[p.obs_pt] - C[p.obs_cam])
        return Ri, Xc

    def evaluate(self, R, C, pts, jac: bool = True, factored: bool = False):
        """Residuals (M, 2); with jac also ``res_D_point`` (M, 2, 3) and [``res_D_cam`` (M, 2, 6)]."""
        Ri, Xc = self.camera_frame(R, C, pts)
        res, Juv = self.proj.residuals(Xc, self.p.obs_uv, 2, jac)  # compiled or numpy (Projector)
        if not jac:
            return res, None, None
        if self.fast:
            from polarref.ba import kernels
            Jp, Jc = kernels.euclidean_jacobians(Juv, Xc, R, self.p.obs_cam)
            return res, Jp, [Jc]
        Jp = Juv @ Ri
        Jc = np.empty((len(Xc), 2, 6))
        Jc[:, :, :3] = rot_columns(Xc, Juv)
        Jc[:, :, 3:] = -Jp
        return res, Jp, [Jc]

    def pixel_residuals(self, R, C, pts) -> np.ndarray:
        return self.evaluate(R, C, pts, jac=False)[0]

    def pixel_part(self, res: np.ndarray) -> np.ndarray | None:
        """The pixel residuals inside :meth:`evaluate`'s residuals: all of them, bitwise
        :meth:`pixel_residuals` on the compiled path (the same rays and pixel rows with and
        without Jacobians); None on numpy's (its jac path projects by another route)."""
        return res if self.proj.compiled else None

    def retract_points(self, pts, dp):
        return pts + dp

    def store(self, R, C, pts) -> None:
        """Write the solution's points back into the problem (XYZ)."""
        self.p.X = pts.copy()
