"""The polar form's view-angle row as a combination of its pixel rows (issue 34).

The predicted pixel ``uv(Xc)`` and the predicted view angle ``theta(Xc)`` both depend on the
camera-frame ray only through its direction, so ``P = uv_D_Xc`` (2, 3) and ``t = theta_D_Xc``
(3,) both vanish along ``Xc``; P has rank 2, so ``t = P^T g`` for one ``g`` (2,), the view
angle's gradient in the image at the predicted pixel. Every parameter Jacobian of an
observation is ``res_D_Xc`` times the same chain rule, so the view-angle row of each of them is
``g^T`` times the two pixel rows: the whole (3, n) Jacobian is ``E J2`` with ``E = [I; g^T]``.

With row weights ``w = (w0, w0, w2)`` (the robust loss, one weight per residual block) the
normal equations take ``J3^T W J3 = J2^T M J2`` and ``J3^T W r = J2^T c``, where
``M = w0^2 I + w2^2 g g^T`` and ``c = w0^2 r_uv + w2^2 r_theta g``. With ``L L^T = M``
(2 x 2 Cholesky), two whitened rows ``L^T J2`` and ``L^-1 c`` give exactly the normal equations
of the three rows: the build then reads two rows per observation, as the Euclidean form's does,
and the chain rule writes two rows instead of three. The cost and the LM acceptance still read
the three residuals, so the objective is the paper's; only the arithmetic of the normal
equations changes (rounding; tests/ba/test_row_map.py compares both builds and solves).
"""

from __future__ import annotations

import numpy as np

from polarref.ba import kernels


def whiten(r: np.ndarray, w: np.ndarray | None, G: np.ndarray, Jp: np.ndarray,
           J_obs: np.ndarray, Ad: np.ndarray) -> np.ndarray:
    """Two whitened residual rows (M, 2) from the three unweighted ones r (M, 3); the 2-row
    Jacobians Jp (M, 2, 3), J_obs (M, 2, 6) and Ad (M, 2) are whitened in place. w (M, 3)
    robust row weights or None; G (M, 2) the row map (see module docstring)."""
    out = np.empty((len(r), 2))
    ww = np.zeros((0, 3)) if w is None else np.ascontiguousarray(w)
    kernels.whiten_mapped(np.ascontiguousarray(r), ww, np.ascontiguousarray(G), Jp, J_obs, Ad,
                          out)
    return out


def whiten_reference(r, w, G, J2):
    """The numpy reference of :func:`whiten` for one stacked Jacobian J2 (M, 2, n):
    (whitened residuals (M, 2), whitened Jacobian (M, 2, n)), new arrays (tests)."""
    w = np.ones_like(r) if w is None else w
    a1, a2 = w[:, 0] ** 2, w[:, 2] ** 2
    Mm = a1[:, None, None] * np.eye(2) + a2[:, None, None] * G[:, :, None] * G[:, None, :]
    c = a1[:, None] * r[:, :2] + (a2 * r[:, 2])[:, None] * G
    L = np.linalg.cholesky(Mm)
    return np.linalg.solve(L, c[:, :, None])[:, :, 0], np.swapaxes(L, 1, 2) @ J2
