"""Index structures and the reduced camera system (Schur complement over point blocks).

Everything index-like is built once per problem; per iteration only dense arithmetic, small
GEMMs and sparse 0/1 "sum by key" products run (no ``np.add.at``, no sorting, no Python loop
over observations). Terms:

* a *slot* is one camera that an observation's residual depends on: the observing camera, and
  for parallax landmarks also the main and associate anchors. A slot covers a column range of
  the camera block: the observing slot all 6 ``(dtheta, dC)``, an anchor slot only the centre
  columns 3:6 (an anchor's rotation does not enter the landmark), so its Jacobian is (M, k, 3);
* an *entry* is a distinct (point, variable camera) pair with a Jacobian coupling;
* ``U`` (6x6 camera blocks, both triangles kept), ``V`` (3x3 point blocks), ``W`` (6x3 per
  entry). With ``V = L L^T`` and ``Z = W L^-T`` per entry, ``S = U - Z Z^T`` (+ damping).
* ``Z Z^T`` is formed either by one BLAS ``dsyrk`` on a dense (6 Nv, 3 P) matrix (dense
  visibility: most points in most images) or by one small GEMM per pair of cameras that share
  points, over the entry pairs of that camera pair gathered contiguously (sparse
  visibility), whichever a cost estimate says is cheaper. The second form replaced one 6x6 product per entry pair plus ``np.add.reduceat``: Ladybug-49 Schur
  0.17 s -> ~0.02 s per iteration.
* Kernel path, dense S: the entry-pair kernel, or GEMMs over windows of consecutive cameras
  (schur_panel.py) where its cost model says padding the points into dense panels pays
  (long runs of shared cameras); reports/bench-ba-scale/schur-panel.md measures both.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from polarref.ba import schur_panel
from polarref.ba.reduced_solve import ReducedSolver, pcg

# Cost model for choosing the Z Z^T form, measured on this machine (1 BLAS thread):
# ~30 ns per gathered entry pair (2 x 18 doubles), ~4 us per camera-pair GEMM call,
# ~0.1 ns per dsyrk flop (n^2 k flops for an (n, k) operand).
_PAIR_S = 3.0e-8
_PAIR_CHUNK = 1 << 20  # entry pairs per gather run of the camera-pair GEMM path (~300 MB)
_SEGMENT_S = 4.0e-6
_FLOP_S = 1.0e-10
_PAIR_KERNEL_S = 3.0e-8  # compiled kernel: one 6x6x3 block product per entry pair (measured below)


def _group_starts(sorted_keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starts of runs of equal values in a sorted array, and the run values."""
    if len(sorted_keys) == 0:
        return np.zeros(0, np.int64), sorted_keys
    starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]])
    return starts, sorted_keys[starts]


def unique_inverse(keys: np.ndarray, bound: int) -> tuple[np.ndarray, np.ndarray]:
    """(sorted distinct values of ``keys``, each key's index into them): the result of
    ``np.unique(keys, return_inverse=True)`` for int keys in [0, bound). The structure build
    did several such uniques per solve (a third of a warm solve on synth-200-sparse); a
    presence table replaces the sort when ``bound`` is small beside the key count (camera
    pairs), a stable argsort (cheap on the point-grouped keys) otherwise."""
    keys = np.asarray(keys, np.int64)
    if bound <= 4 * len(keys) + 4096:
        seen = np.zeros(bound, bool)
        seen[keys] = True
        return np.flatnonzero(seen).astype(np.int64), (np.cumsum(seen) - 1)[keys]
    order = np.argsort(keys, kind="stable")
    ks = keys[order]
    new = np.ones(len(ks), bool)
    new[1:] = ks[1:] != ks[:-1]
    inv = np.empty(len(keys), np.int64)
    inv[order] = np.cumsum(new) - 1
    return ks[new], inv


