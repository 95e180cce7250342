"""The numba-compiled kernels behind :mod:`polarref.ba.kernels` (imported only when a solve
uses them: importing numba takes ~0.5 s, which every CLI command would otherwise pay)."""

from __future__ import annotations

import numba
import numpy as np


def _njit(fn):
    # numpy semantics for x / 0 (inf or nan, as the reference path), not ZeroDivisionError
    return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)


@_njit
def _longest(bounds):
    """The most entries of one point (bounds (G + 1,) the points' entry ranges)."""
    nmax = 0
    for g in range(len(bounds) - 1):
        nmax = max(nmax, bounds[g + 1] - bounds[g])
    return nmax


@_njit
def _point_factors(W, Li, q, p, e0, e1, entry_cam, Z, b):
    """``Z[a - e0] = W_a L_p^-T`` for the entries a of point p (e0 <= a < e1) and their share of
    the right-hand side, ``b[cam(a)] += Z_a q_p``: the per-entry half of the point's elimination
    that the dense and the block-sparse Schur kernels share."""
    for a in range(e0, e1):
        za = Z[a - e0]
        ca = entry_cam[a]
        for i in range(6):
            for j in range(3):  # (W Li^T)[i, j] = sum_l W[i, l] Li[j, l], Li lower
                s = 0.0
                for l in range(j + 1):
                    s += W[a, i, l] * Li[p, j, l]
                za[i, j] = s
            b[ca, i] += za[i, 0] * q[p, 0] + za[i, 1] * q[p, 1] + za[i, 2] * q[p, 2]


@_njit
def schur_dense(W, Li, q, bounds, entry_pt, entry_cam, S, b, cross, X, h, Xma, ent,
                obs_bounds):
    """Point elimination into the dense reduced system, per point p with entries a <= b:
    ``S[6 ca:, 6 cb:] -= Z_a Z_b^T`` (6x6) and ``b[ca] += Z_a q_p``, ``Z = W L^-T``.

    W (E, 6, 3); Li (P, 3, 3) = L^-1 of the damped point blocks; q (P, 3) = L^-1 g_p; bounds
    (G + 1,) entry ranges of the G points with entries (entries sorted by point, then camera,
    so ca < cb for a < b: the upper triangle of the C-ordered S); S (6 Nv, 6 Nv) and
    b (Nv, 6), updated in place.

    With ``cross`` (three-slot forms, see schur.py ``fused``) the camera blocks that couple two
    different cameras of one observation are added to the point's 6x6 blocks of S in the same
    pass as its Schur products (the block is in cache then; a second pass over S cost ~40 %).
    They come compact from :func:`build_anchored`: per observer entry X (E, 6, 4) = [N | t]
    (N = the observer's own ``J0^T J0[:, 3:6]``, t = ``J0^T (A d)``), so observer x main
    centre = ``-N - t h_p^T`` and observer x associate centre = ``t h_p^T`` (h (P, 3) = dh/de),
    and main x associate centre Xma (P, 3, 3); ent (3, M) the slots' entries, obs_bounds
    (P + 1,) each point's observations.
    """
    Z = np.empty((_longest(bounds), 6, 3))
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        p = entry_pt[e0]
        em = ea = -1
        if cross:
            em, ea = ent[1, obs_bounds[p]], ent[2, obs_bounds[p]]
        _point_factors(W, Li, q, p, e0, e1, entry_cam, Z, b)
        for a in range(e0, e1):
            za = Z[a - e0]
            ra = 6 * entry_cam[a]
            for bb in range(a, e1):
                zb = Z[bb - e0]
                rb = 6 * entry_cam[bb]
                for i in range(6):
                    z0, z1, z2 = za[i, 0], za[i, 1], za[i, 2]
                    for j in range(6):
                        S[ra + i, rb + j] -= z0 * zb[j, 0] + z1 * zb[j, 1] + z2 * zb[j, 2]
                if bb == a or (em < 0 and ea < 0):
                    continue
                # observer x anchor centre: rows of the observer, columns 3:6 of the anchor
                if bb == em:
                    _add_cross(S, X, h, p, a, ra, rb + 3, True, False)
                elif a == em:
                    _add_cross(S, X, h, p, bb, ra + 3, rb, True, True)
                if bb == ea:
                    _add_cross(S, X, h, p, a, ra, rb + 3, False, False)
                elif a == ea:
                    _add_cross(S, X, h, p, bb, ra + 3, rb, False, True)
                if a == em and bb == ea:
                    _add_block(S, Xma, p, ra + 3, rb + 3, 3, False)
                elif a == ea and bb == em:
                    _add_block(S, Xma, p, ra + 3, rb + 3, 3, True)


