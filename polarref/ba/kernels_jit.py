"""The numba-compiled kernels behind :mod:`polarref.ba.kernels` (imported only when a solve
uses them: importing numba takes ~0.5 s, which every CLI command would otherwise pay)."""

from __future__ import annotations

import numba
import numpy as np


def _njit(fn):
    # numpy semantics for x / 0 (inf or nan, as the reference path), not ZeroDivisionError
    return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)


@_njit
def schur_dense(W, Li, q, bounds, entry_pt, entry_cam, S, b, cross, J0, J1, J2, ent, obs_bounds):
    """Point elimination into the dense reduced system, per point p with entries a <= b:
    ``S[6 ca:, 6 cb:] -= Z_a Z_b^T`` (6x6) and ``b[ca] += Z_a q_p``, ``Z = W L^-T``.

    W (E, 6, 3); Li (P, 3, 3) = L^-1 of the damped point blocks; q (P, 3) = L^-1 g_p; bounds
    (G + 1,) entry ranges of the G points with entries (entries sorted by point, then camera,
    so ca < cb for a < b: the upper triangle of the C-ordered S); S (6 Nv, 6 Nv) and
    b (Nv, 6), updated in place.

    With ``cross`` (three-slot forms, see schur.py ``fused``) the camera blocks of U that couple
    two different cameras of one observation (observer x main / associate anchor, main x
    associate; J0 (M, k, 6), J1 and J2 (M, k, 3) at columns 3:6, ent (3, M) their entries,
    obs_bounds (P + 1,) each point's observations) are summed per point into a local buffer
    and added with the point's Schur products, one write per block of S.
    """
    nmax = 0
    for g in range(len(bounds) - 1):
        nmax = max(nmax, bounds[g + 1] - bounds[g])
    Z = np.empty((nmax, 6, 3))
    L = np.zeros((nmax, nmax, 6, 6) if cross else (1, 1, 6, 6))
    k = J0.shape[1]
    for g in range(len(bounds) - 1):
        e0, e1 = bounds[g], bounds[g + 1]
        n = e1 - e0
        p = entry_pt[e0]
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
        if cross:
            L[:n, :n] = 0.0
            for m in range(obs_bounds[p], obs_bounds[p + 1]):
                t0, t1, t2 = ent[0, m], ent[1, m], ent[2, m]
                if t0 >= 0 and t1 >= 0 and t0 != t1:
                    _local_cross(J0, 0, J1, m, t0 - e0, t1 - e0, L, k)
                if t0 >= 0 and t2 >= 0 and t0 != t2:
                    _local_cross(J0, 0, J2, m, t0 - e0, t2 - e0, L, k)
                if t1 >= 0 and t2 >= 0 and t1 != t2:
                    _local_cross(J1, 3, J2, m, t1 - e0, t2 - e0, L, k)
        for a in range(e0, e1):
            za = Z[a - e0]
            ra = 6 * entry_cam[a]
            for bb in range(a, e1):
                zb = Z[bb - e0]
                rb = 6 * entry_cam[bb]
                if cross and bb > a:
                    blk = L[a - e0, bb - e0]
                    for i in range(6):
                        z0, z1, z2 = za[i, 0], za[i, 1], za[i, 2]
                        for j in range(6):
                            S[ra + i, rb + j] += blk[i, j] - (
                                z0 * zb[j, 0] + z1 * zb[j, 1] + z2 * zb[j, 2])
                else:
                    for i in range(6):
                        z0, z1, z2 = za[i, 0], za[i, 1], za[i, 2]
                        for j in range(6):
                            S[ra + i, rb + j] -= z0 * zb[j, 0] + z1 * zb[j, 1] + z2 * zb[j, 2]


@_njit
def _local_cross(Ja, oa, Jb, m, la, lb, L, k):
    """``Ja[m]^T Jb[m]`` (columns oa: of entry la, 3:6 of entry lb) into the point's local
    block buffer, upper triangle (la < lb; else transposed)."""
    na = Ja.shape[2]
    for i in range(na):
        for j in range(3):
            s = 0.0
            for r in range(k):
                s += Ja[m, r, i] * Jb[m, r, j]
            if la < lb:
                L[la, lb, oa + i, 3 + j] += s
            else:
                L[lb, la, 3 + j, oa + i] += s


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
def _wg(J, off, m, c, e, Jp, res, W, g):
    k, n = J.shape[1], J.shape[2]
    for p in range(n):
        s = 0.0
        for r in range(k):
            s += J[m, r, p] * res[m, r]
        g[c, off + p] += s
        for q in range(3):
            s = 0.0
            for r in range(k):
                s += J[m, r, p] * Jp[m, r, q]
            W[e, off + p, q] += s


