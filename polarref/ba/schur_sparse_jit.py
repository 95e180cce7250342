"""The three-slot forms' Schur passes into the block-sparse reduced system (numba).

Above ``dense_max_cameras`` the reduced camera system is stored as its camera-pair blocks
(kernels_jit.schur_blocks: ``blocks[pair_blk[k]]``, k the entry pair's place in the order the
pass visits them). The anchors of a point observe it, so every camera pair the three-slot forms
couple through one observation (observer x main centre, observer x associate centre, main x
associate) is a pair of entries of that point and already has its block. These kernels are
:func:`kernels_jit.schur_dense`'s cross terms and :func:`xspace_jit.schur_xspace` with that
addressing, so the fused build (compact cross terms) and the X-space elimination run at every
size, not only while S is dense.
"""

from __future__ import annotations

import numba
import numpy as np

from polarref.ba.kernels_jit import _add_block, _add_cross, _longest, _point_factors


def _njit(fn):
    return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)


def _inline(fn):
    # inlined in numba's IR: as a called helper per entry pair the pass took 1.6x as long
    # (6.35 vs 3.98 ms on synth-200-sparse, thread time; xspace_jit.py saw the same)
    return numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")(fn)


@_inline
def _subtract_product(blk, za, zb):
    for i in range(6):
        z0, z1, z2 = za[i, 0], za[i, 1], za[i, 2]
        for j in range(6):
            blk[i, j] -= z0 * zb[j, 0] + z1 * zb[j, 1] + z2 * zb[j, 2]


@_inline
def _pair(k0, i, j, n):
    """The place of entry pair (i, j), i <= j (offsets in a point of n entries), in the pass's
    order: the point's first pair k0, then i * n - i (i - 1) / 2 + (j - i)."""
    return k0 + i * n - i * (i - 1) // 2 + (j - i)


@_njit
def schur_blocks_cross(W, Li, q, bounds, entry_pt, entry_cam, pair_blk, blocks, b, X, h, Xma,
                       ent, obs_bounds):
    """kernels_jit.schur_blocks plus the fused build's cross-camera blocks (the compact
    ``X = [N | t]``, ``h``, ``Xma`` of kernels_jit.build_anchored, as kernels_jit.add_cross
    adds them), each into the block of its entry pair: after the point's products, so the
    pair loop carries no anchor tests."""
    Z = np.empty((_longest(bounds), 6, 3))
    k = 0
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        n = e1 - e0
        p = entry_pt[e0]
        _point_factors(W, Li, q, p, e0, e1, entry_cam, Z, b)
        k0 = k
        for a in range(e0, e1):
            for bb in range(a, e1):
                _subtract_product(blocks[pair_blk[k]], Z[a - e0], Z[bb - e0])
                k += 1
        em, ea = ent[1, obs_bounds[p]], ent[2, obs_bounds[p]]
        for a in range(e0, e1):  # observer entry a x each anchor's centre (entries by camera)
            for main in (True, False):
                ee = em if main else ea
                if ee < 0 or ee == a:
                    continue
                if a < ee:
                    blk = blocks[pair_blk[_pair(k0, a - e0, ee - e0, n)]]
                    _add_cross(blk, X, h, p, a, 0, 3, main, False)
                else:
                    blk = blocks[pair_blk[_pair(k0, ee - e0, a - e0, n)]]
                    _add_cross(blk, X, h, p, a, 3, 0, main, True)
        if em >= 0 and ea >= 0 and em != ea:
            blk = blocks[pair_blk[_pair(k0, min(em, ea) - e0, max(em, ea) - e0, n)]]
            _add_block(blk, Xma, p, 3, 3, 3, em > ea)


