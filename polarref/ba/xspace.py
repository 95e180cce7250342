"""Three-slot forms eliminated through a change of point variable: no anchor cross terms.

Every three-slot form's residual depends on its observing camera and the world point
``X(q, C_m, C_a)`` only (parallax.py: the ray ``v_i = sin(w) (X - C_i)``, and every residual
row is a function of the ray's direction). So, per observation, the anchors' Jacobians are
the point Jacobian times a per-point 3x3 map: with ``D = dX/dq`` and ``G_x = dX/dC_x``,

    res_D_C_x = res_D_X G_x = Jp B_x,   B_x = D^-1 G_x   (x = main, associate),

and the forms' Jacobian is ``J_f = J_E T`` with ``J_E = [J_obs, Jp]`` (observer only: the
Euclidean structure, the forms' own Jp) and ``T = [[I, 0], [B, I]]`` (B: per point, the anchors'
centre columns). In the new point variable ``y = dq + B dc`` the damped LM system
``(T^T H_E T + Lambda) x = -T^T g_E`` reads

    (H_E + T^-T Lambda T^-1) [dc; y] = -g_E,   T^-T Lambda T^-1 = [[Lc + B^T Lq B, -B^T Lq],
                                                                  [-Lq B,        Lq]]

so the reduced camera system is the Euclidean-structured one (no observer x anchor products
per observation) with, per point, ``-B^T Lq`` on its anchors' two W entries and ``B^T Lq B`` on
their centre blocks of S; ``dq = y - B dc``. The point blocks ``V + Lq`` are the forms' own,
as conditioned as before. Exact arithmetic gives the same LM step; in floating point it agrees
to rounding (tests: 1e-9). The damping needs the forms' ``diag(U_f)``, with ``U_f = U_E + W B +
B^T W^T + B^T V B``, and the gradient test and model decrease the forms' ``g_f = g_E + B^T g_p``:
per-point sums.

The maps in closed form (parallax.py's terms: d, e, ``s = |d x e|``, h, ``dh/de``, ``dv/d(alpha,
beta)``): ``X = C_m + (h / sin w) d``, so ``D = [dv/d(alpha, beta) | -s d] diag(1/sin w, 1/sin w,
1/sin^2 w)`` and ``G_a = d dh/de^T / sin w``, ``G_m = I - G_a``. Since ``D e_3 = -(s / sin^2 w) d``,
``B_a = e_3 b^T`` with ``b = -(sin w / s) dh/de`` (only omega moves with the associate centre),
and ``B_m = D^-1 - B_a``. Both vanish at w = 0 (the point at infinity: the anchors do not
enter its rays), where they stay finite, so points at infinity need no special case.

Implementation (xspace_jit.py): the build is the observer slot's alone (the Euclidean
form's), with the anchors' share of ``g_f`` and ``diag(U_f)`` summed in its point loop; W
stays undamped, the anchors' ``-B^T Lq`` enters inside the Schur pass (``schur_xspace``; the
dense-visibility dsyrk path damps a copy of W) and as ``Lq B dc`` in the back-substitution.
Measured (reports/bench-ba/notes.md, sixth pass): the build and the Schur pass cost what the
Euclidean form's do, 0.5-1.5 ms per iteration less than with the cross terms (4 ms on
synth-200-sparse).

Where ``B`` does not carry the anchors' Jacobians, the solver keeps the reference path
(anchor_terms / the fused kernels' cross terms) for that build: fixed points (their Jp is
zeroed), a box-constrained omega held at a bound with ``B != 0`` (its Jp column is zeroed;
at w = 0, B = 0 and the identity holds; the chunked build, which learns that only after its
X-space build, then builds again by cross terms). Kernel path only
(``SchurStructure.fused``), dense S or its camera-pair blocks above ``dense_max_cameras``
(schur_sparse_jit.py); ``BAOptions.anchor_schur = "cross"`` keeps the reference always.
"""