def _inverse_or_skip(keys: np.ndarray, bound: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`unique_inverse` of the keys >= 0; the index array keeps the shape of ``keys``
    with -1 where a key is negative (a fixed camera)."""
    ok = keys >= 0
    uniq, inv = unique_inverse(keys[ok], bound)
    full = np.full(keys.shape, -1, np.int64)
    full[ok] = inv
    return uniq, full


_NO_CROSS = (np.zeros((0, 6, 4)), np.zeros((0, 3)), np.zeros((0, 3, 3)))  # schur_dense
# camera-pair tables up to this many cells (Nv^2: 2^25 at ~5,800 variable cameras, 160 MB with
# its int32 index); above, the pairs' keys are sorted (schur.py _build_blocks)
_PAIR_TABLE_MAX = 1 << 25


def _c(a: np.ndarray) -> np.ndarray:
    """C-contiguous float64 (the kernels are compiled for that layout only)."""
    return np.ascontiguousarray(a, dtype=np.float64)


class Reducer:
    """Sums rows (M, ...) into K groups by key (-1 = dropped) with a sparse 0/1 matrix.

    One C pass over the values, no gather copy (10x faster than sort + ``np.add.reduceat``).
    """

    def __init__(self, keys: np.ndarray, K: int):
        keys = np.asarray(keys, np.int64)
        ok = np.flatnonzero(keys >= 0)
        self.K = K
        self.G = scipy.sparse.csr_matrix((np.ones(len(ok)), (keys[ok], ok)),
                                         shape=(K, len(keys)))

    def __call__(self, values: np.ndarray) -> np.ndarray:
        flat = np.ascontiguousarray(values).reshape(len(values), -1)
        return np.asarray(self.G @ flat).reshape((self.K,) + values.shape[1:])


def gram(J: np.ndarray) -> np.ndarray:
    """Batched ``J^T J`` (M, c, c) of (M, k, c).

    numpy's batched matmul takes a slow path (3x) when both operands share memory, so the
    transposed operand is copied first.
    """
    return np.matmul(np.ascontiguousarray(J.transpose(0, 2, 1)), J)


def chol_inv3(V: np.ndarray) -> np.ndarray | None:
    """Batched ``L^-1`` of the Cholesky factor ``V = L L^T`` of 3x3 blocks (P, 3, 3).

    Closed form (5x faster than ``np.linalg.inv`` on (P, 3, 3)); ``V^-1 = Li^T Li``.
    Returns None when a block is not positive definite.
    """
    a, b, c = V[:, 0, 0], V[:, 1, 0], V[:, 2, 0]
    d, e, f = V[:, 1, 1], V[:, 2, 1], V[:, 2, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        l11 = np.sqrt(a)
        l21, l31 = b / l11, c / l11
        l22 = np.sqrt(d - l21 * l21)
        l32 = (e - l31 * l21) / l22
        l33 = np.sqrt(f - l31 * l31 - l32 * l32)
        Li = np.zeros_like(V)
        Li[:, 0, 0] = m11 = 1.0 / l11
        Li[:, 1, 1] = m22 = 1.0 / l22
        Li[:, 2, 2] = m33 = 1.0 / l33
        Li[:, 1, 0] = m21 = -l21 * m11 * m22
        Li[:, 2, 1] = -l32 * m22 * m33
        Li[:, 2, 0] = -(l31 * m11 + l32 * m21) * m33
    return Li if np.isfinite(Li).all() else None


class SchurStructure:
    """Precomputed index structure for one problem and one parameterization.

    ``reduced_solver`` (set by the solver, reduced_solve.py) picks PCG instead of the dense
    Cholesky / sparse LU that ``sparse_S`` implies; ``pcg_settings`` = (rtol, max iterations).

    Args:
        slot_cams: (S, M) camera index of each of the S camera slots of each observation.
        slot_cols: S column ranges ``(c0, c1)`` of the 6-column camera block per slot.
        obs_pt: (M,) point index, sorted ascending, every point present.
        cam_var: (N,) True for cameras with at least one free parameter.
        num_points: P.
        dense_max_cameras: above this many variable cameras S is sparse (sparse LU).
        fast: compiled kernels. anchored: a three-slot layout's anchors can come factored
            (``[J_obs, AnchorJacobian]``), which the fused kernel build needs.
    """

    def __init__(self, slot_cams: np.ndarray, slot_cols, obs_pt: np.ndarray,
                 cam_var: np.ndarray, num_points: int, dense_max_cameras: int = 700,
                 fast: bool = False, anchored: bool = True):
        S, M = slot_cams.shape
        N, P = len(cam_var), num_points
        self.S, self.M, self.N, self.P = S, M, N, P
        self.fast = fast  # compiled kernels (kernels.py) instead of numpy gathers/reducers
        self.reduced_solver = ReducedSolver.AUTO  # AUTO: sparse LU if sparse_S else Cholesky
        self.pcg_settings, self.pcg_iterations = (1e-8, 1000), []
        self.slot_cols = [tuple(c) for c in slot_cols]
        self.var_index = -np.ones(N, np.int64)
        self.var_cams = np.flatnonzero(cam_var)
        self.var_index[self.var_cams] = np.arange(len(self.var_cams))
        self.Nv = Nv = len(self.var_cams)
        nv = max(Nv, 1)
        self.pt_starts, _ = _group_starts(obs_pt)
        if len(self.pt_starts) != P:
            raise ValueError("SchurStructure: every point needs >= 1 observation, sorted by point")
        self.obs_pt = np.ascontiguousarray(obs_pt, np.int64)
        self.pt_reduce = Reducer(obs_pt, P)
        vc = self.var_index[slot_cams]  # (S, M), -1 = fixed camera
        self.slot_vc = vc
        # -- entries: distinct (point, variable camera), sorted by point then camera ----------
        key = np.where(vc >= 0, obs_pt[None, :] * nv + vc, -1)
        ukeys, slot_entry = _inverse_or_skip(key, max(P, 1) * nv)
        self.E = E = len(ukeys)
        self.entry_pt, self.entry_cam = ukeys // nv, ukeys % nv
        self.slot_entry = slot_entry
        self.entry_cam_reduce = Reducer(self.entry_cam, Nv)
        self.entry_pt_starts, self.pts_with_entries = _group_starts(self.entry_pt)
        # -- choose how to form Z Z^T ----------------------------------------------------------
        counts = np.diff(np.r_[self.entry_pt_starts, E])
        self.num_pairs = int((counts * (counts + 1) // 2).sum())
        self.sparse_S = Nv > dense_max_cameras
        gemm_s = (6.0 * Nv) ** 2 * 3 * len(counts) * _FLOP_S
        if fast:
            pair_s = self.num_pairs * _PAIR_KERNEL_S
        else:
            segments = min(Nv * (Nv + 1) // 2, self.num_pairs)  # upper bound, without building
            pair_s = self.num_pairs * _PAIR_S + segments * _SEGMENT_S
        self.use_gemm = (not self.sparse_S) and gemm_s < pair_s
        # Kernel path, dense S by entry pairs, three slots (parallax forms): the camera blocks
        # that couple two different cameras of one observation go straight into S inside the
        # Schur kernel (both cameras are entries of the observation's point, so the kernel
        # touches that block of S anyway); U keeps only the diagonal camera blocks. The build
        # then takes the anchors' Jacobians factored ([J_obs, AnchorJacobian], anchor_terms.py)
        # and computes those blocks once per build (kernels.build_anchored), not per LM step.
        # With the dsyrk (dense visibility) they are added to S after it (kernels.add_cross).
        # Block-sparse S (sparse_S) too: those cross blocks are pairs of the point's entries
        # (the anchors observe it), so they have their blocks (schur_sparse_jit.py).
        self.fused = fast and anchored and self.slot_cols == [(0, 6), (3, 6), (3, 6)]
        if fast:
            obs_e = slot_entry[0][slot_entry[0] >= 0]
            # no entry observes its point twice: build_anchored writes its cross blocks once
            self.observer_unique = not len(obs_e) or np.bincount(obs_e, minlength=E).max() <= 1
            self._build_u_fast(vc)
            self.entry_bounds = np.r_[self.entry_pt_starts, E].astype(np.int64)
            self.obs_bounds = np.r_[self.pt_starts, M].astype(np.int64)
        else:
            self._build_u_reducers(vc, slot_entry)
        # Euclidean-structured entry-pair path: products into contiguous camera-pair blocks
        # (scattered into the dense S once per step): 1.7x the rate of writing them into
        # six rows of the dense S on scale-1e5 (reports/bench-ba-scale/schur-roofline.md)
        self.dense_blocks = fast and not self.sparse_S and not self.use_gemm and not self.fused
        self.pair_blk = None  # the block layout (_build_blocks), built once where a path needs it
        # dense S with long runs of shared cameras: GEMMs over camera windows (schur_panel.py)
        self.panel = None
        self._zd = None  # dsyrk path: the scattered Z, kept across builds (_scatter_zd)
        if fast and not self.sparse_S and not self.use_gemm and E:
            self.use_panels(schur_panel.choose_width(self.entry_bounds, self.entry_cam,
                                                     self.num_pairs, Nv))
        if fast and (self.sparse_S or self.dense_blocks) and self.pair_blk is None:
            self._build_blocks()
        elif not self.use_gemm and (self.sparse_S or not fast):
            self._build_pairs(counts)

    def use_panels(self, width: int) -> None:
        """Kernel path, dense S: the point products by GEMMs over camera windows of ``width``
        (schur_panel.py), or 0: the entry-pair kernel."""
        self.panel = schur_panel.plan(self.entry_bounds, self.entry_cam, width) if width else None
        self.dense_blocks = self.panel is None and not self.use_gemm and not self.fused
        if self.dense_blocks and self.pair_blk is None:
            self._build_blocks()

    def _build_u_reducers(self, vc: np.ndarray, slot_entry: np.ndarray) -> None:
        """numpy path: sparse 0/1 reducers per slot and slot pair (U, W, g)."""
        S, M, Nv, E = self.S, self.M, self.Nv, self.E
        nv = max(Nv, 1)
        self.w_reduce = [Reducer(slot_entry[s], E) for s in range(S)]
        self.g_reduce = [Reducer(vc[s], Nv) for s in range(S)]
        # -- U: slot pairs a <= b; diagonal slot pairs by per-camera GEMM over sorted rows ---
        self.u_keys = []
        self.u_diag = []  # per slot: (row order, segment starts/ends, camera of each segment)
        self.u_cross = []  # per slot pair a < b: (a, b, reducer, keys (K,))
        for s in range(S):
            rows = np.flatnonzero(vc[s] >= 0)
            order = rows[np.argsort(vc[s, rows], kind="stable")]
            starts, cams = _group_starts(vc[s, order])
            ends = np.r_[starts[1:], len(order)]
            self.u_diag.append((order, starts, ends, cams))
            self.u_keys.append(cams * nv + cams)
        for a in range(S):
            for b in range(a + 1, S):
                ok = (vc[a] >= 0) & (vc[b] >= 0)
                k_ab = np.where(ok, vc[a] * nv + vc[b], -1)
                uk, inv = np.unique(k_ab[ok], return_inverse=True)
                keys = -np.ones(M, np.int64)
                keys[ok] = inv
                self.u_cross.append((a, b, Reducer(keys, len(uk)), uk))
                ca, cb = uk // nv, uk % nv
                self.u_keys += [uk, cb * nv + ca]
        allk = np.unique(np.concatenate(self.u_keys)) if self.u_keys else np.zeros(0, np.int64)
        self.u_ca, self.u_cb = allk // nv, allk % nv
        self.B = len(allk)
        self.u_diag_idx = [np.searchsorted(allk, cams * nv + cams) for _, _, _, cams in self.u_diag]
        self.u_cross_idx = [(np.searchsorted(allk, uk),
                             np.searchsorted(allk, (uk % nv) * nv + uk // nv))
                            for _, _, _, uk in self.u_cross]

    def _build_u_fast(self, vc: np.ndarray) -> None:
        """Kernel path: the U block of every observation and slot pair (a <= b), and of its
        transpose (a < b), as (M,) index arrays (-1 = a fixed camera). Fused: the diagonal
        camera blocks only (the rest goes into S, see __init__)."""
        S, nv = self.S, max(self.Nv, 1)
        if self.fused:  # kernels.build_anchored: U block index = variable camera
            self.u_ca = self.u_cb = np.arange(self.Nv)
            self.B = self.Nv
            return
        pairs = [(a, b) for a in range(S) for b in range(a, S)]
        keys = []
        for a, b in pairs:
            ok = (vc[a] >= 0) & (vc[b] >= 0)
            keys.append(np.where(ok, vc[a] * nv + vc[b], -1))
            if a != b:
                keys.append(np.where(ok, vc[b] * nv + vc[a], -1))
        allk, index = _inverse_or_skip(np.concatenate(keys), nv * nv)
        self.u_ca, self.u_cb = allk // nv, allk % nv
        self.B = len(allk)
        self.u_pairs, it = [], iter(np.split(index, len(keys)))
        none = -np.ones(self.M, np.int64)
        for a, b in pairs:
            idx = next(it)
            self.u_pairs.append((a, b, idx, next(it) if a != b else none))

    def _build_pairs(self, counts: np.ndarray) -> None:
        """Entry pairs (ea <= eb) sharing a point, sorted by camera pair into segments."""
        E, Nv = self.E, max(self.Nv, 1)
        if E == 0:
            self.pair_a = self.pair_b = self.seg_starts = self.seg_ends = np.zeros(0, np.int64)
            self.seg_ca = self.seg_cb = np.zeros(0, np.int64)
            self.seg_bounds, self.seg_chunks = [], []
            return
        reps = np.repeat(counts, counts)  # per entry: size of its point's group
        first = np.repeat(self.entry_pt_starts, counts)  # per entry: its group's start
        ea = np.repeat(np.arange(E), reps)
        off = np.arange(len(ea)) - np.repeat(np.cumsum(reps) - reps, reps)
        eb = np.repeat(first, reps) + off
        keep = eb >= ea  # entries are sorted by camera within a point: ca <= cb
        ea, eb = ea[keep], eb[keep]
        key = self.entry_cam[ea] * Nv + self.entry_cam[eb]
        order = np.argsort(key, kind="stable")
        self.pair_a, self.pair_b = ea[order], eb[order]
        self.seg_starts, sk = _group_starts(key[order])
        self.seg_ends = np.r_[self.seg_starts[1:], len(order)]
        self.seg_ca, self.seg_cb = sk // Nv, sk % Nv
        self.seg_bounds = list(zip((3 * self.seg_starts).tolist(), (3 * self.seg_ends).tolist()))
        # runs of whole segments of <= _PAIR_CHUNK pairs: the column gathers of _pair_blocks are
        # 288 B per pair, 8 GB at once on the 857-view twin (tens of millions of entry pairs)
        cut = np.searchsorted(self.seg_starts, np.arange(0, len(order), _PAIR_CHUNK), side="right") - 1
        cut = np.unique(np.r_[np.maximum(cut, 0), len(self.seg_starts)])
        self.seg_chunks = list(zip(cut[:-1].tolist(), cut[1:].tolist()))

    def _build_blocks(self) -> None:
        """Kernel path, sparse S: its block pattern (the camera pairs ca <= cb of the entry
        pairs, of U's blocks and the diagonal), each entry pair's block (int32) in the order
        ``kernels.schur_blocks`` visits them, and the permutation that lays the blocks and
        their transposes out as the full symmetric BSR matrix (rows sorted once, here)."""
        from polarref.ba import kernels
        nv = max(self.Nv, 1)
        self.u_up = np.flatnonzero(self.u_ca <= self.u_cb)
        u_keys = self.u_ca[self.u_up] * nv + self.u_cb[self.u_up]
        d_keys = np.arange(self.Nv) * (nv + 1)
        if nv * nv <= _PAIR_TABLE_MAX:
            # a table of the camera pairs: the per-pair int64 keys and their inverse (3 x 8
            # bytes per entry pair, ~1 GB beside the 631-view twin's final BA) are never made
            seen = np.zeros(nv * nv, bool)
            if self.E:
                kernels.mark_pairs(self.entry_bounds, self.entry_cam, nv, seen)
            seen[u_keys] = seen[d_keys] = True
            allk = np.flatnonzero(seen)
            index = (np.cumsum(seen) - 1).astype(np.int32)
            self.pair_blk = np.empty(self.num_pairs, np.int32)
            if self.E:
                kernels.pair_blocks(self.entry_bounds, self.entry_cam, nv, index, self.pair_blk)
            self.u_blk, self.diag_blk = index[u_keys].astype(np.int64), index[d_keys].astype(np.int64)
        else:
            keys = np.empty(self.num_pairs, np.int64)
            if self.E:
                kernels.pair_keys(self.entry_bounds, self.entry_cam, nv, keys)
            allk, inv = unique_inverse(np.concatenate([keys, u_keys, d_keys]), nv * nv)
            n, nu = len(keys), len(u_keys)
            del keys
            self.pair_blk = inv[:n].astype(np.int32)
            self.u_blk, self.diag_blk = inv[n:n + nu], inv[n + nu:]
        self.K = len(allk)
        self.blk_ca, self.blk_cb = ca, cb = allk // nv, allk % nv
        self.blk_off = np.flatnonzero(ca != cb)
        rows, cols = np.r_[ca, cb[self.blk_off]], np.r_[cb, ca[self.blk_off]]
        self.bsr_order = np.lexsort((cols, rows))
        self.bsr_indices = cols[self.bsr_order].astype(np.int32)
        self.bsr_indptr = np.r_[0, np.cumsum(np.bincount(rows, minlength=self.Nv))].astype(np.int32)

    # ------------------------------------------------------------------------------------------
    def linear_solver_name(self) -> str:
        how = ("dense syrk" if self.use_gemm else
               f"window GEMMs, width {self.panel.width}" if self.panel is not None else
               "entry-pair kernel" + (", block-sparse S" if self.sparse_S else ", camera-pair blocks"
                                      if self.dense_blocks else "") if self.fast
               else "camera-pair GEMMs")
        kern = "; numba kernels" if self.fast else "; numpy"
        solver = ("PCG block-Jacobi" + (f" ({sum(self.pcg_iterations)} CG iterations in "
                                        f"{len(self.pcg_iterations)} solves)"
                                        if self.pcg_iterations else "")
                  if self.reduced_solver is ReducedSolver.PCG else
                  "sparse LU" if self.sparse_S else "dense Cholesky")
        return f"Schur ({how}) + {solver}{kern}"

    def reduce_points(self, per_obs: np.ndarray) -> np.ndarray:
        """Sum per-observation arrays (M, ...) over each point -> (P, ...)."""
        return self.pt_reduce(per_obs)

    def point_terms(self, Jp: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(V (P, 3, 3), g_p (P, 3)): sums of Jp^T Jp and Jp^T r over each point's rows."""
        if not self.fast:
            return self.pt_reduce(gram(Jp)), self.pt_reduce(np.einsum("mki,mk->mi", Jp, r))
        from polarref.ba import kernels
        V, g = np.zeros((self.P, 3, 3)), np.zeros((self.P, 3))
        kernels.point_sums(_c(Jp), _c(r), self.obs_pt, V, g)
        return V, g

    def entries_W(self, Jc: list[np.ndarray], Jp: np.ndarray) -> np.ndarray:
        """W blocks (E, 6, 3) = sum of Jc^T Jp over the observations/slots of each entry."""
        W = None
        for s, J in enumerate(Jc):
            c0, c1 = self.slot_cols[s]
            part = self.w_reduce[s](np.matmul(J.transpose(0, 2, 1), Jp))
            if W is None and (c0, c1) == (0, 6):
                W = part
                continue
            if W is None:
                W = np.zeros((self.E, 6, 3))
            W[:, c0:c1] += part
        return W

    def apply_mask(self, mask_v: np.ndarray, g_c, W, U):
        """Zero the held (gauge) columns of partly fixed variable cameras in g_c, W and U.

        mask_v: (Nv, 6) 1 = free. Fully fixed cameras have no entries at all.
        """
        self.mask_v = mask_v
        partial = ~(mask_v > 0).all(1)
        if not partial.any():
            return g_c, W, U
        g_c = g_c * mask_v
        e = np.flatnonzero(partial[self.entry_cam])
        W[e] *= mask_v[self.entry_cam[e]][:, :, None]
        b = np.flatnonzero(partial[self.u_ca] | partial[self.u_cb])
        U[b] *= mask_v[self.u_ca[b]][:, :, None] * mask_v[self.u_cb[b]][:, None, :]
        return g_c, W, U

    def build(self, Jc: list[np.ndarray], Jp: np.ndarray, r: np.ndarray):
        """(g_c (Nv, 6), W (E, 6, 3), U (B, 6, 6)) from per-slot Jacobians, unmasked."""
        if self.fast:
            return self._build_fast(Jc, Jp, r)
        return self.camera_vector(Jc, r), self.entries_W(Jc, Jp), self.camera_U(Jc)

    def _build_fast(self, Jc: list[np.ndarray], Jp: np.ndarray, r: np.ndarray):
        from polarref.ba import kernels
        g_c, W, U = np.zeros((self.Nv, 6)), np.zeros((self.E, 6, 3)), np.zeros((self.B, 6, 6))
        Jp, r = _c(Jp), _c(r)
        if self.fused:  # one pass; the cross-camera blocks are added to S in reduced_system
            if len(Jc) != 2:
                raise ValueError("fused three-slot build needs [J_obs, AnchorJacobian]")
            anc = Jc[1]
            # the previous build's cross blocks are dead once a new build starts: reuse their
            # memory (fresh 2 x (E, 6, 3) pages cost ~0.5 ms of page faults per build)
            cross = getattr(self, "cross_blocks", None)
            if cross is None:
                cross = (np.empty((self.E, 6, 4)), np.empty((self.P, 3, 3)))
            if not self.observer_unique:
                cross[0][:] = 0.0
            h = _c(anc.h)
            kernels.build_anchored(_c(Jc[0]), _c(anc.Ad), h, Jp, r, self.slot_vc,
                                   self.slot_entry, self.obs_bounds, W, g_c, U, *cross,
                                   self.observer_unique)
            self.cross_blocks = cross
            self.cross_h = h
            return g_c, W, U
        Jc = [_c(J) for J in Jc]
        if self.slot_cols == [(0, 6)]:  # one observer slot (Euclidean): one pass
            kernels.build_observer(Jc[0], Jp, r, self.slot_vc[0], self.slot_entry[0],
                                   self.u_pairs[0][2], W, g_c, U)
            return g_c, W, U
        for s, J in enumerate(Jc):
            kernels.slot_w_g(J, self.slot_cols[s][0], Jp, r, self.slot_entry[s],
                             self.slot_vc[s], W, g_c)
        for a, b, idx, idx_t in self.u_pairs:
            kernels.slot_gram(Jc[a], self.slot_cols[a][0], Jc[b], self.slot_cols[b][0],
                              idx, idx_t, U)
        return g_c, W, U

    def add_diagonal_gram(self, U: np.ndarray, s: int, J: np.ndarray) -> None:
        """U[(c, c)] += sum of J^T J over the rows of slot s with camera c (one GEMM per c)."""
        order, starts, ends, _ = self.u_diag[s]
        c0, c1 = self.slot_cols[s]
        nc = c1 - c0
        k = J.shape[1]
        rows = J[order].reshape(-1, nc)  # observations' rows grouped by camera
        blocks = np.empty((len(starts), nc, nc))
        for i, (s0, s1) in enumerate(zip((starts * k).tolist(), (ends * k).tolist())):
            seg = rows[s0:s1]
            blocks[i] = seg.T @ seg
        U[self.u_diag_idx[s], c0:c1, c0:c1] += blocks

    def camera_U(self, Jc: list[np.ndarray]) -> np.ndarray:
        """U blocks (B, 6, 6) at (u_ca, u_cb), both triangles."""
        U = np.zeros((self.B, 6, 6))
        for s, J in enumerate(Jc):
            self.add_diagonal_gram(U, s, J)
        for (a, b, red, _), (idx, idx_t) in zip(self.u_cross, self.u_cross_idx):
            (a0, a1), (b0, b1) = self.slot_cols[a], self.slot_cols[b]
            R = red(np.matmul(Jc[a].transpose(0, 2, 1), Jc[b]))
            U[idx, a0:a1, b0:b1] += R
            U[idx_t, b0:b1, a0:a1] += R.transpose(0, 2, 1)
        return U

    def camera_vector(self, Jc: list[np.ndarray], r: np.ndarray) -> np.ndarray:
        """Sum of Jc^T r per variable camera -> (Nv, 6)."""
        out = np.zeros((self.Nv, 6))
        for s, J in enumerate(Jc):
            c0, c1 = self.slot_cols[s]
            out[:, c0:c1] += self.g_reduce[s](np.einsum("mki,mk->mi", J, r))
        return out

    def reduced_system(self, U_blocks, W, Vd, g_c, g_p, diag_c, cross: bool = True):
        """Assemble S (dense (6Nv, 6Nv) or sparse) and b = -g_c + W V^-1 g_p.

        Args: U blocks (B, 6, 6), W (E, 6, 3), damped V (P, 3, 3), g_c (Nv, 6), g_p (P, 3),
        camera damping diag_c (Nv, 6); cross: the fused build's cross blocks go in (False:
        the observer-only system of xspace.py).
        Returns (S, b, Li) with ``Li`` from :func:`chol_inv3` (reused for back-substitution),
        or None when a damped point block is not positive definite.
        """
        Nv, E = self.Nv, self.E
        Li = chol_inv3(Vd)
        if Li is None:
            return None
        q = np.matmul(Li, g_p[:, :, None])[:, :, 0]  # L^-1 g_p
        b = -g_c.copy()
        fused = self.fused and cross
        if self.fast and self.sparse_S:
            return self.bsr(self._blocks(U_blocks, W, Li, q, b, diag_c, fused)), b.reshape(-1), Li
        if self.panel is not None:
            return self._panel_system(U_blocks, W, Li, q, b, diag_c, fused), b.reshape(-1), Li
        if self.dense_blocks:  # the upper block triangle (ca <= cb), what the Cholesky reads
            S = np.zeros((Nv, 6, Nv, 6))
            S[self.blk_ca, :, self.blk_cb, :] = self._blocks(U_blocks, W, Li, q, b, diag_c)
            return S.reshape(6 * Nv, 6 * Nv), b.reshape(-1), Li
        if self.fast and not self.sparse_S and not self.use_gemm:
            from polarref.ba import kernels
            S = np.zeros((Nv, 6, Nv, 6))
            S[self.u_ca, :, self.u_cb, :] = U_blocks
            S = S.reshape(6 * Nv, 6 * Nv)
            if E:
                X = self._cross() if fused else _NO_CROSS
                kernels.schur_dense(_c(W), Li, q, self.entry_bounds, self.entry_pt,
                                    self.entry_cam, S, b, fused, *X, self.slot_entry,
                                    self.obs_bounds)
            if fused:
                self._zero_held(S)
            S[np.diag_indices_from(S)] += diag_c.reshape(-1)
            return S, b.reshape(-1), Li
        if E and self.fast and self.use_gemm:
            # compiled: Z and b in one pass over the entries, then scattered for the dsyrk; numpy's
            # batched 6x3 products, its b reduction and the fancy scatter were 3/4 of synth-20's
            # Schur stage. Z differs from numpy's (BLAS fused multiply-adds) in the last bits.
            from polarref.ba import schur_panel_jit
            Z, zq = np.empty((E, 6, 3)), np.zeros_like(b)
            # summed apart, then added: numpy's order (-g_c + sum over the entries)
            schur_panel_jit.entry_factors(_c(W), Li, q, self.entry_bounds, self.entry_pt, self.entry_cam, Z, zq)
            b += zq
        else:
            Z = np.matmul(W, Li[self.entry_pt].transpose(0, 2, 1)) if E else np.zeros((0, 6, 3))
            if E:
                b += self.entry_cam_reduce(np.matmul(Z, q[self.entry_pt][:, :, None])[:, :, 0])
        if self.sparse_S:
            return self._sparse_system(U_blocks, Z, diag_c), b.reshape(-1), Li
        S = np.zeros((Nv, 6, Nv, 6))
        S[self.u_ca, :, self.u_cb, :] = U_blocks
        S = S.reshape(6 * Nv, 6 * Nv)
        if E and self.use_gemm:
            Zd = self._scatter_zd(Z)
            # S -= Zd Zd^T, lower triangle (column-major view of S) in one BLAS call; the
            # Cholesky below reads only that triangle.
            Sf = S.T
            scipy.linalg.blas.dsyrk(-1.0, Zd.reshape(6 * Nv, -1).T, beta=1.0, c=Sf, trans=1,
                                    lower=1, overwrite_c=1)
            if fused:
                from polarref.ba import kernels
                kernels.add_cross(S, *self._cross(), self.entry_bounds, self.entry_pt,
                                  self.entry_cam, self.slot_entry, self.obs_bounds)
                self._zero_held(S)
        elif E:
            blocks = self._pair_blocks(Z)
            S4 = S.reshape(Nv, 6, Nv, 6)
            S4[self.seg_ca, :, self.seg_cb, :] -= blocks
            off = self.seg_ca != self.seg_cb
            S4[self.seg_cb[off], :, self.seg_ca[off], :] -= blocks[off].transpose(0, 2, 1)
        S[np.diag_indices_from(S)] += diag_c.reshape(-1)
        return S, b.reshape(-1), Li

    def _scatter_zd(self, Z: np.ndarray) -> np.ndarray:
        """Z (E, 6, 3) in the (Nv, 6, P, 3) layout of the dsyrk. Its zeros depend only on the
        sparsity, so the buffer is kept across builds and only the entries' cells are written
        again, through flat indices made once: a fresh zeroed buffer and the 4-d fancy
        assignment cost ~2.5x this per build (synth-60: 8.6 MB)."""
        if self.fast:
            from polarref.ba import schur_panel_jit
            if self._zd is None:
                self._zd = np.zeros((self.Nv, 6, self.P, 3))
            schur_panel_jit.scatter_entries(Z, self.entry_pt, self.entry_cam, self._zd)
            return self._zd
        if self._zd is None:
            n = 6 * self.Nv * 3 * self.P
            base = ((self.entry_cam[:, None, None] * 6 + np.arange(6)[:, None]) * self.P
                    + self.entry_pt[:, None, None]) * 3 + np.arange(3)
            self._zd_index = base.astype(np.int32 if n < 2**31 else np.int64).reshape(-1)
            self._zd = np.zeros((self.Nv, 6, self.P, 3))
        self._zd.reshape(-1)[self._zd_index] = Z.reshape(-1)
        return self._zd

    def _panel_system(self, U_blocks, W, Li, q, b, diag_c, fused: bool) -> np.ndarray:
        """Dense S (upper triangle) with the point products by window GEMMs; b (Nv, 6) gets
        the points' share in place."""
        from polarref.ba import kernels, schur_panel_jit
        Nv = self.Nv
        S = np.zeros((Nv, 6, Nv, 6))
        S[self.u_ca, :, self.u_cb, :] = U_blocks
        S = S.reshape(6 * Nv, 6 * Nv)
        Z = np.empty((self.E, 6, 3))
        schur_panel_jit.entry_factors(_c(W), Li, q, self.entry_bounds, self.entry_pt,
                                      self.entry_cam, Z, b)
        schur_panel.subtract_products(S, self.panel, Z, self.entry_cam)
        if fused:
            kernels.add_cross(S, *self._cross(), self.entry_bounds, self.entry_pt,
                              self.entry_cam, self.slot_entry, self.obs_bounds)
            self._zero_held(S)
        S[np.diag_indices_from(S)] += diag_c.reshape(-1)
        return S

    def _blocks(self, U_blocks, W, Li, q, b, diag_c, fused: bool = False) -> np.ndarray:
        """(K, 6, 6): U, the entry-pair Schur products (with ``fused``, the three-slot cross
        blocks too) and the damping in the blocks of the pattern (:meth:`_build_blocks`); b
        (Nv, 6) gets the points' share in place."""
        from polarref.ba import kernels, schur_sparse_jit
        blocks = self.blocks_with_u(U_blocks)
        if self.E and fused:
            X, h, Xma = self._cross()
            schur_sparse_jit.schur_blocks_cross(_c(W), Li, q, self.entry_bounds, self.entry_pt,
                                                self.entry_cam, self.pair_blk, blocks, b, X, h,
                                                Xma, self.slot_entry, self.obs_bounds)
        elif self.E:
            kernels.schur_blocks(_c(W), Li, q, self.entry_bounds, self.entry_pt, self.pair_blk,
                                 blocks, b, self.entry_cam)
        if fused:
            self.zero_held_blocks(blocks)
        self.add_diagonal_blocks(blocks, diag_c)
        return blocks

    def blocks_with_u(self, U_blocks) -> np.ndarray:
        """Block-sparse S's (K, 6, 6) blocks holding U's upper blocks, the rest zero."""
        blocks = np.zeros((self.K, 6, 6))
        blocks[self.u_blk] = U_blocks[self.u_up]
        return blocks

    def add_diagonal_blocks(self, blocks: np.ndarray, diag_c: np.ndarray) -> None:
        """The camera damping diag_c (Nv, 6) onto the diagonal blocks, in place."""
        i6 = np.arange(6)
        blocks[self.diag_blk[:, None], i6, i6] += diag_c

    def zero_held_blocks(self, blocks: np.ndarray) -> None:
        """:meth:`_zero_held` for the blocks of a block-sparse S."""
        from polarref.ba import schur_sparse_jit
        mask_v = getattr(self, "mask_v", None)
        if mask_v is not None and not (mask_v > 0).all():
            schur_sparse_jit.zero_held_blocks(blocks, self.blk_ca, self.blk_cb, _c(mask_v))

    def bsr(self, blocks: np.ndarray):
        """The symmetric BSR matrix (6 Nv, 6 Nv) of the upper blocks (their transposes below)."""
        data = np.concatenate([blocks, blocks[self.blk_off].transpose(0, 2, 1)])[self.bsr_order]
        return scipy.sparse.bsr_matrix((data, self.bsr_indices, self.bsr_indptr),
                                       shape=(6 * self.Nv, 6 * self.Nv))

    def _cross(self):
        """The fused build's compact cross terms (X [N | t], h, Xma) as schur_dense takes them."""
        X, Xma = self.cross_blocks
        return X, self.cross_h, Xma

    def _zero_held(self, S: np.ndarray) -> None:
        """Fused path: the held gauge columns (apply_mask's mask_v) of the cross blocks added
        straight into S (U and W are masked in apply_mask)."""
        mask_v = getattr(self, "mask_v", None)
        if mask_v is not None:
            held = np.flatnonzero(mask_v.reshape(-1) == 0)
            S[held, :] = 0.0
            S[:, held] = 0.0

    def _pair_blocks(self, Z: np.ndarray) -> np.ndarray:
        """Z Z^T blocks (segments, 6, 6) of the camera pairs (seg_ca <= seg_cb)."""
        Zt = np.ascontiguousarray(Z.transpose(1, 0, 2)).reshape(6, -1)  # (6, 3E)
        out = np.empty((len(self.seg_bounds), 6, 6))
        for g0, g1 in self.seg_chunks:
            p0, p1 = int(self.seg_starts[g0]), int(self.seg_ends[g1 - 1])
            # column gathers (np.take on the last axis is 8x faster than fancy-indexing (6, E, 3));
            # one GEMM per camera pair: batching padded segments was slower (2x gather volume)
            Ga = np.take(Zt, (3 * self.pair_a[p0:p1, None] + np.arange(3)).ravel(), axis=1)
            Gb = np.take(Zt, (3 * self.pair_b[p0:p1, None] + np.arange(3)).ravel(), axis=1)
            c0 = 3 * p0
            for i in range(g0, g1):
                s0, s1 = self.seg_bounds[i]
                out[i] = Ga[:, s0 - c0:s1 - c0] @ Gb[:, s0 - c0:s1 - c0].T
        return out

    def _sparse_system(self, U_blocks, Z, diag_c):
        Nv = self.Nv
        red = -self._pair_blocks(Z) if self.E else np.zeros((0, 6, 6))
        off = self.seg_ca != self.seg_cb
        D = np.zeros((Nv, 6, 6))
        D[:, np.arange(6), np.arange(6)] = diag_c
        ca = np.r_[self.u_ca, self.seg_ca, self.seg_cb[off], np.arange(Nv)]
        cb = np.r_[self.u_cb, self.seg_cb, self.seg_ca[off], np.arange(Nv)]
        blocks = np.concatenate([U_blocks, red, red[off].transpose(0, 2, 1), D])
        ii = (6 * ca[:, None, None] + np.arange(6)[None, :, None]).repeat(6, 2)
        jj = (6 * cb[:, None, None] + np.arange(6)[None, None, :]).repeat(6, 1)
        return scipy.sparse.coo_matrix((blocks.ravel(), (ii.ravel(), jj.ravel())),
                                       shape=(6 * Nv, 6 * Nv)).tocsc()

    def solve(self, S, b) -> np.ndarray | None:
        """Solve S x = b; None when S is not positive definite (the LM step is then rejected)."""
        if self.reduced_solver is ReducedSolver.PCG:
            res = pcg(S, b, *self.pcg_settings)
            self.pcg_iterations.append(res.iterations)
            return res.x if res.x is not None and np.isfinite(res.x).all() else None
        if self.sparse_S:
            try:
                x = scipy.sparse.linalg.splu(S.tocsc()).solve(b)
            except RuntimeError:
                return None
            return x if np.isfinite(x).all() else None
        try:
            # S is C-ordered; its transpose is the column-major matrix whose lower triangle
            # holds the reduced system (see reduced_system), so no copy is made.
            c = scipy.linalg.cho_factor(S.T, lower=True, overwrite_a=True, check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            return None
        x = scipy.linalg.cho_solve(c, b, check_finite=False)
        return x if np.isfinite(x).all() else None

    def back_substitute(self, W, Li, g_p, dc: np.ndarray) -> np.ndarray:
        """Point steps dp = V^-1 (-g_p - sum_e W_e^T dc_cam(e)) -> (P, 3)."""
        rhs = -g_p
        if self.fast:
            from polarref.ba import kernels
            if self.E:
                kernels.back_substitute_rhs(_c(W), _c(dc), self.entry_pt, self.entry_cam, rhs)
            kernels.point_solve(rhs, _c(Li))
            return rhs
        if self.E:
            wtd = np.matmul(W.transpose(0, 2, 1), dc[self.entry_cam][:, :, None])[:, :, 0]
            rhs[self.pts_with_entries] -= np.add.reduceat(wtd, self.entry_pt_starts, axis=0)
        y = np.matmul(Li, rhs[:, :, None])
        return np.matmul(Li.transpose(0, 2, 1), y)[:, :, 0]