@_njit
def schur_blocks_xspace(W, Li, q, bounds, entry_pt, entry_cam, pair_blk, blocks, bvec, em, ea,
                        Bm, b, lam):
    """xspace_jit.schur_xspace into the blocks: each point's anchor entries enter as
    ``W - B^T Lambda`` and ``B^T Lambda B`` goes onto the anchors' centre blocks (their
    diagonal blocks, and the block of the (main, associate) entry pair). em, ea (P,) the
    anchors' entries (-1 = fixed camera)."""
    Z = np.empty((_longest(bounds), 6, 3))
    w = np.empty((1, 6, 3))
    k = 0
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        n = e1 - e0
        p = entry_pt[e0]
        pm, pa = em[p], ea[p]
        l0, l1, l2 = lam[p, 0], lam[p, 1], lam[p, 2]
        for a in range(e0, e1):
            w[0] = W[a]
            if a == pm:
                for i in range(3):
                    w[0, 3 + i, 0] -= Bm[p, 0, i] * l0
                    w[0, 3 + i, 1] -= Bm[p, 1, i] * l1
                    w[0, 3 + i, 2] -= Bm[p, 2, i] * l2
            elif a == pa:
                for i in range(3):
                    w[0, 3 + i, 2] -= b[p, i] * l2
            # this entry's factor and right-hand side share: _point_factors on the damped copy
            _point_factors(w, Li, q, p, 0, 1, entry_cam[a:a + 1], Z[a - e0:a - e0 + 1], bvec)
        k0 = k
        for a in range(e0, e1):
            for bb in range(a, e1):
                _subtract_product(blocks[pair_blk[k]], Z[a - e0], Z[bb - e0])
                k += 1
        if pm >= 0:
            blk = blocks[pair_blk[_pair(k0, pm - e0, pm - e0, n)]]
            for i in range(3):
                for j in range(3):
                    blk[3 + i, 3 + j] += (Bm[p, 0, i] * l0 * Bm[p, 0, j]
                                          + Bm[p, 1, i] * l1 * Bm[p, 1, j]
                                          + Bm[p, 2, i] * l2 * Bm[p, 2, j])
        if pa >= 0:
            blk = blocks[pair_blk[_pair(k0, pa - e0, pa - e0, n)]]
            for i in range(3):
                for j in range(3):
                    blk[3 + i, 3 + j] += l2 * b[p, i] * b[p, j]
        if pm >= 0 and pa >= 0:
            blk = blocks[pair_blk[_pair(k0, min(pm, pa) - e0, max(pm, pa) - e0, n)]]
            _add_anchor_pair(blk, Bm, b, l2, p, pm >= pa)


@_njit
def _add_anchor_pair(blk, Bm, b, l2, p, transposed):
    """``(Bm^T Lambda B_a)[i, j] = Bm[2, i] l2 b[j]`` into the centre columns of the (main,
    associate) block, or its transpose when the associate's camera comes first."""
    for i in range(3):
        for j in range(3):
            x = Bm[p, 2, i] * l2 * b[p, j]
            if transposed:
                blk[3 + j, 3 + i] += x
            else:
                blk[3 + i, 3 + j] += x


@_njit
def zero_held_blocks(blocks, blk_ca, blk_cb, mask_v):
    """The held (gauge) columns of partly fixed cameras zeroed in every block, as
    schur.py's ``_zero_held`` zeroes their rows and columns of the dense S."""
    for k in range(len(blocks)):
        ca, cb = blk_ca[k], blk_cb[k]
        for i in range(6):
            for j in range(6):
                blocks[k, i, j] *= mask_v[ca, i] * mask_v[cb, j]


def warm_up() -> None:
    """Compile (or load from the disk cache) these kernels on tiny inputs (kernels.warm_up)."""
    f = np.zeros
    one, none = np.zeros(1, np.int64), -np.ones(1, np.int64)
    b01, z3 = np.array([0, 1], np.int64), np.zeros((3, 1), np.int64)
    W, Li, q, g, blocks = f((1, 6, 3)), f((1, 3, 3)), f((1, 3)), f((1, 6)), f((1, 6, 6))
    one32 = np.zeros(1, np.int32)  # pair_blk (schur.py _build_blocks)
    schur_blocks_cross(W, Li, q, b01, one, one, one32, blocks, g, f((1, 6, 4)), q, f((1, 3, 3)),
                       z3, b01)
    schur_blocks_xspace(W, Li, q, b01, one, one, one32, blocks, g, one, none, f((1, 3, 3)), q,
                        np.ones((1, 3)))
    zero_held_blocks(blocks, one, one, np.ones((1, 6)))
