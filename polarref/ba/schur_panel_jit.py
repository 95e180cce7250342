"""numba kernels of the panel Schur path (schur_panel.py); imported only when a solve uses it."""

from __future__ import annotations

import numba
import numpy as np

from polarref.ba.kernels_jit import _point_factors


def _njit(fn):
    return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)


@_njit
def entry_factors(W, Li, q, bounds, entry_pt, entry_cam, Z, b):
    """``Z_e = W_e L_p^-T`` for every entry (E, 6, 3) and ``b[cam] += Z_e q_p``: the per-entry
    half of the point elimination, for all points at once (the GEMMs need all of Z)."""
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        _point_factors(W, Li, q, entry_pt[e0], e0, e1, entry_cam, Z[e0:e1], b)


@_njit
def fill_panel(Z, entry_cam, r0, r1, c0, width, out):
    """out[:3 n] (n = len(r0)) as the (3 n, 6 width) panel of one window: row block k holds
    ``Z_e^T`` of the entries e in [r0[k], r1[k]) (one point's run of cameras in the window
    [c0, c0 + width)) at the columns 6 (cam(e) - c0) .. + 6, zeros elsewhere. Then
    ``A^T B`` of two windows' panels over the same points is their (6 w, 6 w) tile of
    ``sum_p Z_p Z_p^T``."""
    n = len(r0)
    out[:3 * n] = 0.0
    for k in range(n):
        r = 3 * k
        for e in range(r0[k], r1[k]):
            col = 6 * (entry_cam[e] - c0)
            for i in range(6):
                out[r, col + i] = Z[e, i, 0]
                out[r + 1, col + i] = Z[e, i, 1]
                out[r + 2, col + i] = Z[e, i, 2]