@_njit
def add_cross(S, X, h, Xma, bounds, entry_pt, entry_cam, ent, obs_bounds):
    """The three-slot cross-camera blocks of :func:`build_anchored` into the upper triangle
    of S (6 Nv, 6 Nv), for the dense-visibility path whose Schur products come from one
    ``dsyrk`` (schur.py); arguments as :func:`schur_dense`. Every entry of a point is the
    observer entry of one of its observations (the anchors observe the point too)."""
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        p = entry_pt[e0]
        em, ea = ent[1, obs_bounds[p]], ent[2, obs_bounds[p]]
        for a in range(e0, e1):  # entries sorted by camera: a < em <=> cam(a) < cam(em)
            ra = 6 * entry_cam[a]
            for main in (True, False):
                ee = em if main else ea
                if ee < 0 or ee == a:
                    continue
                rx = 6 * entry_cam[ee]
                if a < ee:
                    _add_cross(S, X, h, p, a, ra, rx + 3, main, False)
                else:
                    _add_cross(S, X, h, p, a, rx + 3, ra, main, True)
        if em >= 0 and ea >= 0 and em != ea:
            rm, rx = 6 * entry_cam[em] + 3, 6 * entry_cam[ea] + 3
            if em < ea:
                _add_block(S, Xma, p, rm, rx, 3, False)
            else:
                _add_block(S, Xma, p, rx, rm, 3, True)


@_njit
def _add_cross(S, X, h, p, e, r0, c0, main, transposed):
    """``S[r0:, c0:] +=`` observer entry e x the main (``-N - t h^T``) or associate
    (``t h^T``) centre of point p, 6 x 3, or its transpose (X = [N | t], see schur_dense)."""
    h0, h1, h2 = h[p, 0], h[p, 1], h[p, 2]
    for i in range(6):
        t = X[e, i, 3]
        if main:
            x0 = -X[e, i, 0] - t * h0
            x1 = -X[e, i, 1] - t * h1
            x2 = -X[e, i, 2] - t * h2
        else:
            x0, x1, x2 = t * h0, t * h1, t * h2
        if transposed:
            S[r0, c0 + i] += x0
            S[r0 + 1, c0 + i] += x1
            S[r0 + 2, c0 + i] += x2
        else:
            S[r0 + i, c0] += x0
            S[r0 + i, c0 + 1] += x1
            S[r0 + i, c0 + 2] += x2


@_njit
def _add_block(S, X, e, r0, c0, n, transposed):
    """``S[r0:, c0:] += X[e]`` (n x 3), or its transpose (3 x n)."""
    if transposed:
        for i in range(n):
            for j in range(3):
                S[r0 + j, c0 + i] += X[e, i, j]
    else:
        for i in range(n):
            for j in range(3):
                S[r0 + i, c0 + j] += X[e, i, j]


@_njit
def slot_gram(Ja, ca, Jb, cb, idx, idx_t, U):
    """``U[idx[m], ca:, cb:] += Ja[m]^T Jb[m]`` and, where ``idx_t[m] >= 0``, the transpose
    into ``U[idx_t[m], cb:, ca:]``. Ja (M, k, na), Jb (M, k, nb); idx/idx_t (M,), -1 = skip."""
    M, k, na = Ja.shape
    nb = Jb.shape[2]
    for m in range(M):
        i, t = idx[m], idx_t[m]
        if i < 0:
            continue
        for p in range(na):
            for q in range(nb):
                s = 0.0
                for r in range(k):
                    s += Ja[m, r, p] * Jb[m, r, q]
                U[i, ca + p, cb + q] += s
                if t >= 0:
                    U[t, cb + q, ca + p] += s


@_njit
def slot_w_g(J, c0, Jp, res, w_idx, g_idx, W, g):
    """``W[w_idx[m], c0:, :] += J[m]^T Jp[m]`` and ``g[g_idx[m], c0:] += J[m]^T res[m]``.
    J (M, k, n), Jp (M, k, 3), res (M, k); indices (M,), -1 = skip (fixed camera)."""
    M, k, n = J.shape
    for m in range(M):
        e, c = w_idx[m], g_idx[m]
        if c < 0:
            continue
        for p in range(n):
            s = 0.0
            for r in range(k):
                s += J[m, r, p] * res[m, r]
            g[c, c0 + p] += s
            if e >= 0:
                for q in range(3):
                    s = 0.0
                    for r in range(k):
                        s += J[m, r, p] * Jp[m, r, q]
                    W[e, c0 + p, q] += s


