"""numba kernels of the anchor elimination in X-space (xspace.py); imported only when a solve
uses them. Per point p: ``Bm[p]`` (3, 3) and ``b[p]`` (3,) with ``B_a = e_3 b^T`` (xspace.py);
``vm``, ``va`` (P,) the anchors' variable-camera indices and ``em``, ``ea`` (P,) their entries
of the point (-1 = fixed camera)."""

from __future__ import annotations

import numba
import numpy as np

from polarref.ba.kernels_jit import _tri_solve, add_observer_share, observer_share


def _njit(fn):
    return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)


@_njit
def anchor_maps(d, sw, dh_de, dv_dab, C, main, assoc):
    """``Bm = D^-1 - e_3 b^T`` and ``b = -(sin w / s) dh/de`` per point (xspace.py), with
    ``D^-1 = diag(sin w, sin w, sin^2 w) [dv/d(alpha, beta) | -s d]^-1``; d, dh_de (P, 3),
    sw (P,), dv_dab (P, 3, 2) as forms_jit.parallax_points returns them."""
    P = len(sw)
    Bm, b = np.empty((P, 3, 3)), np.empty((P, 3))
    M = np.empty((3, 3))
    for p in range(P):
        m, a = main[p], assoc[p]
        e0, e1, e2 = C[a, 0] - C[m, 0], C[a, 1] - C[m, 1], C[a, 2] - C[m, 2]
        d0, d1, d2 = d[p, 0], d[p, 1], d[p, 2]
        x0, x1, x2 = d1 * e2 - d2 * e1, d2 * e0 - d0 * e2, d0 * e1 - d1 * e0
        s = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        for i in range(3):  # columns of [dv_dab | -s d]
            M[i, 0], M[i, 1] = dv_dab[p, i, 0], dv_dab[p, i, 1]
        M[0, 2], M[1, 2], M[2, 2] = -s * d0, -s * d1, -s * d2
        # inverse by cofactors: row r of M^-1 = (col j x col k) / det for (r, j, k) cyclic
        det = (M[0, 0] * (M[1, 1] * M[2, 2] - M[2, 1] * M[1, 2])
               - M[0, 1] * (M[1, 0] * M[2, 2] - M[2, 0] * M[1, 2])
               + M[0, 2] * (M[1, 0] * M[2, 1] - M[2, 0] * M[1, 1]))
        swp = sw[p]
        for r in range(3):
            j, k = (r + 1) % 3, (r + 2) % 3
            f = (swp * swp if r == 2 else swp) / det
            Bm[p, r, 0] = f * (M[1, j] * M[2, k] - M[2, j] * M[1, k])
            Bm[p, r, 1] = f * (M[2, j] * M[0, k] - M[0, j] * M[2, k])
            Bm[p, r, 2] = f * (M[0, j] * M[1, k] - M[1, j] * M[0, k])
        g = -swp / s
        for i in range(3):
            b[p, i] = g * dh_de[p, i]
            Bm[p, 2, i] -= b[p, i]
    return Bm, b


