"""The numba-compiled kernels behind :mod:`polarref.ba.kernels` (imported only when a solve
uses them: importing numba takes ~0.5 s, which every CLI command would otherwise pay)."""

from __future__ import annotations

import numba
import numpy as np


def _njit(fn):
    # numpy semantics for x / 0 (inf or nan, as the reference path), not ZeroDivisionError
    return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)


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
    nmax = 0
    for g in range(len(bounds) - 1):
        nmax = max(nmax, bounds[g + 1] - bounds[g])
    Z = np.empty((nmax, 6, 3))
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        p = entry_pt[e0]
        em = ea = -1
        if cross:
            em, ea = ent[1, obs_bounds[p]], ent[2, obs_bounds[p]]
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
            for j in range(3):
                s = 0.0
                for r in range(k):
                    s += Jp[m, r, i] * Jp[m, r, j]
                V[p, i, j] += s


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
def euclidean_rays(R, C, X, obs_cam, obs_pt):
    """Camera-frame points ``Xc[m] = R_i (X_p - C_i)`` (M, 3)."""
    M = len(obs_cam)
    Xc = np.empty((M, 3))
    for m in range(M):
        i, p = obs_cam[m], obs_pt[m]
        v0, v1, v2 = X[p, 0] - C[i, 0], X[p, 1] - C[i, 1], X[p, 2] - C[i, 2]
        for r in range(3):
            Xc[m, r] = R[i, r, 0] * v0 + R[i, r, 1] * v1 + R[i, r, 2] * v2
    return Xc


@_njit
def euclidean_jacobians(Jx, Xc, R, obs_cam):
    """``res_D_point = Jx R_i`` (M, k, 3) and ``res_D_cam = [Xc x Jx, -res_D_point]`` (M, k, 6)
    from ``res_D_Xc`` (M, k, 3) (euclidean.py)."""
    M, k, _ = Jx.shape
    Jp = np.empty((M, k, 3))
    Jc = np.empty((M, k, 6))
    for m in range(M):
        i = obs_cam[m]
        x, y, z = Xc[m, 0], Xc[m, 1], Xc[m, 2]
        for r in range(k):
            a0, a1, a2 = Jx[m, r, 0], Jx[m, r, 1], Jx[m, r, 2]
            for j in range(3):
                v = a0 * R[i, 0, j] + a1 * R[i, 1, j] + a2 * R[i, 2, j]
                Jp[m, r, j] = v
                Jc[m, r, 3 + j] = -v
            Jc[m, r, 0] = y * a2 - z * a1
            Jc[m, r, 1] = z * a0 - x * a2
            Jc[m, r, 2] = x * a1 - y * a0
    return Jp, Jc


@_njit
def parallax_points(frame, pts, C, main, assoc, jac):
    """Per-point terms of parallax landmarks (parallax.py ``landmark_terms`` and
    ``point_derivatives``): main centre Cm (P, 3), direction d (P, 3), sin(w), cos(w) (P,),
    h d (P, 3); with ``jac`` also dh/dw (P,), dh/de (P, 3), dv/d(alpha, beta) (P, 3, 2)."""
    P = len(pts)
    Cm, d, hd = np.empty((P, 3)), np.empty((P, 3)), np.empty((P, 3))
    sw, cw, dh_dw = np.empty(P), np.empty(P), np.empty(P)
    dh_de, dv_dab = np.empty((P, 3)), np.empty((P, 3, 2))
    u, e, ua, ub, dd = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for p in range(P):
        ca, sa = np.cos(pts[p, 0]), np.sin(pts[p, 0])
        cb, sb = np.cos(pts[p, 1]), np.sin(pts[p, 1])
        u[0], u[1], u[2] = cb * ca, cb * sa, sb
        m, a = main[p], assoc[p]
        for i in range(3):
            d[p, i] = frame[p, i, 0] * u[0] + frame[p, i, 1] * u[1] + frame[p, i, 2] * u[2]
            Cm[p, i] = C[m, i]
            e[i] = C[a, i] - C[m, i]
        c = d[p, 0] * e[0] + d[p, 1] * e[1] + d[p, 2] * e[2]
        x0 = d[p, 1] * e[2] - d[p, 2] * e[1]
        x1 = d[p, 2] * e[0] - d[p, 0] * e[2]
        x2 = d[p, 0] * e[1] - d[p, 1] * e[0]
        s = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        sw[p], cw[p] = np.sin(pts[p, 2]), np.cos(pts[p, 2])
        h = sw[p] * c + cw[p] * s
        for i in range(3):
            hd[p, i] = h * d[p, i]
        if not jac:
            continue
        dh_dw[p] = cw[p] * c - sw[p] * s
        e2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
        f = cw[p] / s
        for i in range(3):
            dd[i] = sw[p] * e[i] + f * (e2 * d[p, i] - c * e[i])  # dh/dd
            dh_de[p, i] = sw[p] * d[p, i] + f * (e[i] - c * d[p, i])
        ua[0], ua[1], ua[2] = -cb * sa, cb * ca, 0.0  # d u / d alpha, d u / d beta
        ub[0], ub[1], ub[2] = -sb * ca, -sb * sa, cb
        ga = gb = 0.0
        for i in range(3):
            Da = frame[p, i, 0] * ua[0] + frame[p, i, 1] * ua[1] + frame[p, i, 2] * ua[2]
            Db = frame[p, i, 0] * ub[0] + frame[p, i, 1] * ub[1] + frame[p, i, 2] * ub[2]
            ga += dd[i] * Da
            gb += dd[i] * Db
            dv_dab[p, i, 0] = h * Da
            dv_dab[p, i, 1] = h * Db
        for i in range(3):
            dv_dab[p, i, 0] += d[p, i] * ga
            dv_dab[p, i, 1] += d[p, i] * gb
    return Cm, d, sw, cw, hd, dh_dw, dh_de, dv_dab


