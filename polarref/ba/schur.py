"""Index structures and the reduced camera system (Schur complement over point blocks).

Everything here is built once per problem; per iteration only dense arithmetic, gathers and
``np.add.reduceat`` over precomputed sorted orders run (no ``np.add.at``, no Python loops
over observations). Terms:

* an *entry* is a distinct (variable camera, point) pair with a Jacobian coupling: the
  observing camera, and for parallax landmarks also the two anchor cameras;
* ``U`` (6x6 camera blocks), ``V`` (3x3 point blocks), ``W`` (6x3 per entry);
* ``S = U - W V^-1 W^T`` is formed either by one dense GEMM (dense visibility: every point in
  most images) or by summing 6x6 products over entry pairs that share a point (sparse
  visibility), whichever a flop estimate says is cheaper.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

# Relative cost of one entry pair (gather + 6x6x3 product + reduction) vs one dense GEMM flop,
# measured on this machine (2 cores): ~100 ns per pair, ~0.1 ns per GEMM flop.
_PAIR_S = 1.0e-7
_FLOP_S = 1.0e-10


def _group_starts(sorted_keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starts of runs of equal values in a sorted array, and the run values."""
    if len(sorted_keys) == 0:
        return np.zeros(0, np.int64), sorted_keys
    starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]])
    return starts, sorted_keys[starts]


