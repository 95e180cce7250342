"""Normal-equation blocks of parallax landmarks with the anchors' Jacobians kept factored.

For a parallax landmark (see parallax.py) observed by camera i with main anchor m and
associate anchor a, the residual's Jacobians with respect to the anchor centres are

    J_a = (A d) h^T                      (k, 3), rank one
    J_m = -J_obs[:, 3:6] - J_a           (the observing camera's centre columns are -sin(w) A)

with ``A = res_D_v`` (k, 3), ``d`` the landmark direction and ``h = dh/de`` (per point, 3).
So only ``Ad`` (M, k) and ``h`` (P, 3) are needed: every anchor block of U, W and g follows
from per-observation quantities the observing slot needs anyway plus a few (M, k)-sized
contractions, summed per point first (the anchors are the same for all of a point's
observations). This replaces 6 batched 3-column products and their reductions per build
(the generic slot path of schur.py) and brings the three-slot forms' cost per iteration
close to the Euclidean one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.ba.schur import Reducer, SchurStructure, gram


@dataclass
class AnchorJacobian:
    """Factored anchor Jacobians of all observations (see module docstring)."""

    Ad: np.ndarray  # (M, k) A d per observation
    h: np.ndarray  # (P, 3) dh/de per point
    # (Bm (P, 3, 3), b (P, 3)): the same Jacobians as maps of Jp (xspace.py), kernel path
    maps: tuple | None = None
    # (M, 2): the residual's last row is row_map . (the two rows every Jacobian holds), so
    # the build reads two whitened rows (row_map.py; polar, kernel path); None: all k rows
    row_map: np.ndarray | None = None

    def scaled(self, w: np.ndarray) -> "AnchorJacobian":
        """Rows scaled by (M, k) weights (robust loss; the maps are weight-free)."""
        return AnchorJacobian(self.Ad * w, self.h, self.maps)

    def dense(self, J_obs: np.ndarray, obs_pt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(J_m, J_a), each (M, k, 3): the explicit Jacobians (tests, generic path)."""
        J_a = self.Ad[:, :, None] * self.h[obs_pt][:, None, :]
        return -J_obs[:, :, 3:] - J_a, J_a


class AnchorTerms:
    """Builds (g_c, W, U) for [J_obs, AnchorJacobian] on a 3-slot SchurStructure."""

    def __init__(self, st: SchurStructure, obs_pt: np.ndarray, main: np.ndarray,
                 assoc: np.ndarray):
        if st.S != 3 or st.slot_cols != [(0, 6), (3, 6), (3, 6)]:
            raise ValueError("AnchorTerms needs the (observer, main, associate) slot layout")
        self.st, self.obs_pt = st, obs_pt
        P, nv = st.P, max(st.Nv, 1)
        vm, va = st.var_index[main], st.var_index[assoc]  # (P,), -1 = fixed
        allk = st.u_ca * nv + st.u_cb

        def block(ca, cb):
            ok = (ca >= 0) & (cb >= 0)
            return np.where(ok, np.searchsorted(allk, np.maximum(ca, 0) * nv + np.maximum(cb, 0)), -1)

        def entry(vc):
            key = np.arange(P) * nv + np.maximum(vc, 0)
            ekeys = st.entry_pt * nv + st.entry_cam
            return np.where(vc >= 0, np.searchsorted(ekeys, key), -1)

        self.u_mm, self.u_aa = Reducer(block(vm, vm), st.B), Reducer(block(va, va), st.B)
        self.u_ma, self.u_am = Reducer(block(vm, va), st.B), Reducer(block(va, vm), st.B)
        self.g_m, self.g_a = Reducer(vm, st.Nv), Reducer(va, st.Nv)
        em, ea = entry(vm), entry(va)
        self.main_ok, self.assoc_ok = np.flatnonzero(em >= 0), np.flatnonzero(ea >= 0)
        self.e_main, self.e_assoc = em[self.main_ok], ea[self.assoc_ok]
        # observer x anchor pairs: the structure's M-level reducers for slot pairs (0,1), (0,2)
        self.cross = {(a, b): (red, idx) for (a, b, red, _), idx in zip(st.u_cross, st.u_cross_idx)}

    def build(self, Jc: list, Jp: np.ndarray, r: np.ndarray):
        """(g_c (Nv, 6), W (E, 6, 3), U (B, 6, 6)) for Jc = [J_obs (M, k, 6), AnchorJacobian]."""
        st, op = self.st, self.obs_pt
        J0, anc = Jc[0], Jc[1]
        Ad, h = anc.Ad, anc.h
        pr = st.pt_reduce
        A_C = J0[:, :, 3:]  # (M, k, 3) = -sin(w) A
        # observing slot (as in the generic path), keeping the per-observation products
        Wo = np.matmul(J0.transpose(0, 2, 1), Jp)  # (M, 6, 3)
        W = st.w_reduce[0](Wo)
        go = np.einsum("mki,mk->mi", J0, r)  # (M, 6)
        g_c = st.g_reduce[0](go)
        U = np.zeros((st.B, 6, 6))
        st.add_diagonal_gram(U, 0, J0)
        # W: J_a^T Jp = h (Ad^T Jp); J_m^T Jp = -(J_obs^T Jp)[3:6] - J_a^T Jp
        W_a = h[:, :, None] * pr(np.einsum("mki,mk->mi", Jp, Ad))[:, None, :]
        W_m = -pr(Wo[:, 3:, :]) - W_a
        W[self.e_main, 3:] += W_m[self.main_ok]
        W[self.e_assoc, 3:] += W_a[self.assoc_ok]
        # g
        g_a = h * pr(np.einsum("mk,mk->m", Ad, r))[:, None]
        g_m = -pr(go[:, 3:]) - g_a
        g_c[:, 3:] += self.g_m(g_m) + self.g_a(g_a)
        # U, observer x anchors (per observation; batched products beat the factored form here)
        J_a = Ad[:, :, None] * h[op][:, None, :]
        for pair in ((0, 1), (0, 2)):
            red, (idx, idx_t) = self.cross[pair]
            if red.G.nnz == 0:  # e.g. every main anchor is the gauge camera
                continue
            J = J_a if pair == (0, 2) else -(A_C + J_a)
            R = red(np.matmul(J0.transpose(0, 2, 1), J))
            U[idx, :, 3:] += R
            U[idx_t, 3:, :] += R.transpose(0, 2, 1)
        # U, anchor x anchor (per point)
        s_aa = pr(np.einsum("mk,mk->m", Ad, Ad))
        T3 = pr(np.einsum("mki,mk->mi", A_C, Ad))  # sum A_C^T Ad
        Q = pr(gram(A_C))
        U_aa = s_aa[:, None, None] * (h[:, :, None] * h[:, None, :])
        T3h = T3[:, :, None] * h[:, None, :]
        U_ma = -T3h - U_aa  # rows: main centre, columns: associate centre
        U_mm = Q + T3h + T3h.transpose(0, 2, 1) + U_aa
        U[:, 3:, 3:] += (self.u_mm(U_mm) + self.u_aa(U_aa) + self.u_ma(U_ma)
                         + self.u_am(U_ma.transpose(0, 2, 1)))
        return g_c, W, U
