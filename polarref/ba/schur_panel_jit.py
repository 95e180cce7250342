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
    ``sum_p Z_p Z_p^T``. Each cell is written once, row by row (zeroing the buffer first and
    writing the entries across three rows cost ~2x)."""
    for k in range(len(r0)):
        for l in range(3):
            row = out[3 * k + l]
            e = r0[k]
            for c in range(width):
                col = 6 * c
                if e < r1[k] and entry_cam[e] - c0 == c:
                    for i in range(6):
                        row[col + i] = Z[e, i, l]
                    e += 1
                else:
                    for i in range(6):
                        row[col + i] = 0.0


@_njit
def scatter_entries(Z, entry_pt, entry_cam, Zd):
    """Zd[cam(e), :, pt(e), :] = Z_e for every entry (Z (E, 6, 3), Zd (Nv, 6, P, 3)): the layout
    of the dense-visibility path's one dsyrk (schur.py). Cells of no entry are left as they are
    (zero: the sparsity does not change between builds)."""
    for e in range(len(Z)):
        c, p = entry_cam[e], entry_pt[e]
        for i in range(6):
            for j in range(3):
                Zd[c, i, p, j] = Z[e, i, j]


def warm_up() -> None:
    """Compile (or load from the disk cache) these kernels on tiny inputs (kernels.warm_up)."""
    f, one = np.zeros, np.zeros(1, np.int64)
    Z = f((1, 6, 3))
    entry_factors(f((1, 6, 3)), f((1, 3, 3)), f((1, 3)), np.array([0, 1], np.int64), one, one, Z, f((1, 6)))
    fill_panel(Z, one, one, one + 1, 0, 1, f((3, 6)))
    scatter_entries(Z, one, one, f((1, 6, 1, 3)))
