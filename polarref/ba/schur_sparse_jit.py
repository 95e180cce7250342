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


@_njit
def _subtract_product(blk, za, zb):
    for i in range(6):
        z0, z1, z2 = za[i, 0], za[i, 1], za[i, 2]
        for j in range(6):
            blk[i, j] -= z0 * zb[j, 0] + z1 * zb[j, 1] + z2 * zb[j, 2]


@_njit
def schur_blocks_cross(W, Li, q, bounds, entry_pt, entry_cam, pair_blk, blocks, b, X, h, Xma,
                       ent, obs_bounds):
    """kernels_jit.schur_blocks plus the fused build's cross-camera blocks (the compact
    ``X = [N | t]``, ``h``, ``Xma`` of kernels_jit.build_anchored, as schur_dense adds them),
    each into the block of its entry pair."""
    Z = np.empty((_longest(bounds), 6, 3))
    k = 0
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        p = entry_pt[e0]
        em, ea = ent[1, obs_bounds[p]], ent[2, obs_bounds[p]]
        _point_factors(W, Li, q, p, e0, e1, entry_cam, Z, b)
        for a in range(e0, e1):
            for bb in range(a, e1):
                blk = blocks[pair_blk[k]]
                k += 1
                _subtract_product(blk, Z[a - e0], Z[bb - e0])
                if bb == a:
                    continue
                # offsets inside the (cam(a), cam(bb)) block, as schur_dense's in S
                if bb == em:
                    _add_cross(blk, X, h, p, a, 0, 3, True, False)
                elif a == em:
                    _add_cross(blk, X, h, p, bb, 3, 0, True, True)
                if bb == ea:
                    _add_cross(blk, X, h, p, a, 0, 3, False, False)
                elif a == ea:
                    _add_cross(blk, X, h, p, bb, 3, 0, False, True)
                if a == em and bb == ea:
                    _add_block(blk, Xma, p, 3, 3, 3, False)
                elif a == ea and bb == em:
                    _add_block(blk, Xma, p, 3, 3, 3, True)


@_njit
def schur_blocks_xspace(W, Li, q, bounds, entry_pt, entry_cam, pair_blk, blocks, bvec, em, ea,
                        Bm, b, lam):
    """xspace_jit.schur_xspace into the blocks: each point's anchor entries enter as
    ``W - B^T Lambda`` and ``B^T Lambda B`` goes onto the anchors' centre blocks (their
    diagonal blocks, and the block of the (main, associate) entry pair). em, ea (P,) the
    anchors' entries (-1 = fixed camera)."""
    Z = np.empty((_longest(bounds), 6, 3))
    w = np.empty((6, 3))
    wl = np.empty((1, 6, 3))
    k = 0
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        p = entry_pt[e0]
        pm, pa = em[p], ea[p]
        l0, l1, l2 = lam[p, 0], lam[p, 1], lam[p, 2]
        for a in range(e0, e1):
            for i in range(6):
                for j in range(3):
                    w[i, j] = W[a, i, j]
            if a == pm:
                for i in range(3):
                    w[3 + i, 0] -= Bm[p, 0, i] * l0
                    w[3 + i, 1] -= Bm[p, 1, i] * l1
                    w[3 + i, 2] -= Bm[p, 2, i] * l2
            elif a == pa:
                for i in range(3):
                    w[3 + i, 2] -= b[p, i] * l2
            wl[0] = w
            # one entry's factor: _point_factors on a one-entry W (entry 0, camera of a)
            _point_factors(wl, Li, q, p, 0, 1, entry_cam[a:a + 1], Z[a - e0:a - e0 + 1], bvec)
        for a in range(e0, e1):
            for bb in range(a, e1):
                blk = blocks[pair_blk[k]]
                k += 1
                _subtract_product(blk, Z[a - e0], Z[bb - e0])
                if a == bb:
                    if a == pm:
                        for i in range(3):
                            for j in range(3):
                                blk[3 + i, 3 + j] += (Bm[p, 0, i] * l0 * Bm[p, 0, j]
                                                      + Bm[p, 1, i] * l1 * Bm[p, 1, j]
                                                      + Bm[p, 2, i] * l2 * Bm[p, 2, j])
                    if a == pa:
                        for i in range(3):
                            for j in range(3):
                                blk[3 + i, 3 + j] += l2 * b[p, i] * b[p, j]
                    if a == pm and a == pa:
                        _add_anchor_pair(blk, Bm, b, l2, p, True)
                elif a == pm and bb == pa:
                    _add_anchor_pair(blk, Bm, b, l2, p, False)
                elif a == pa and bb == pm:
                    _add_anchor_pair(blk, Bm, b, l2, p, True)


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