@_njit
def observer_share(J, Jp, res, m, acc):
    """``acc (6, 10) = J[m]^T [J[m] | res[m] | Jp[m]]``: one observation's share of U, g and W,
    accumulated row by row (fixed-length inner loops, which numba unrolls and vectorizes)."""
    acc[:] = 0.0
    for r in range(J.shape[1]):
        rr = res[m, r]
        for i in range(6):
            x = J[m, r, i]
            for j in range(6):
                acc[i, j] += x * J[m, r, j]
            acc[i, 6] += x * rr
            for j in range(3):
                acc[i, 7 + j] += x * Jp[m, r, j]


@_njit
def add_observer_share(acc, c, e, u, g, W, U):
    """``g[c] +=``, ``W[e] +=``, ``U[u] +=`` the share :func:`observer_share` left in acc
    (e, u = -1: skip that block)."""
    for i in range(6):
        g[c, i] += acc[i, 6]
        if e >= 0:
            for j in range(3):
                W[e, i, j] += acc[i, 7 + j]
        if u >= 0:
            for j in range(6):
                U[u, i, j] += acc[i, j]


@_njit
def build_observer(J, Jp, res, g_idx, w_idx, u_idx, W, g, U):
    """One camera slot of 6 columns (Euclidean): ``g[g_idx[m]] += J^T res``, ``W[w_idx[m]] +=
    J^T Jp``, ``U[u_idx[m]] += J^T J`` in one pass over observations (the same row-by-row
    accumulation as :func:`build_anchored`). J (M, k, 6), Jp (M, k, 3), res (M, k); -1 = skip."""
    acc = np.empty((6, 10))
    for m in range(J.shape[0]):
        if g_idx[m] < 0:
            continue
        observer_share(J, Jp, res, m, acc)
        add_observer_share(acc, g_idx[m], w_idx[m], u_idx[m], g, W, U)