@_njit
def build_xspace(J0, Jp, res, vc, ent, obs_bounds, mask_v, Bm, b, V, g_p, W, g, U, gx,
                 diag_f):
    """The observer slot's W, g and U (as kernels_jit.build_observer, U (Nv, 6, 6) by
    variable camera) and, per point once its entries are complete, what the anchors add to
    the forms' gradient and camera diagonal (xspace.py): ``gx += B^T g_p``, ``diag_f +=
    diag(W B + B^T W^T + B^T V B)``. The maps' held camera columns (gauge; mask_v (Nv, 6))
    are zeroed in place first. J0 (M, k, 6), Jp (M, k, 3), res (M, k); vc, ent (3, M) as
    kernels_jit.build_anchored; V (P, 3, 3), g_p (P, 3) the point sums; gx, diag_f (Nv, 6)."""
    acc = np.empty((6, 10))  # J0^T [J0 | res | Jp] of one observation
    for p in range(len(obs_bounds) - 1):
        m0, m1 = obs_bounds[p], obs_bounds[p + 1]
        if m1 == m0:
            continue
        for m in range(m0, m1):
            c = vc[0, m]
            if c < 0:
                continue
            observer_share(J0, Jp, res, m, acc)
            add_observer_share(acc, c, ent[0, m], c, g, W, U)
        cm, ca = vc[1, m0], vc[2, m0]
        if cm >= 0:
            e = ent[1, m0]
            for i in range(3):
                mk = mask_v[cm, 3 + i]
                c0, c1, c2 = Bm[p, 0, i] * mk, Bm[p, 1, i] * mk, Bm[p, 2, i] * mk
                Bm[p, 0, i], Bm[p, 1, i], Bm[p, 2, i] = c0, c1, c2
                gx[cm, 3 + i] += c0 * g_p[p, 0] + c1 * g_p[p, 1] + c2 * g_p[p, 2]
                wb = W[e, 3 + i, 0] * c0 + W[e, 3 + i, 1] * c1 + W[e, 3 + i, 2] * c2
                vb = (c0 * (V[p, 0, 0] * c0 + V[p, 0, 1] * c1 + V[p, 0, 2] * c2)
                      + c1 * (V[p, 1, 0] * c0 + V[p, 1, 1] * c1 + V[p, 1, 2] * c2)
                      + c2 * (V[p, 2, 0] * c0 + V[p, 2, 1] * c1 + V[p, 2, 2] * c2))
                diag_f[cm, 3 + i] += 2.0 * wb + vb
        if ca >= 0:
            e = ent[2, m0]
            for i in range(3):
                bi = b[p, i] * mask_v[ca, 3 + i]
                b[p, i] = bi
                gx[ca, 3 + i] += bi * g_p[p, 2]
                diag_f[ca, 3 + i] += 2.0 * W[e, 3 + i, 2] * bi + bi * bi * V[p, 2, 2]


@_njit
def schur_xspace(W, Li, q, bounds, entry_pt, entry_cam, em, ea, vm, va, Bm, b, lam, S, bvec):
    """kernels_jit.schur_dense (no cross terms) for the damped X-space system: each point's
    anchor entries enter as ``W - B^T Lambda`` (lam (P, 3) the point blocks' damping
    diagonal) and ``B^T Lambda B`` goes onto the anchors' centre blocks of S (upper
    triangle; diagonal blocks whole). W is not modified. em, ea, vm, va (P,) the anchors'
    entries and variable cameras (-1 = fixed)."""
    # The entry loops repeat kernels_jit.schur_dense's on purpose: as shared njit helpers per
    # entry and entry pair (tried: commit 339be37) the Schur pass took ~1.6x as long
    # (Ladybug-49, Euclidean form: 4.3-4.7 -> 7.3-7.5 ms per pass).
    nmax = 0
    for gi in range(len(bounds) - 1):
        nmax = max(nmax, bounds[gi + 1] - bounds[gi])
    Z = np.empty((nmax, 6, 3))
    w = np.empty((6, 3))
    for gi in range(len(bounds) - 1):
        e0, e1 = bounds[gi], bounds[gi + 1]
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
            za = Z[a - e0]
            ca = entry_cam[a]
            for i in range(6):
                for j in range(3):  # (w Li^T)[i, j], Li lower
                    s = 0.0
                    for l in range(j + 1):
                        s += w[i, l] * Li[p, j, l]
                    za[i, j] = s
                bvec[ca, i] += za[i, 0] * q[p, 0] + za[i, 1] * q[p, 1] + za[i, 2] * q[p, 2]
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
        _add_damping(S, Bm, b, l0, l1, l2, p, vm[p], va[p])


@_njit
def _add_damping(S, Bm, b, l0, l1, l2, p, cm, ca):
    """``S += B^T Lambda B`` of point p on its anchors' centre blocks (upper triangle of S;
    diagonal blocks whole)."""
    if cm >= 0:
        r = 6 * cm + 3
        for i in range(3):
            for j in range(3):
                S[r + i, r + j] += (Bm[p, 0, i] * l0 * Bm[p, 0, j] + Bm[p, 1, i] * l1 * Bm[p, 1, j]
                                    + Bm[p, 2, i] * l2 * Bm[p, 2, j])
    if ca >= 0:
        r = 6 * ca + 3
        for i in range(3):
            for j in range(3):
                S[r + i, r + j] += l2 * b[p, i] * b[p, j]
    if cm >= 0 and ca >= 0:
        rm, ra = 6 * cm + 3, 6 * ca + 3
        for i in range(3):  # (Bm^T Lambda B_a)[i, j] = Bm[2, i] l2 b[j]
            for j in range(3):
                x = Bm[p, 2, i] * l2 * b[p, j]
                if cm < ca:
                    S[rm + i, ra + j] += x
                else:
                    S[ra + j, rm + i] += x


