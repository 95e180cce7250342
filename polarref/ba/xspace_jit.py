"""numba kernels of the anchor elimination in X-space (xspace.py); imported only when a solve
uses them. Per point p: ``Bm[p]`` (3, 3) and ``b[p]`` (3,) with ``B_a = e_3 b^T`` (xspace.py);
``vm``, ``va`` (P,) the anchors' variable-camera indices and ``em``, ``ea`` (P,) their entries
of the point (-1 = fixed camera)."""

from __future__ import annotations

import numba
import numpy as np


def _njit(fn):
    return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)


@_njit
def anchor_maps(d, sw, dh_de, dv_dab, C, main, assoc):
    """``Bm = D^-1 - e_3 b^T`` and ``b = -(sin w / s) dh/de`` per point (xspace.py), with
    ``D^-1 = diag(sin w, sin w, sin^2 w) [dv/d(alpha, beta) | -s d]^-1``; d, dh_de (P, 3),
    sw (P,), dv_dab (P, 3, 2) as kernels_jit.parallax_points returns them."""
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
def forms_terms(Bm, b, mask_v, vm, va, em, ea, W, V, g_p, g_f, diag_f):
    """Masks the maps' held camera columns (gauge; in place) and adds what the anchors add to
    the forms' gradient and camera-block diagonal: ``g_f += B^T g_p`` and ``diag_f += diag(W B
    + B^T W^T + B^T V B)`` over each point's anchor columns (xspace.py). mask_v (Nv, 6);
    W (E, 6, 3) the observer-only entries; V (P, 3, 3) undamped; g_p (P, 3); g_f, diag_f
    (Nv, 6) updated in place."""
    for p in range(len(vm)):
        cm, ca = vm[p], va[p]
        if cm >= 0:
            for i in range(3):
                mk = mask_v[cm, 3 + i]
                for j in range(3):
                    Bm[p, j, i] *= mk
            e = em[p]
            for i in range(3):
                c0, c1, c2 = Bm[p, 0, i], Bm[p, 1, i], Bm[p, 2, i]
                g_f[cm, 3 + i] += c0 * g_p[p, 0] + c1 * g_p[p, 1] + c2 * g_p[p, 2]
                wb = W[e, 3 + i, 0] * c0 + W[e, 3 + i, 1] * c1 + W[e, 3 + i, 2] * c2
                vb = 0.0
                for j in range(3):
                    vb += (Bm[p, j, i]
                           * (V[p, j, 0] * c0 + V[p, j, 1] * c1 + V[p, j, 2] * c2))
                diag_f[cm, 3 + i] += 2.0 * wb + vb
        if ca >= 0:
            e = ea[p]
            for i in range(3):
                bi = b[p, i] * mask_v[ca, 3 + i]
                b[p, i] = bi
                g_f[ca, 3 + i] += bi * g_p[p, 2]
                diag_f[ca, 3 + i] += 2.0 * W[e, 3 + i, 2] * bi + bi * bi * V[p, 2, 2]


@_njit
def damp_W(W, save_m, save_a, Bm, b, lam, vm, va, em, ea):
    """The damped system's anchor entries ``W -= B^T Lambda`` (lam (P, 3), the point blocks'
    damping diagonal) in place, the entries' old values saved in save_m (P, 3, 3) and
    save_a (P, 3) for :func:`restore_W` (a copy of W per LM step cost ~1 ms of fresh pages)."""
    for p in range(len(vm)):
        if vm[p] >= 0:
            e = em[p]
            for i in range(3):
                for j in range(3):
                    save_m[p, i, j] = W[e, 3 + i, j]
                    W[e, 3 + i, j] -= Bm[p, j, i] * lam[p, j]
        if va[p] >= 0:
            e = ea[p]
            for i in range(3):
                save_a[p, i] = W[e, 3 + i, 2]
                W[e, 3 + i, 2] -= b[p, i] * lam[p, 2]


@_njit
def restore_W(W, save_m, save_a, vm, va, em, ea):
    """Undo :func:`damp_W` exactly (the saved values written back)."""
    for p in range(len(vm)):
        if vm[p] >= 0:
            e = em[p]
            for i in range(3):
                for j in range(3):
                    W[e, 3 + i, j] = save_m[p, i, j]
        if va[p] >= 0:
            e = ea[p]
            for i in range(3):
                W[e, 3 + i, 2] = save_a[p, i]


@_njit
def add_damping(S, Bm, b, lam, vm, va):
    """``S += B^T Lambda B`` on the anchors' centre blocks (the upper triangle of S (6 Nv,
    6 Nv), as schur_dense fills it; diagonal blocks whole)."""
    for p in range(len(vm)):
        cm, ca = vm[p], va[p]
        l0, l1, l2 = lam[p, 0], lam[p, 1], lam[p, 2]
        if cm >= 0:
            r = 6 * cm + 3
            for i in range(3):
                for j in range(3):
                    S[r + i, r + j] += (Bm[p, 0, i] * l0 * Bm[p, 0, j]
                                        + Bm[p, 1, i] * l1 * Bm[p, 1, j]
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
def point_steps(y, Bm, b, dc, vm, va):
    """``dq = y - Bm dc_main[3:6] - e_3 (b . dc_assoc[3:6])`` in place on y (P, 3)."""
    for p in range(len(vm)):
        cm, ca = vm[p], va[p]
        if cm >= 0:
            for j in range(3):
                y[p, j] -= (Bm[p, j, 0] * dc[cm, 3] + Bm[p, j, 1] * dc[cm, 4]
                            + Bm[p, j, 2] * dc[cm, 5])
        if ca >= 0:
            y[p, 2] -= b[p, 0] * dc[ca, 3] + b[p, 1] * dc[ca, 4] + b[p, 2] * dc[ca, 5]


def warm_up() -> None:
    """Compile (or load from the disk cache) these kernels on tiny inputs (kernels.warm_up)."""
    f = np.zeros
    one, none = np.zeros(1, np.int64), -np.ones(1, np.int64)
    d = np.array([[1.0, 0.0, 0.0]])
    dv = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]])
    C = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    Bm, b = anchor_maps(d, np.ones(1), f((1, 3)), dv, C, one, one + 1)
    W, lam = f((1, 6, 3)), np.ones((1, 3))
    forms_terms(Bm, b, np.ones((1, 6)), one, none, one, none, W, f((1, 3, 3)), f((1, 3)),
                f((1, 6)), f((1, 6)))
    damp_W(W, f((1, 3, 3)), f((1, 3)), Bm, b, lam, one, none, one, none)
    restore_W(W, f((1, 3, 3)), f((1, 3)), one, none, one, none)
    add_damping(f((6, 6)), Bm, b, lam, one, none)
    point_steps(f((1, 3)), Bm, b, f((1, 6)), one, none)