@_njit
def build_anchored(J0, Ad, h, Jp, res, vc, ent, obs_bounds, W, g, U, X, Xma, assign):
    """W, g and the diagonal camera blocks of U for parallax landmarks with the anchors'
    Jacobians factored (anchor_terms.py: ``J_a = (A d) h^T``, ``J_m = -J_obs[:, 3:6] - J_a``),
    and the compact cross-camera terms for :func:`schur_dense`.

    J0 (M, k, 6) observer Jacobians; Ad (M, k); h (P, 3) = dh/de; Jp (M, k, 3); res (M, k);
    vc, ent (3, M) variable camera / entry of the (observer, main, associate) slots, -1 =
    fixed; obs_bounds (P + 1,). U (Nv, 6, 6) indexed by variable camera. Out: X (E, 6, 4) =
    [N | t] per observer entry, ``N = J0^T J0[:, 3:6]`` and ``t = J0^T (A d)`` of its
    observation (observer x main centre = ``-N - t h^T``, observer x associate centre =
    ``t h^T``: schur_dense forms them, 24 numbers per entry instead of two 6x3 blocks), and
    Xma (P, 3, 3) main x associate centre. Blocks whose two cameras coincide (the anchors'
    own observations) go into U instead. With ``assign`` (every entry is the observer of at
    most one observation) X is written, not accumulated (no zeroing). As anchor_terms.py,
    the anchor blocks are sums over the point's observations of the observer's own products
    (its centre columns) and of the k-vector ``A d``: no (M, k, 3) anchor Jacobian is formed.
    """
    k = J0.shape[1]
    acc = np.empty((6, 11))  # J0^T [J0 | A d | res | Jp] of one observation
    Q, Sw = np.empty((3, 3)), np.empty((3, 3))
    T3, Sg, sp = np.empty(3), np.empty(3), np.empty(3)
    for p in range(len(obs_bounds) - 1):
        m0, m1 = obs_bounds[p], obs_bounds[p + 1]
        if m1 == m0:
            continue
        vm, va = vc[1, m0], vc[2, m0]
        Q[:] = 0.0
        Sw[:] = 0.0
        T3[:] = 0.0
        Sg[:] = 0.0
        sp[:] = 0.0
        sr = saa = 0.0
        for m in range(m0, m1):
            c0, e0 = vc[0, m], ent[0, m]
            acc[:] = 0.0
            for r in range(k):  # row by row: fixed-length inner loops (unrolled, vectorized)
                ad, rr = Ad[m, r], res[m, r]
                sr += ad * rr
                saa += ad * ad
                for j in range(3):
                    sp[j] += ad * Jp[m, r, j]
                for i in range(6):
                    x = J0[m, r, i]
                    for j in range(6):
                        acc[i, j] += x * J0[m, r, j]
                    acc[i, 6] += x * ad
                    acc[i, 7] += x * rr
                    for j in range(3):
                        acc[i, 8 + j] += x * Jp[m, r, j]
            for i in range(3):  # the observer's centre rows feed the anchors
                Sg[i] += acc[3 + i, 7]
                T3[i] += acc[3 + i, 6]
                for j in range(3):
                    Sw[i, j] += acc[3 + i, 8 + j]
                    Q[i, j] += acc[3 + i, 3 + j]
            if c0 < 0:
                continue
            for i in range(6):  # observer slot: g, W, U
                g[c0, i] += acc[i, 7]
                if e0 >= 0:
                    for j in range(3):
                        W[e0, i, j] += acc[i, 8 + j]
                for j in range(6):
                    U[c0, i, j] += acc[i, j]
            if e0 >= 0:  # cross terms, compact: [N | t] (schur_dense forms the blocks)
                if assign:
                    for i in range(6):
                        for j in range(4):
                            X[e0, i, j] = acc[i, 3 + j]
                else:
                    for i in range(6):
                        for j in range(4):
                            X[e0, i, j] += acc[i, 3 + j]
            # the observer is its point's anchor: J0^T J_m (J0^T J_a) is a diagonal block;
            # J0^T J_a = t h^T, J0^T J_m = -(J0^T J0)[:, 3:6] - t h^T
            if c0 == vm:
                for i in range(6):
                    t = acc[i, 6]
                    for j in range(3):
                        xm = -acc[i, 3 + j] - t * h[p, j]
                        U[c0, i, 3 + j] += xm
                        U[c0, 3 + j, i] += xm
            if c0 == va:
                for i in range(6):
                    t = acc[i, 6]
                    for j in range(3):
                        xa = t * h[p, j]
                        U[c0, i, 3 + j] += xa
                        U[c0, 3 + j, i] += xa
        # anchors: g, W, U centre blocks from the point's sums (anchor_terms.py)
        for i in range(3):
            ga = h[p, i] * sr
            if va >= 0:
                g[va, 3 + i] += ga
            if vm >= 0:
                g[vm, 3 + i] += -Sg[i] - ga
            for j in range(3):
                wa = h[p, i] * sp[j]
                if va >= 0:
                    W[ent[2, m0], 3 + i, j] += wa
                if vm >= 0:
                    W[ent[1, m0], 3 + i, j] += -Sw[i, j] - wa
                uaa = saa * h[p, i] * h[p, j]
                th, ht = T3[i] * h[p, j], h[p, i] * T3[j]
                Xma[p, i, j] = -th - uaa
                if va >= 0:
                    U[va, 3 + i, 3 + j] += uaa
                if vm >= 0:
                    U[vm, 3 + i, 3 + j] += Q[i, j] + th + ht + uaa
        if vm >= 0 and vm == va:  # never for valid anchors (distinct centres); kept exact
            for i in range(3):
                for j in range(3):
                    U[vm, 3 + i, 3 + j] += Xma[p, i, j] + Xma[p, j, i]


@_njit
def point_sums(Jp, res, obs_pt, V, g):
    """``V[p] += Jp^T Jp`` and ``g[p] += Jp^T res`` over each point's observations."""
    M, k, _ = Jp.shape
    for m in range(M):
        p = obs_pt[m]
        for i in range(3):
            s = 0.0
            for r in range(k):
                s += Jp[m, r, i] * res[m, r]
            g[p, i] += s
            for j in range(i + 1):  # the upper triangle mirrored: products commute exactly
                s = 0.0
                for r in range(k):
                    s += Jp[m, r, i] * Jp[m, r, j]
                V[p, i, j] += s
                if j != i:
                    V[p, j, i] += s


@_njit
def back_substitute_rhs(W, dc, entry_pt, entry_cam, rhs):
    """``rhs[pt(e)] -= W_e^T dc[cam(e)]`` for every entry e."""
    for e in range(len(entry_pt)):
        p, c = entry_pt[e], entry_cam[e]
        for q in range(3):
            s = 0.0
            for i in range(6):
                s += W[e, i, q] * dc[c, i]
            rhs[p, q] -= s


