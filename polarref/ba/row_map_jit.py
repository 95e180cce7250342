"""numba kernels of the polar form's mapped view-angle row (row_map.py); reached through
:mod:`polarref.ba.kernels` like forms_jit.py's."""

from __future__ import annotations

import numba
import numpy as np

from polarref.ba.forms_jit import _pixel, _put2, _theta


def _njit(fn):
    return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)


@_njit
def polar_rows_mapped(Xc, K, obs_uv, theta_obs, w_theta):
    """Polar's residuals (M, 3) (pixel rows, then the weighted view-angle row, bitwise
    forms_jit.pixel_rows + theta_row_into), the pixel rows' ``res_D_Xc`` (M, 2, 3) and the row
    map G (M, 2): the view-angle row's ``res_D_Xc`` is ``G[m] @ J[m]``. Xc (M, 3), K (M, 6)."""
    M = len(Xc)
    res = np.empty((M, 3))
    J = np.empty((M, 2, 3))
    G = np.empty((M, 2))
    for m in range(M):
        x, y, z = Xc[m, 0], Xc[m, 1], Xc[m, 2]
        _put2(res, m, J, m, True, _pixel(K, m, x, y, z, obs_uv, True))
        th, t0, t1, t2 = _theta(x, y, z, True)
        w = w_theta[m]
        res[m, 2] = (th - theta_obs[m]) * w
        # g^T P = w t solved in the row space of P (2, 3): exact, as both P and t vanish
        # along Xc (row_map.py)
        p00, p01, p02 = J[m, 0, 0], J[m, 0, 1], J[m, 0, 2]
        p10, p11, p12 = J[m, 1, 0], J[m, 1, 1], J[m, 1, 2]
        a = p00 * p00 + p01 * p01 + p02 * p02
        b = p00 * p10 + p01 * p11 + p02 * p12
        c = p10 * p10 + p11 * p11 + p12 * p12
        h0 = (p00 * t0 + p01 * t1 + p02 * t2) * w
        h1 = (p10 * t0 + p11 * t1 + p12 * t2) * w
        det = a * c - b * b
        G[m, 0] = (c * h0 - b * h1) / det
        G[m, 1] = (a * h1 - b * h0) / det
    return res, J, G


@_njit
def whiten_mapped(r, w, G, Jp, Jo, Ad, out):
    """The two whitened rows ``L^-1 c`` into out (M, 2) and ``L^T J`` in place on Jp (M, 2, 3),
    Jo (M, 2, 6), Ad (M, 2), with ``L L^T = w0^2 I + w2^2 g g^T`` and ``c = w0^2 r_uv + w2^2
    r_theta g`` (row_map.py). r (M, 3) unweighted; w (M, 3) robust row weights, or 0 rows
    for none; G (M, 2)."""
    weighted = len(w) > 0
    for m in range(len(r)):
        a1, a2 = 1.0, 1.0
        if weighted:
            a1, a2 = w[m, 0] * w[m, 0], w[m, 2] * w[m, 2]
        g0, g1 = G[m, 0], G[m, 1]
        m00 = a1 + a2 * g0 * g0
        m01 = a2 * g0 * g1
        m11 = a1 + a2 * g1 * g1
        c0 = a1 * r[m, 0] + a2 * g0 * r[m, 2]
        c1 = a1 * r[m, 1] + a2 * g1 * r[m, 2]
        l00 = np.sqrt(m00)
        l10 = m01 / l00 if l00 > 0.0 else 0.0
        l11 = np.sqrt(max(m11 - l10 * l10, 0.0))
        y0 = c0 / l00 if l00 > 0.0 else 0.0
        out[m, 0] = y0
        out[m, 1] = (c1 - l10 * y0) / l11 if l11 > 0.0 else 0.0
        for j in range(3):
            u, v = Jp[m, 0, j], Jp[m, 1, j]
            Jp[m, 0, j], Jp[m, 1, j] = l00 * u + l10 * v, l11 * v
        for j in range(6):
            u, v = Jo[m, 0, j], Jo[m, 1, j]
            Jo[m, 0, j], Jo[m, 1, j] = l00 * u + l10 * v, l11 * v
        u, v = Ad[m, 0], Ad[m, 1]
        Ad[m, 0], Ad[m, 1] = l00 * u + l10 * v, l11 * v


def warm_up() -> None:
    """Compile (or load from the disk cache) these kernels on tiny inputs (kernels.warm_up)."""
    f = np.zeros
    x3 = np.array([[0.1, 0.2, 1.0]])
    K = np.array([[1.0, 1.0, 0.0, 0.0, 0.0, 0.0]])
    res, J, G = polar_rows_mapped(x3, K, f((1, 2)), f(1), np.ones(1))
    for w in (f((0, 3)), np.ones((1, 3))):
        whiten_mapped(res, w, G, J.copy(), f((1, 2, 6)), f((1, 2)), f((1, 2)))