@_njit
def parallax_xyz(frame, pts, C, main, assoc, far):
    """XYZ (P, 3) of parallax landmarks (parallax.py ``to_xyz``: ``C_m + (h / sin(w)) d``, or
    ``far |e|`` along d where ``|sin(w)| far < 1``) and the number of such points at
    infinity; the solve's write-back, one pass instead of numpy's (P,) temporaries."""
    P = len(pts)
    X = np.empty((P, 3))
    n_far = 0
    for p in range(P):
        ca, sa = np.cos(pts[p, 0]), np.sin(pts[p, 0])
        cb, sb = np.cos(pts[p, 1]), np.sin(pts[p, 1])
        u0, u1, u2 = cb * ca, cb * sa, sb
        m, a = main[p], assoc[p]
        d0 = frame[p, 0, 0] * u0 + frame[p, 0, 1] * u1 + frame[p, 0, 2] * u2
        d1 = frame[p, 1, 0] * u0 + frame[p, 1, 1] * u1 + frame[p, 1, 2] * u2
        d2 = frame[p, 2, 0] * u0 + frame[p, 2, 1] * u1 + frame[p, 2, 2] * u2
        e0, e1, e2 = C[a, 0] - C[m, 0], C[a, 1] - C[m, 1], C[a, 2] - C[m, 2]
        sw = np.sin(pts[p, 2])
        if abs(sw) * far < 1.0:
            dist = far * np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
            n_far += 1
        else:
            c = d0 * e0 + d1 * e1 + d2 * e2
            x0, x1, x2 = d1 * e2 - d2 * e1, d2 * e0 - d0 * e2, d0 * e1 - d1 * e0
            s = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
            dist = (sw * c + np.cos(pts[p, 2]) * s) / sw
        X[p, 0], X[p, 1], X[p, 2] = C[m, 0] + dist * d0, C[m, 1] + dist * d1, C[m, 2] + dist * d2
    return X, n_far


@_njit
def parallax_rays(R, C, obs_cam, obs_pt, Cm, sw, hd):
    """Camera-frame rays ``Xc[m] = R_i (sin(w) (C_m - C_i) + h d)`` (M, 3) of parallax
    landmarks (parallax.py); Cm, hd = h d (P, 3) and sw (P,) per point."""
    M = len(obs_cam)
    Xc = np.empty((M, 3))
    for m in range(M):
        i, p = obs_cam[m], obs_pt[m]
        v0 = sw[p] * (Cm[p, 0] - C[i, 0]) + hd[p, 0]
        v1 = sw[p] * (Cm[p, 1] - C[i, 1]) + hd[p, 1]
        v2 = sw[p] * (Cm[p, 2] - C[i, 2]) + hd[p, 2]
        for r in range(3):
            Xc[m, r] = R[i, r, 0] * v0 + R[i, r, 1] * v1 + R[i, r, 2] * v2
    return Xc