@_njit
def _tri_solve(Li, p, r0, r1, r2):
    """``V_p^-1 r = Li^T (Li r)`` with Li[p] = L^-1 lower (schur.chol_inv3): (x0, x1, x2)."""
    u0 = Li[p, 0, 0] * r0
    u1 = Li[p, 1, 0] * r0 + Li[p, 1, 1] * r1
    u2 = Li[p, 2, 0] * r0 + Li[p, 2, 1] * r1 + Li[p, 2, 2] * r2
    return (Li[p, 0, 0] * u0 + Li[p, 1, 0] * u1 + Li[p, 2, 0] * u2,
            Li[p, 1, 1] * u1 + Li[p, 2, 1] * u2,
            Li[p, 2, 2] * u2)


@_njit
def point_solve(rhs, Li):
    """Point steps in place: rhs (P, 3) <- V^-1 rhs per point (Li (P, 3, 3) lower)."""
    for p in range(len(rhs)):
        rhs[p, 0], rhs[p, 1], rhs[p, 2] = _tri_solve(Li, p, rhs[p, 0], rhs[p, 1], rhs[p, 2])


@_njit
def pair_keys(bounds, entry_cam, nv, out):
    """The camera-pair key ``ca * nv + cb`` of every entry pair a <= b of each point, in the
    order :func:`schur_blocks` visits them (points in entry order, a ascending, b from a);
    bounds (G + 1,) the points' entry ranges; out (pairs,) int64."""
    k = 0
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        for a in range(e0, e1):
            ka = entry_cam[a] * nv
            for bb in range(a, e1):
                out[k] = ka + entry_cam[bb]
                k += 1


@_njit
def mark_pairs(bounds, entry_cam, nv, seen):
    """``seen[ca * nv + cb] = True`` for every entry pair a <= b of each point (the keys of
    :func:`pair_keys`, without an array of them: tens of millions of pairs at 631 views)."""
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        for a in range(e0, e1):
            ka = entry_cam[a] * nv
            for bb in range(a, e1):
                seen[ka + entry_cam[bb]] = True


@_njit
def pair_blocks(bounds, entry_cam, nv, index, out):
    """``out[k] = index[key]`` for the entry pairs in :func:`pair_keys`' order: each pair's
    block from the camera-pair table ``index`` (nv * nv,); out (pairs,) int32."""
    k = 0
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        for a in range(e0, e1):
            ka = entry_cam[a] * nv
            for bb in range(a, e1):
                out[k] = index[ka + entry_cam[bb]]
                k += 1


@_njit
def schur_blocks(W, Li, q, bounds, entry_pt, pair_blk, blocks, b, entry_cam):
    """:func:`schur_dense` (no cross terms) into block storage: per point p with entries
    a <= b, ``blocks[pair_blk[k]] -= Z_a Z_b^T`` (k: the pair's place in :func:`pair_keys`'
    order) and ``b[ca] += Z_a q_p``. blocks (K, 6, 6) are the camera-pair blocks (ca <= cb)
    of a block-sparse S; a pair's 36 products land in one contiguous 288-byte block instead of
    six rows of a dense (6 Nv)^2 matrix."""
    Z = np.empty((_longest(bounds), 6, 3))
    k = 0
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        p = entry_pt[e0]
        _point_factors(W, Li, q, p, e0, e1, entry_cam, Z, b)
        for a in range(e0, e1):
            za = Z[a - e0]
            for bb in range(a, e1):
                zb = Z[bb - e0]
                blk = blocks[pair_blk[k]]
                k += 1
                for i in range(6):
                    z0, z1, z2 = za[i, 0], za[i, 1], za[i, 2]
                    for j in range(6):
                        blk[i, j] -= z0 * zb[j, 0] + z1 * zb[j, 1] + z2 * zb[j, 2]


@_njit
def triad(a, b, c, s):
    """STREAM's triad ``a = b + s c`` (roofline.triad_gbs: the machine's memory bandwidth)."""
    for i in range(len(a)):
        a[i] = b[i] + s * c[i]


@_njit
def count_behind(R, C, X, obs_cam, obs_pt):
    """Observations whose point is at depth <= 0 in its camera (solver.behind_camera_xyz's
    count, its depth to rounding, in one pass without its (M, 3) gathers)."""
    n = 0
    for m in range(len(obs_cam)):
        c, p = obs_cam[m], obs_pt[m]
        z = (R[c, 2, 0] * (X[p, 0] - C[c, 0]) + R[c, 2, 1] * (X[p, 1] - C[c, 1])) \
            + R[c, 2, 2] * (X[p, 2] - C[c, 2])
        n += z <= 0.0
    return n
