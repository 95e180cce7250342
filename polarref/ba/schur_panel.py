"""The reduced camera matrix's point products ``sum_p Z_p Z_p^T`` (``Z = W L^-T``) as GEMMs
over camera windows (issue 35), beside the entry-pair kernel of schur.py.

The entry-pair kernel does one 6x3 by 3x6 product per pair of entries of a point (216 flops
on a 6x6 block held in memory): ~3-7 GFLOP/s, a tenth of GEMM. Here the cameras are cut into
windows of ``width`` consecutive variable cameras; a *tile* (I, J), I <= J, of S is the
(6 width)^2 block of windows I and J, and every point with entries in both windows adds its
3 columns to both tiles' panels (zeros where a camera of the window does not see it). One
tile is then one dense GEMM ``A^T B`` of two (3 n, 6 width) panels, inner dimension 3 n (n
points shared by the two windows). The price is padding: a point contributes
``(6 width)^2 3 x 2`` flops to each of its window pairs whatever its cameras in them, against
216 per entry pair that the sum needs; :func:`choose_width` estimates both paths' time and
returns 0 (keep the kernel) when padding loses, e.g. for short tracks spread over many
cameras (scale-1e5, scale-1e6), and a width for long runs of consecutive cameras (SfM maps).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

# Cost model (one BLAS thread, measured on this machine, scripts/schur_panel.py):
# entry-pair kernel >= 3.2e-8 s per entry pair (best locality: runs of consecutive cameras); padded GEMM rate by tile width; panel fill and
# subtract ~1 ns per panel double; ~15 us of Python and call overhead per tile.
_PAIR_KERNEL_S = 3.2e-8
_GEMM_RATE = {2: 8e9, 4: 18e9, 8: 30e9, 16: 38e9, 32: 42e9}
_PANEL_DOUBLE_S = 1.0e-9
_TILE_S = 1.5e-5
WIDTHS = tuple(_GEMM_RATE)


@dataclass(frozen=True)
class PanelPlan:
    """The tiles of one width: tile t is windows (tile_i[t], tile_j[t]) over the points k in
    ``tile_bounds[t]:tile_bounds[t + 1]``, whose entries in window I are ``[a0[k], a1[k])``
    and in window J ``[b0[k], b1[k])`` (runs of the entries, sorted by point then camera)."""

    width: int
    tile_i: np.ndarray
    tile_j: np.ndarray
    tile_bounds: np.ndarray
    a0: np.ndarray
    a1: np.ndarray
    b0: np.ndarray
    b1: np.ndarray
    padded_flops: float
    longest: int          # most points of one tile


def _window_runs(entry_bounds: np.ndarray, entry_cam: np.ndarray, width: int):
    """Per point group, its distinct windows: (group of each run, window of each run)."""
    E = len(entry_cam)
    win = entry_cam // width
    starts = np.zeros(E, bool)
    starts[entry_bounds[:-1]] = True
    starts[1:] |= win[1:] != win[:-1]
    idx = np.flatnonzero(starts)
    group = np.searchsorted(entry_bounds, idx, side="right") - 1
    return group, win[idx], idx, np.r_[idx[1:], E]


def window_triples(entry_bounds: np.ndarray, entry_cam: np.ndarray, width: int) -> int:
    """Number of (point, window I, window J >= I) triples: the padded GEMM's point columns."""
    group = _window_runs(entry_bounds, entry_cam, width)[0]
    c = np.bincount(group, minlength=len(entry_bounds) - 1)
    return int((c * (c + 1) // 2).sum())


def estimate_s(triples: int, width: int, num_windows: int) -> float:
    """Estimated seconds of the panel path at ``width`` (module cost model)."""
    flops = 216.0 * width**2 * triples
    tiles = min(triples, num_windows * (num_windows + 1) // 2)   # an upper bound
    fill = 2 * 18 * width * triples + 36 * width**2 * tiles
    return flops / _GEMM_RATE[width] + fill * _PANEL_DOUBLE_S + _TILE_S * tiles


def choose_width(entry_bounds: np.ndarray, entry_cam: np.ndarray, num_pairs: int, nv: int) -> int:
    """The cheapest width by the cost model, or 0 when the entry-pair kernel is cheaper."""
    best, best_s = 0, num_pairs * _PAIR_KERNEL_S
    per_point = np.diff(entry_bounds)
    for w in WIDTHS:
        if w > nv:
            break
        # a point of n entries spans >= ceil(n / w) windows and the estimate grows with the
        # triples: a width whose lower bound already loses skips the exact count (a few ms
        # per solve on synth-200-sparse, where no width wins)
        c = -(-per_point // w)
        if estimate_s(int((c * (c + 1) // 2).sum()), w, -(-nv // w)) >= best_s:
            continue
        s = estimate_s(window_triples(entry_bounds, entry_cam, w), w, -(-nv // w))
        if s < best_s:
            best, best_s = w, s
    return best


def plan(entry_bounds: np.ndarray, entry_cam: np.ndarray, width: int) -> PanelPlan:
    """The tiles and their point groups (groups ascending within a tile)."""
    group, win, r0, r1 = _window_runs(entry_bounds, entry_cam, width)
    c = np.bincount(group, minlength=len(entry_bounds) - 1)
    first = np.r_[0, np.cumsum(c)[:-1]]
    # all window pairs a <= b of each group's runs (runs sorted by window within a group)
    reps = np.repeat(c, c)
    a = np.repeat(np.arange(len(win)), reps)
    off = np.arange(len(a)) - np.repeat(np.cumsum(reps) - reps, reps)
    b = np.repeat(np.repeat(first, c), reps) + off
    keep = b >= a
    a, b = a[keep], b[keep]
    nw = int(win.max()) + 1 if len(win) else 1
    key = win[a].astype(np.int64) * nw + win[b]
    order = np.argsort(key, kind="stable")
    starts = np.flatnonzero(np.r_[True, key[order][1:] != key[order][:-1]]) if len(key) else np.zeros(0, np.int64)
    tk = key[order][starts]
    bounds = np.r_[starts, len(key)].astype(np.int64)
    a, b = a[order], b[order]

    def c64(x):
        return np.ascontiguousarray(x, np.int64)

    return PanelPlan(width, tk // nw, tk % nw, bounds, c64(r0[a]), c64(r1[a]), c64(r0[b]),
                     c64(r1[b]), 216.0 * width**2 * len(key), int(np.diff(bounds).max(initial=0)))


def subtract_products(S: np.ndarray, p: PanelPlan, Z: np.ndarray, entry_cam: np.ndarray) -> None:
    """S (6 Nv, 6 Nv), C order: its upper block triangle (tiles I <= J) -= sum_p Z_p Z_p^T.
    Diagonal tiles by ``dsyrk`` (half the flops of a GEMM), the others by ``dgemm``; the
    panels reuse two buffers."""
    from polarref.ba import schur_panel_jit as jit

    w, n6 = p.width, S.shape[0]
    bufA, bufB = np.empty((3 * p.longest, 6 * w)), np.empty((3 * p.longest, 6 * w))
    for t in range(len(p.tile_i)):
        k0, k1 = p.tile_bounds[t], p.tile_bounds[t + 1]
        i, j = int(p.tile_i[t]), int(p.tile_j[t])
        r0, c0 = 6 * w * i, 6 * w * j
        r1, c1 = min(r0 + 6 * w, n6), min(c0 + 6 * w, n6)
        n = 3 * (k1 - k0)
        jit.fill_panel(Z, entry_cam, p.a0[k0:k1], p.a1[k0:k1], i * w, w, bufA)
        A = bufA[:n, :r1 - r0]
        if i == j:  # A^T A's upper triangle (zeros below): the triangle the Cholesky reads
            S[r0:r1, c0:c1] -= scipy.linalg.blas.dsyrk(1.0, A, trans=1)
            continue
        jit.fill_panel(Z, entry_cam, p.b0[k0:k1], p.b1[k0:k1], j * w, w, bufB)
        S[r0:r1, c0:c1] -= A.T @ bufB[:n, :c1 - c0]