from __future__ import annotations

import numpy as np


def anchor_maps(d, sw, s, dh_de, dv_dab) -> tuple[np.ndarray, np.ndarray]:
    """numpy reference of ``(Bm (P, 3, 3), b (P, 3))`` (module docstring) from parallax.py's
    per-point terms (P, ...)."""
    Mx = np.concatenate([dv_dab, -s[:, None, None] * d[:, :, None]], axis=2)
    Dinv = np.stack([sw, sw, sw * sw], axis=1)[:, :, None] * np.linalg.inv(Mx)
    b = -(sw / s)[:, None] * dh_de
    Bm = Dinv.copy()
    Bm[:, 2, :] -= b
    return Bm, b


def xspace_note(builds_x: int, builds_ref: int) -> str:
    """The solve's linear-solver string note: builds in X-space and by cross terms."""
    if not builds_x:
        return ""
    ref = f", {builds_ref} of {builds_x + builds_ref} builds by cross terms" if builds_ref else ""
    return f"; anchors eliminated in X-space{ref}"


class AnchorElimination:
    """The X-space elimination on a fused three-slot SchurStructure (kernel path).

    Per build: :meth:`build` (observer-only W, g_E, U diagonal blocks, and the anchors'
    share of the forms' gradient and diag(U_f)), :meth:`forms_terms`; per LM step:
    :meth:`reduced_system`, :meth:`back_substitute`. W stays the undamped observer-only one:
    the damping's ``-B^T Lq`` on the anchor entries enters inside the Schur pass and as
    ``Lq B dc`` in the back-substitution.
    """

    def __init__(self, st, main: np.ndarray, assoc: np.ndarray):
        if not st.fused:
            raise ValueError("AnchorElimination needs the fused three-slot kernel structure")
        self.st = st
        starts = st.obs_bounds[:-1]
        self.vm = np.ascontiguousarray(st.var_index[main], np.int64)
        self.va = np.ascontiguousarray(st.var_index[assoc], np.int64)
        # the anchors observe their point: their entries are observer entries of its rows
        self.em = np.ascontiguousarray(st.slot_entry[1][starts], np.int64)
        self.ea = np.ascontiguousarray(st.slot_entry[2][starts], np.int64)
        self.maps = self.lam = self.gx = self.diag_f = None

    @staticmethod
    def carries(anchors, active) -> bool:
        """Whether the maps of ``anchors`` (AnchorJacobian with ``maps``) hold this build's
        anchor Jacobians: every point with a held component (active (P, 3) or None) has
        B = 0."""
        if anchors.maps is None:
            return False
        if active is None:
            return True
        ai = np.flatnonzero(active.any(1))
        Bm, b = anchors.maps
        return not (Bm[ai].any() or b[ai].any())

    def build(self, J_obs, anchors, Jp, r, V, g_p, mask_v):
        """(g_E (Nv, 6), W (E, 6, 3), U (Nv, 6, 6)) of the observer slot alone, unmasked; V,
        g_p the (held-masked) point sums, mask_v (Nv, 6) the gauge mask (the maps' held
        columns are zeroed)."""
        from polarref.ba import xspace_jit
        st = self.st
        c = np.ascontiguousarray
        g, W, U = np.zeros((st.Nv, 6)), np.zeros((st.E, 6, 3)), np.zeros((st.Nv, 6, 6))
        self.start(anchors.maps)
        xspace_jit.build_xspace(c(J_obs), c(Jp), c(r), st.slot_vc, st.slot_entry, st.obs_bounds,
                                c(mask_v), *self.maps, c(V), c(g_p), W, g, U, self.gx,
                                self.diag_f)
        return g, W, U

    def start(self, maps) -> None:
        """A new build: the anchors' maps (Bm (P, 3, 3), b (P, 3)), copied (the build masks
        their held columns in place), and zeroed sums of the anchors' share."""
        Bm, b = maps
        self.maps = (np.array(Bm, order="C"), np.array(b, order="C"))
        self.gx, self.diag_f = np.zeros((self.st.Nv, 6)), np.zeros((self.st.Nv, 6))

    def carries_maps(self, active) -> bool:
        """:meth:`carries` for a build that made its own maps (chunked.py): checked on the
        masked maps, whose zeroed columns are held cameras' (their steps are zero)."""
        if active is None:
            return True
        ai = np.flatnonzero(active.any(1))
        Bm, b = self.maps
        return not (Bm[ai].any() or b[ai].any())

    def forms_terms(self, g_E) -> tuple[np.ndarray, np.ndarray]:
        """(g_f (Nv, 6), diag(U_f) - diag(U_E) (Nv, 6)) from the masked g_E of the build."""
        return g_E + self.gx, self.diag_f

    def reduced_system(self, U, W, Vd, g_E, g_p, diag_c, lam):
        """(S, b, Li) of the damped X-space system (module docstring); lam (P, 3) the point
        blocks' damping diagonal (kept for :meth:`back_substitute`)."""
        from polarref.ba import xspace_jit
        from polarref.ba.schur import chol_inv3
        st = self.st
        Bm, b = self.maps
        self.lam = lam = np.ascontiguousarray(lam)
        if st.use_gemm:  # dense visibility: Z = W L^-T for one dsyrk, from a damped copy
            Wd = W.copy()
            xspace_jit.damp_W(Wd, Bm, b, lam, self.vm, self.va, self.em, self.ea)
            system = st.reduced_system(U, Wd, Vd, g_E, g_p, diag_c, cross=False)
            if system is not None:
                xspace_jit.add_damping(system[0], Bm, b, lam, self.vm, self.va)
            return system
        Li = chol_inv3(Vd)
        if Li is None:
            return None
        q = np.matmul(Li, g_p[:, :, None])[:, :, 0]
        if st.sparse_S:
            return self._sparse_system(U, W, Li, q, g_E, diag_c)
        Nv = st.Nv
        S = np.zeros((Nv, 6, Nv, 6))
        S[st.u_ca, :, st.u_cb, :] = U
        S = S.reshape(6 * Nv, 6 * Nv)
        bvec = -g_E
        if st.E:
            xspace_jit.schur_xspace(W, Li, q, st.entry_bounds, st.entry_pt, st.entry_cam,
                                    self.em, self.ea, self.vm, self.va, Bm, b, lam, S, bvec)
        S[np.diag_indices_from(S)] += diag_c.reshape(-1)
        return S, bvec.reshape(-1), Li

    def _sparse_system(self, U, W, Li, q, g_E, diag_c):
        """:meth:`reduced_system` into the block-sparse S (schur_sparse_jit.py)."""
        from polarref.ba import schur_sparse_jit
        st = self.st
        Bm, b = self.maps
        blocks = st.blocks_with_u(U)
        bvec = -g_E
        if st.E:
            schur_sparse_jit.schur_blocks_xspace(np.ascontiguousarray(W), Li, q, st.entry_bounds,
                                                 st.entry_pt, st.entry_cam, st.pair_blk, blocks,
                                                 bvec, self.em, self.ea, Bm, b, self.lam)
        st.add_diagonal_blocks(blocks, diag_c)
        return st.bsr(blocks), bvec.reshape(-1), Li

    def back_substitute(self, W, Li, g_p, dc: np.ndarray) -> np.ndarray:
        """Point steps dq (P, 3) from the camera step dc (Nv, 6, masked)."""
        from polarref.ba import kernels, xspace_jit
        rhs = -g_p
        dc = np.ascontiguousarray(dc)
        if self.st.E:
            kernels.back_substitute_rhs(W, dc, self.st.entry_pt, self.st.entry_cam, rhs)
        xspace_jit.point_steps(rhs, Li, *self.maps, self.lam, dc, self.vm, self.va)
        return rhs