@_njit
def parallax_jacobians(Jx, Xc, R, C, obs_cam, obs_pt, Cm, d, sw, cw, dh_dw, dh_de, dv_dab,
                       dense=True):
    """Chain rule from ``res_D_Xc`` (M, k, 3) to the parameters of parallax landmarks:
    ``res_D_point`` (M, k, 3) and the dense slot Jacobians ``res_D_obs`` (M, k, 6),
    ``res_D_main_centre`` and ``res_D_assoc_centre`` (M, k, 3) (see parallax.py, anchor_terms.py:
    with ``A = Jx R_i``: point ``[A dv/d(alpha, beta), A dv/dw]``, observer ``[Xc x Jx, -sin(w) A]``,
    associate ``(A d) dh/de^T``, main ``sin(w) A - associate``). Also ``A d`` (M, k), the
    anchors' factored form (anchor_terms.py); without ``dense`` the anchors' (M, k, 3)
    Jacobians are not formed (returned with 0 rows)."""
    M, k, _ = Jx.shape
    Jp = np.empty((M, k, 3))
    Jo = np.empty((M, k, 6))
    Md = M if dense else 0
    Jm = np.empty((Md, k, 3))
    Ja = np.empty((Md, k, 3))
    Ad = np.empty((M, k))
    for m in range(M):  # per-point and per-camera terms in scalars (registers), not arrays
        i, p = obs_cam[m], obs_pt[m]
        d0, d1, d2 = d[p, 0], d[p, 1], d[p, 2]
        hw, cwp, swp = dh_dw[p], cw[p], sw[p]
        w0 = hw * d0 + cwp * (Cm[p, 0] - C[i, 0])  # dv/dw
        w1 = hw * d1 + cwp * (Cm[p, 1] - C[i, 1])
        w2 = hw * d2 + cwp * (Cm[p, 2] - C[i, 2])
        b00, b01 = dv_dab[p, 0, 0], dv_dab[p, 0, 1]
        b10, b11 = dv_dab[p, 1, 0], dv_dab[p, 1, 1]
        b20, b21 = dv_dab[p, 2, 0], dv_dab[p, 2, 1]
        r00, r01, r02 = R[i, 0, 0], R[i, 0, 1], R[i, 0, 2]
        r10, r11, r12 = R[i, 1, 0], R[i, 1, 1], R[i, 1, 2]
        r20, r21, r22 = R[i, 2, 0], R[i, 2, 1], R[i, 2, 2]
        x, y, z = Xc[m, 0], Xc[m, 1], Xc[m, 2]
        for r in range(k):
            a0, a1, a2 = Jx[m, r, 0], Jx[m, r, 1], Jx[m, r, 2]
            A0 = a0 * r00 + a1 * r10 + a2 * r20  # A = Jx R_i
            A1 = a0 * r01 + a1 * r11 + a2 * r21
            A2 = a0 * r02 + a1 * r12 + a2 * r22
            Jp[m, r, 0] = A0 * b00 + A1 * b10 + A2 * b20
            Jp[m, r, 1] = A0 * b01 + A1 * b11 + A2 * b21
            Jp[m, r, 2] = A0 * w0 + A1 * w1 + A2 * w2
            Jo[m, r, 0] = y * a2 - z * a1
            Jo[m, r, 1] = z * a0 - x * a2
            Jo[m, r, 2] = x * a1 - y * a0
            Jo[m, r, 3] = -swp * A0
            Jo[m, r, 4] = -swp * A1
            Jo[m, r, 5] = -swp * A2
            ad = A0 * d0 + A1 * d1 + A2 * d2
            Ad[m, r] = ad
    if dense:
        for m in range(M):
            p = obs_pt[m]
            for r in range(k):
                for j in range(3):
                    Ja[m, r, j] = Ad[m, r] * dh_de[p, j]
                    Jm[m, r, j] = -Jo[m, r, 3 + j] - Ja[m, r, j]
    return Jp, Jo, Jm, Ja, Ad


@_njit
def _theta_row(x, y, z, jac, out, m, w):
    """View angle of the projective ray ``sign(Z) (x, y, z)`` (angular_obs.theta_rows) and,
    with jac, ``w * theta_D_Xc`` into out[m] (3,)."""
    sg = -1.0 if z < 0 else 1.0
    x, y, z = x * sg, y * sg, z * sg
    rho2 = x * x + y * y
    rho = np.sqrt(rho2)
    theta = np.arctan2(rho, z)
    if jac:
        n2 = rho2 + z * z
        f = z / (max(rho, 1e-300) * n2)
        out[m, 0] = x * f * sg * w
        out[m, 1] = y * f * sg * w
        out[m, 2] = -rho / n2 * sg * w
    return theta