@_njit
def damp_W(Wd, Bm, b, lam, vm, va, em, ea):
    """``Wd -= B^T Lambda`` on each point's anchor entries, in place on a copy of W (the
    dense-visibility path, whose Schur products come from one dsyrk on W L^-T)."""
    for p in range(len(vm)):
        if vm[p] >= 0:
            e = em[p]
            for i in range(3):
                for j in range(3):
                    Wd[e, 3 + i, j] -= Bm[p, j, i] * lam[p, j]
        if va[p] >= 0:
            e = ea[p]
            for i in range(3):
                Wd[e, 3 + i, 2] -= b[p, i] * lam[p, 2]


@_njit
def add_damping(S, Bm, b, lam, vm, va):
    """:func:`_add_damping` of every point (the dense-visibility path)."""
    for p in range(len(vm)):
        _add_damping(S, Bm, b, lam[p, 0], lam[p, 1], lam[p, 2], p, vm[p], va[p])


@_njit
def point_steps(rhs, Li, Bm, b, lam, dc, vm, va):
    """Point steps in place on rhs (P, 3) = ``-g_p - sum_e W_e^T dc`` (undamped W): with
    ``t = B dc`` (anchors' centre steps), ``y = V_d^-1 (rhs + Lambda t)`` (the damped W's
    share) and ``dq = y - t``; Li (P, 3, 3) = L^-1 of the damped point blocks."""
    for p in range(len(vm)):
        cm, ca = vm[p], va[p]
        t0 = t1 = t2 = 0.0
        if cm >= 0:
            d3, d4, d5 = dc[cm, 3], dc[cm, 4], dc[cm, 5]
            t0 = Bm[p, 0, 0] * d3 + Bm[p, 0, 1] * d4 + Bm[p, 0, 2] * d5
            t1 = Bm[p, 1, 0] * d3 + Bm[p, 1, 1] * d4 + Bm[p, 1, 2] * d5
            t2 = Bm[p, 2, 0] * d3 + Bm[p, 2, 1] * d4 + Bm[p, 2, 2] * d5
        if ca >= 0:
            t2 += b[p, 0] * dc[ca, 3] + b[p, 1] * dc[ca, 4] + b[p, 2] * dc[ca, 5]
        y0, y1, y2 = _tri_solve(Li, p, rhs[p, 0] + lam[p, 0] * t0, rhs[p, 1] + lam[p, 1] * t1,
                                rhs[p, 2] + lam[p, 2] * t2)
        rhs[p, 0], rhs[p, 1], rhs[p, 2] = y0 - t0, y1 - t1, y2 - t2

def warm_up() -> None:
    """Compile (or load from the disk cache) these kernels on tiny inputs (kernels.warm_up)."""
    f = np.zeros
    one, none = np.zeros(1, np.int64), -np.ones(1, np.int64)
    d = np.array([[1.0, 0.0, 0.0]])
    dv = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]])
    C = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    Bm, b = anchor_maps(d, np.ones(1), f((1, 3)), dv, C, one, one + 1)
    W, lam, V, Li = f((1, 6, 3)), np.ones((1, 3)), f((1, 3, 3)), f((1, 3, 3))
    z3, bounds = np.zeros((3, 1), np.int64), np.array([0, 1], np.int64)
    build_xspace(f((1, 2, 6)), f((1, 2, 3)), f((1, 2)), z3, z3, bounds, np.ones((1, 6)), Bm, b,
                 V, f((1, 3)), W, f((1, 6)), f((1, 6, 6)), f((1, 6)), f((1, 6)))
    schur_xspace(W, Li, f((1, 3)), bounds, one, one, one, none, one, none, Bm, b, lam,
                 f((6, 6)), f((1, 6)))
    damp_W(W, Bm, b, lam, one, none, one, none)
    add_damping(f((6, 6)), Bm, b, lam, one, none)
    point_steps(f((1, 3)), Li, Bm, b, lam, f((1, 6)), one, none)