@_njit
def _ugram(Ja, oa, Jb, ob, m, c, U, both):
    k, na, nb = Ja.shape[1], Ja.shape[2], Jb.shape[2]
    for i in range(na):
        for j in range(nb):
            s = 0.0
            for r in range(k):
                s += Ja[m, r, i] * Jb[m, r, j]
            U[c, oa + i, ob + j] += s
            if both:
                U[c, ob + j, oa + i] += s


@_njit
def build_three_slots(J0, J1, J2, Jp, res, vc, ent, W, g, U):
    """One pass of :func:`slot_w_g` and the same-camera :func:`slot_gram` blocks for the
    three-slot layout (observer (M, k, 6), anchor centres (M, k, 3) at columns 3:6); U holds
    the diagonal camera blocks only, indexed by variable camera (see schur.py ``fused``)."""
    for m in range(J0.shape[0]):
        c0, c1, c2 = vc[0, m], vc[1, m], vc[2, m]
        if c0 >= 0:
            _wg(J0, 0, m, c0, ent[0, m], Jp, res, W, g)
            _ugram(J0, 0, J0, 0, m, c0, U, False)
            if c1 == c0:
                _ugram(J0, 0, J1, 3, m, c0, U, True)
            if c2 == c0:
                _ugram(J0, 0, J2, 3, m, c0, U, True)
        if c1 >= 0:
            _wg(J1, 3, m, c1, ent[1, m], Jp, res, W, g)
            _ugram(J1, 3, J1, 3, m, c1, U, False)
            if c2 == c1:
                _ugram(J1, 3, J2, 3, m, c1, U, True)
        if c2 >= 0:
            _wg(J2, 3, m, c2, ent[2, m], Jp, res, W, g)
            _ugram(J2, 3, J2, 3, m, c2, U, False)


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
def parallax_jacobians(Jx, Xc, R, C, obs_cam, obs_pt, Cm, d, sw, cw, dh_dw, dh_de, dv_dab):
    """Chain rule from ``res_D_Xc`` (M, k, 3) to the parameters of parallax landmarks:
    ``res_D_point`` (M, k, 3) and the dense slot Jacobians ``res_D_obs`` (M, k, 6),
    ``res_D_main_centre`` and ``res_D_assoc_centre`` (M, k, 3) (see parallax.py, anchor_terms.py:
    with ``A = Jx R_i``: point ``[A dv/d(alpha, beta), A dv/dw]``, observer ``[Xc x Jx, -sin(w) A]``,
    associate ``(A d) dh/de^T``, main ``sin(w) A - associate``)."""
    M, k, _ = Jx.shape
    Jp = np.empty((M, k, 3))
    Jo = np.empty((M, k, 6))
    Jm = np.empty((M, k, 3))
    Ja = np.empty((M, k, 3))
    A = np.empty(3)
    dvw = np.empty(3)
    for m in range(M):
        i, p = obs_cam[m], obs_pt[m]
        for j in range(3):
            dvw[j] = dh_dw[p] * d[p, j] + cw[p] * (Cm[p, j] - C[i, j])
        x, y, z = Xc[m, 0], Xc[m, 1], Xc[m, 2]
        for r in range(k):
            a0, a1, a2 = Jx[m, r, 0], Jx[m, r, 1], Jx[m, r, 2]
            for j in range(3):
                A[j] = a0 * R[i, 0, j] + a1 * R[i, 1, j] + a2 * R[i, 2, j]
            Jp[m, r, 0] = A[0] * dv_dab[p, 0, 0] + A[1] * dv_dab[p, 1, 0] + A[2] * dv_dab[p, 2, 0]
            Jp[m, r, 1] = A[0] * dv_dab[p, 0, 1] + A[1] * dv_dab[p, 1, 1] + A[2] * dv_dab[p, 2, 1]
            Jp[m, r, 2] = A[0] * dvw[0] + A[1] * dvw[1] + A[2] * dvw[2]
            Jo[m, r, 0] = y * a2 - z * a1
            Jo[m, r, 1] = z * a0 - x * a2
            Jo[m, r, 2] = x * a1 - y * a0
            ad = A[0] * d[p, 0] + A[1] * d[p, 1] + A[2] * d[p, 2]
            for j in range(3):
                Jo[m, r, 3 + j] = -sw[p] * A[j]
                Ja[m, r, j] = ad * dh_de[p, j]
                Jm[m, r, j] = sw[p] * A[j] - Ja[m, r, j]
    return Jp, Jo, Jm, Ja