@_njit
def pixel_rows(Xc, K, obs_uv, k, jac):
    """Pixel residuals ``uv - obs_uv`` into rows 0:2 of res (M, k) and, with jac, ``uv_D_Xc``
    into J (M, k, 3) (J has 0 rows without jac): projection.project with the same operations
    in the same order (bitwise its result), in one pass and without its (M,) temporaries.
    Rows 2: of res and J are left unset for the caller (polar's view-angle row), so a
    k-row residual needs no second copy. K (M, 6) fx, fy, cx, cy, k1, k2; obs_uv (M, 2)."""
    M = len(Xc)
    res = np.empty((M, k))
    J = np.empty((M if jac else 0, k, 3))
    for m in range(M):
        fx, fy, cx, cy, k1, k2 = K[m, 0], K[m, 1], K[m, 2], K[m, 3], K[m, 4], K[m, 5]
        iz = 1.0 / Xc[m, 2]
        x, y = Xc[m, 0] * iz, Xc[m, 1] * iz
        r2 = x * x + y * y
        dist = 1.0 + r2 * (k1 + k2 * r2)
        res[m, 0] = (fx * x * dist + cx) - obs_uv[m, 0]
        res[m, 1] = (fy * y * dist + cy) - obs_uv[m, 1]
        if not jac:
            continue
        a = 2.0 * (k1 + 2.0 * k2 * r2)
        dxx, dxy, dyy = dist + a * x * x, a * x * y, dist + a * y * y
        j00, j01 = fx * dxx * iz, fx * dxy * iz
        j10, j11 = fy * dxy * iz, fy * dyy * iz
        J[m, 0, 0], J[m, 0, 1], J[m, 0, 2] = j00, j01, -(j00 * x + j01 * y)
        J[m, 1, 0], J[m, 1, 1], J[m, 1, 2] = j10, j11, -(j10 * x + j11 * y)
    return res, J


@_njit
def theta_row_into(Xc, theta_obs, w_theta, res, J, jac):
    """Polar's weighted view-angle row ``(theta - theta_obs) w_theta`` into row 2 of res
    (M, 3) and, with jac, its ``res_D_Xc`` into row 2 of J (M, 3, 3), in place (rows 0:2
    from :func:`pixel_rows`): the same values as polar.py's numpy view-angle row."""
    Jt = J[:, 2, :]  # a view: _theta_row writes row 2 of J
    for m in range(len(Xc)):
        th = _theta_row(Xc[m, 0], Xc[m, 1], Xc[m, 2], jac, Jt, m, w_theta[m])
        res[m, 2] = (th - theta_obs[m]) * w_theta[m]


@_njit
def angular_rows(Xc, obs_ang, whiten, w_theta, use, jac):
    """Angular residuals (M, 2) and with jac ``res_D_Xc`` (M, 2, 3) (angular.py without the
    axis chart): ``A^-1 (theta - theta_obs, wrap(phi - phi_obs))`` where ``use``, else
    ``((theta - theta_obs) w_theta, 0)``; angles of the projective ray (angular_obs.py)."""
    M = len(Xc)
    res = np.empty((M, 2))
    J = np.empty((M if jac else 0, 2, 3))
    Jt = np.empty((1, 3))  # theta_D_Xc of the current observation
    for m in range(M):
        x, y, z = Xc[m, 0], Xc[m, 1], Xc[m, 2]
        th = _theta_row(x, y, z, jac, Jt, 0, 1.0)
        dt = th - obs_ang[m, 0]
        if not use[m]:
            res[m, 0] = dt * w_theta[m]
            res[m, 1] = 0.0
            if jac:
                for i in range(3):
                    J[m, 0, i] = Jt[0, i] * w_theta[m]
                    J[m, 1, i] = 0.0
            continue
        sg = -1.0 if z < 0 else 1.0
        xs, ys = x * sg, y * sg
        phi = np.arctan2(ys, xs)
        a = phi - obs_ang[m, 1]
        # wrap to (-pi, pi] (angular_obs.wrap); the modulo only where a is outside
        df = a if -np.pi < a <= np.pi else np.pi - np.mod(np.pi - a, 2.0 * np.pi)
        w00, w01, w10, w11 = whiten[m, 0, 0], whiten[m, 0, 1], whiten[m, 1, 0], whiten[m, 1, 1]
        res[m, 0] = w00 * dt + w01 * df
        res[m, 1] = w10 * dt + w11 * df
        if jac:
            rho2 = max(xs * xs + ys * ys, 1e-300)
            f0, f1 = -ys / rho2 * sg, xs / rho2 * sg  # phi_D_Xc (third component 0)
            t0, t1, t2 = Jt[0, 0], Jt[0, 1], Jt[0, 2]
            J[m, 0, 0] = w00 * t0 + w01 * f0
            J[m, 0, 1] = w00 * t1 + w01 * f1
            J[m, 0, 2] = w00 * t2
            J[m, 1, 0] = w10 * t0 + w11 * f0
            J[m, 1, 1] = w10 * t1 + w11 * f1
            J[m, 1, 2] = w10 * t2
    return res, J