class SchurStructure:
    """Precomputed index structure for one problem and one parameterization.

    Args:
        slot_cams: (S, M) camera index of each of the S camera slots of each observation.
        obs_pt: (M,) point index, sorted ascending, every point present.
        cam_var: (N,) True for cameras with at least one free parameter.
        dense_max_cameras: above this many variable cameras S is sparse.
    """

    def __init__(self, slot_cams: np.ndarray, obs_pt: np.ndarray, cam_var: np.ndarray,
                 num_points: int, dense_max_cameras: int = 700):
        S, M = slot_cams.shape
        N = len(cam_var)
        P = num_points
        self.S, self.M, self.N, self.P = S, M, N, P
        self.var_index = -np.ones(N, np.int64)
        self.var_cams = np.flatnonzero(cam_var)
        self.var_index[self.var_cams] = np.arange(len(self.var_cams))
        self.Nv = Nv = len(self.var_cams)
        self.pt_starts, _ = _group_starts(obs_pt)
        if len(self.pt_starts) != P:
            raise ValueError("SchurStructure: every point needs >= 1 observation, sorted by point")
        # -- entries: distinct (point, variable camera), sorted by point then camera -----------
        flat_cam = slot_cams.reshape(-1)
        flat_pt = np.tile(obs_pt, S)
        vc = self.var_index[flat_cam]
        valid = vc >= 0
        key = flat_pt * Nv + np.where(valid, vc, 0)
        self.slot_valid = valid.reshape(S, M)
        vidx = np.flatnonzero(valid)
        order = vidx[np.argsort(key[vidx], kind="stable")]
        starts, ukeys = _group_starts(key[order])
        self.E = len(ukeys)
        self.entry_pt = ukeys // max(Nv, 1)
        self.entry_cam = ukeys % max(Nv, 1)  # variable-camera index
        # Fast path: one slot and no duplicate entry -> entries are the valid observations.
        self.identity = S == 1 and self.E == len(vidx)
        self.w_order, self.w_starts = order, starts
        if self.E:
            self.entry_pt_starts, pts_with = _group_starts(self.entry_pt)
        else:
            self.entry_pt_starts, pts_with = np.zeros(0, np.int64), np.zeros(0, np.int64)
        self.pts_with_entries = pts_with
        # -- U: camera-camera blocks from slot pairs of the same observation ---------------------
        pairs, keys, sel = [], [], []
        for a in range(S):
            for b in range(S):
                ok = self.slot_valid[a] & self.slot_valid[b]
                idx = np.flatnonzero(ok)
                pairs.append((a, b, idx))
                keys.append(self.var_index[slot_cams[a, idx]] * Nv + self.var_index[slot_cams[b, idx]])
        self.u_pairs = pairs
        allkeys = np.concatenate(keys) if keys else np.zeros(0, np.int64)
        self.u_order = np.argsort(allkeys, kind="stable")
        self.u_starts, uk = _group_starts(allkeys[self.u_order])
        self.u_ca, self.u_cb = uk // max(Nv, 1), uk % max(Nv, 1)
        # -- choose how to form W V^-1 W^T -----------------------------------------------------
        counts = np.diff(np.r_[self.entry_pt_starts, self.E])
        self.num_pairs = int((counts.astype(np.float64) ** 2).sum())
        dense_cost = 2.0 * (6 * Nv) ** 2 * 3 * len(counts) * _FLOP_S
        self.sparse_S = Nv > dense_max_cameras
        self.use_gemm = (not self.sparse_S) and dense_cost < self.num_pairs * _PAIR_S
        if not self.use_gemm:
            self._build_pairs(counts)

    def _build_pairs(self, counts: np.ndarray) -> None:
        """All ordered entry pairs (ea, eb) sharing a point, grouped by target camera block."""
        E = self.E
        reps = np.repeat(counts, counts)  # for every entry: size of its point's group
        ea = np.repeat(np.arange(E), reps)
        first = np.repeat(self.entry_pt_starts, counts)  # for every entry: its group's start
        off = np.arange(len(ea)) - np.repeat(np.cumsum(reps) - reps, reps)
        eb = np.repeat(first, reps) + off
        Nv = self.Nv
        key = self.entry_cam[ea] * Nv + self.entry_cam[eb]
        order = np.argsort(key, kind="stable")
        self.pair_a, self.pair_b = ea[order], eb[order]
        self.pair_starts, pk = _group_starts(key[order])
        self.pair_ca, self.pair_cb = pk // Nv, pk % Nv

    # ------------------------------------------------------------------------------------------
    def linear_solver_name(self) -> str:
        how = "dense GEMM" if self.use_gemm else "entry pairs"
        return f"Schur ({how}) + {'sparse LU' if self.sparse_S else 'dense Cholesky'}"

    def reduce_points(self, per_obs: np.ndarray) -> np.ndarray:
        """Sum per-observation arrays (M, ...) over each point -> (P, ...)."""
        return np.add.reduceat(per_obs, self.pt_starts, axis=0)

    def entries_W(self, Jc: list[np.ndarray], Jp: np.ndarray) -> np.ndarray:
        """W blocks (E, 6, 3) = sum of Jc^T Jp over the observations/slots of each entry."""
        JpT = Jp
        if self.identity:
            idx = self.w_order
            return np.matmul(Jc[0][idx].transpose(0, 2, 1), JpT[idx])
        blocks = np.concatenate([np.matmul(J.transpose(0, 2, 1), JpT) for J in Jc])
        return np.add.reduceat(blocks[self.w_order], self.w_starts, axis=0)

    def camera_U(self, Jc: list[np.ndarray]) -> np.ndarray:
        """Unique U blocks (B, 6, 6) at (u_ca, u_cb)."""
        blocks = np.concatenate([np.matmul(Jc[a][idx].transpose(0, 2, 1), Jc[b][idx])
                                 for a, b, idx in self.u_pairs])
        return np.add.reduceat(blocks[self.u_order], self.u_starts, axis=0)

    def camera_vector(self, Jc: list[np.ndarray], r: np.ndarray) -> np.ndarray:
        """Sum of Jc^T r per variable camera -> (Nv, 6)."""
        out = np.zeros((self.Nv, 6))
        for s, J in enumerate(Jc):
            ok = self.slot_valid[s]
            g = np.einsum("mki,mk->mi", J[ok], r[ok])
            # bincount per column: the camera count is small, so 6 passes are cheap
            cams = self._slot_var_cams[s]
            for i in range(6):
                out[:, i] += np.bincount(cams, g[:, i], minlength=self.Nv)
        return out

    def set_slot_cams(self, slot_cams: np.ndarray) -> None:
        self._slot_var_cams = [self.var_index[slot_cams[s, self.slot_valid[s]]]
                               for s in range(self.S)]

    def reduced_system(self, U_blocks, W, Vinv, g_c, g_p, diag_c):
        """Assemble S (dense (6Nv, 6Nv) or sparse) and b = -g_c + W V^-1 g_p.

        Returns (S, b, Y) with Y = W V^-1 per entry (E, 6, 3), reused for back-substitution.
        """
        Nv, E = self.Nv, self.E
        Y = np.matmul(W, Vinv[self.entry_pt]) if E else np.zeros((0, 6, 3))
        b = -g_c.copy()
        if E:
            yg = np.matmul(Y, g_p[self.entry_pt][:, :, None])[:, :, 0]
            for i in range(6):
                b[:, i] += np.bincount(self.entry_cam, yg[:, i], minlength=Nv)
        if self.sparse_S:
            return self._sparse_system(U_blocks, W, Y, diag_c), b.reshape(-1), Y
        S = np.zeros((Nv, 6, Nv, 6))
        S[self.u_ca, :, self.u_cb, :] = U_blocks
        if E and self.use_gemm:
            P = self.P
            Yd = np.zeros((Nv, 6, P, 3))
            Wd = np.zeros((Nv, 6, P, 3))
            Yd[self.entry_cam, :, self.entry_pt, :] = Y
            Wd[self.entry_cam, :, self.entry_pt, :] = W
            S = S.reshape(6 * Nv, 6 * Nv)
            # S -= Yd Wd^T as one BLAS call (dgemm with beta = 1 through scipy)
            S = scipy.linalg.blas.dgemm(-1.0, Yd.reshape(6 * Nv, -1), Wd.reshape(6 * Nv, -1),
                                        beta=1.0, c=S, trans_b=True, overwrite_c=True)
        elif E:
            blocks = np.matmul(Y[self.pair_a], W[self.pair_b].transpose(0, 2, 1))
            red = np.add.reduceat(blocks, self.pair_starts, axis=0)
            S[self.pair_ca, :, self.pair_cb, :] -= red
            S = S.reshape(6 * Nv, 6 * Nv)
        else:
            S = S.reshape(6 * Nv, 6 * Nv)
        S[np.diag_indices_from(S)] += diag_c.reshape(-1)
        return S, b.reshape(-1), Y

    def _sparse_system(self, U_blocks, W, Y, diag_c):
        Nv = self.Nv
        red = -np.add.reduceat(np.matmul(Y[self.pair_a], W[self.pair_b].transpose(0, 2, 1)),
                               self.pair_starts, axis=0)
        ca = np.r_[self.u_ca, self.pair_ca, np.arange(Nv)]
        cb = np.r_[self.u_cb, self.pair_cb, np.arange(Nv)]
        D = np.zeros((Nv, 6, 6))
        D[:, np.arange(6), np.arange(6)] = diag_c
        blocks = np.concatenate([U_blocks, red, D])
        ii = (6 * ca[:, None, None] + np.arange(6)[None, :, None]).repeat(6, 2)
        jj = (6 * cb[:, None, None] + np.arange(6)[None, None, :]).repeat(6, 1)
        return scipy.sparse.coo_matrix((blocks.ravel(), (ii.ravel(), jj.ravel())),
                                       shape=(6 * Nv, 6 * Nv)).tocsc()

    def solve(self, S, b) -> np.ndarray | None:
        """Solve S x = b; None when S is not positive definite (the LM step is then rejected)."""
        if self.sparse_S:
            try:
                x = scipy.sparse.linalg.splu(S).solve(b)
            except RuntimeError:
                return None
            return x if np.isfinite(x).all() else None
        try:
            c = scipy.linalg.cho_factor(S, lower=True, overwrite_a=True, check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            return None
        x = scipy.linalg.cho_solve(c, b, check_finite=False)
        return x if np.isfinite(x).all() else None

    def back_substitute(self, W, Vinv, g_p, dc: np.ndarray) -> np.ndarray:
        """Point steps dp = V^-1 (-g_p - sum_e W_e^T dc_cam(e)) -> (P, 3)."""
        rhs = -g_p.copy()
        if self.E:
            wtd = np.matmul(W.transpose(0, 2, 1), dc[self.entry_cam][:, :, None])[:, :, 0]
            rhs[self.pts_with_entries] -= np.add.reduceat(wtd, self.entry_pt_starts, axis=0)
        return np.matmul(Vinv, rhs[:, :, None])[:, :, 0]
