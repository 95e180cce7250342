"""Solvers of the reduced camera system ``S x = b`` (S: (6 Nv, 6 Nv), symmetric positive
definite once damped), chosen by size.

* dense Cholesky (LAPACK via scipy) while the dense S fits: Nv <= ``dense_max_cameras``;
* sparse LU (SuperLU, ``scipy.sparse.linalg.splu``) above that, on the block-sparse S
  (kernel path: the camera-pair 6x6 blocks of its fixed pattern, laid out as BSR once,
  schur.py ``_build_blocks``);
* preconditioned conjugate gradients with a 6x6 block-Jacobi preconditioner (our own, ~40
  lines) above ``pcg_min_cameras``: memory is S's nonzeros plus five vectors, with no fill-in.
  Our own rather than ``scipy.sparse.linalg.cg`` because a dense S holds only one valid
  triangle (the one the Cholesky reads; BLAS ``dsymv`` multiplies with it directly) and we
  want the iteration count back. No sparse Cholesky (CHOLMOD) is installed: scikit-sparse
  would be a new compiled dependency, and SuperLU already covers the mid range.

PCG with a tight relative tolerance (1e-12) gives the Cholesky step to rounding (tests); the
default 1e-8 keeps it within the model's own accuracy. Ceres' ITERATIVE_SCHUR runs inexact
steps (eta = 0.1) instead.
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse

log = logging.getLogger(__name__)


class ReducedSolver(enum.StrEnum):
    """How ``S x = b`` is solved (``BAOptions.reduced_solver``; AUTO picks by size)."""

    AUTO = "auto"
    DENSE_CHOLESKY = "dense-cholesky"
    SPARSE_LU = "sparse-lu"
    PCG = "pcg"


@dataclass(frozen=True)
class PCGResult:
    """x (n,) or None (S not positive definite), iterations, final relative residual
    ``|b - S x| / |b|`` (above the tolerance when the iteration limit stopped it: the
    inexact step is still returned; LM's gain ratio judges it)."""

    x: np.ndarray | None
    iterations: int
    relative_residual: float


def choose(requested: str, num_var_cameras: int, dense_max_cameras: int,
           pcg_min_cameras: int) -> ReducedSolver:
    """The solver for ``requested`` (a ReducedSolver value) at this many variable cameras."""
    req = ReducedSolver(requested)
    if req is not ReducedSolver.AUTO:
        return req
    if num_var_cameras <= dense_max_cameras:
        return ReducedSolver.DENSE_CHOLESKY
    return ReducedSolver.PCG if num_var_cameras >= pcg_min_cameras else ReducedSolver.SPARSE_LU


def _operator(S):
    """x -> S x for a sparse S (both triangles) or a C-ordered dense S whose upper triangle
    holds the system (= the lower triangle of the column-major ``S.T`` the Cholesky reads)."""
    if scipy.sparse.issparse(S):
        return lambda x: S @ x
    St = S.T
    return lambda x: scipy.linalg.blas.dsymv(1.0, St, x, lower=1)


def diagonal_blocks(S) -> np.ndarray:
    """The 6x6 diagonal blocks (Nv, 6, 6) of S, symmetric (from the valid triangle if dense)."""
    n = S.shape[0] // 6
    if scipy.sparse.issparse(S):
        bs = scipy.sparse.bsr_matrix(S, blocksize=(6, 6))
        out = np.zeros((n, 6, 6))
        rows = np.repeat(np.arange(n), np.diff(bs.indptr))
        on = bs.indices == rows
        out[rows[on]] = bs.data[on]
        return out
    D = S.reshape(n, 6, n, 6)[np.arange(n), :, np.arange(n), :]
    upper = np.triu(D)
    return upper + np.swapaxes(np.triu(D, 1), 1, 2)


def pcg(S, b: np.ndarray, rtol: float, max_iterations: int) -> PCGResult:
    """Conjugate gradients on ``S x = b`` preconditioned by S's inverted 6x6 diagonal blocks.

    Returns x = None when a diagonal block or a search direction shows S is not positive
    definite (the LM step is then rejected, as for a failed Cholesky).
    """
    mul = _operator(S)
    try:
        Minv = np.linalg.inv(np.linalg.cholesky(diagonal_blocks(S)))
    except np.linalg.LinAlgError:
        return PCGResult(None, 0, float("inf"))
    Minv = np.matmul(np.swapaxes(Minv, 1, 2), Minv)  # (L L^T)^-1 = L^-T L^-1

    def precond(r: np.ndarray) -> np.ndarray:
        return np.matmul(Minv, r.reshape(-1, 6, 1)).reshape(-1)

    bnorm = float(np.linalg.norm(b))
    x = np.zeros_like(b)
    if bnorm == 0.0:
        return PCGResult(x, 0, 0.0)
    r = b.copy()
    z = precond(r)
    p = z.copy()
    rz = float(r @ z)
    for k in range(1, max_iterations + 1):
        q = mul(p)
        pq = float(p @ q)
        if not pq > 0.0:
            return PCGResult(None, k, float("inf"))
        alpha = rz / pq
        x += alpha * p
        r -= alpha * q
        res = float(np.linalg.norm(r)) / bnorm
        if res <= rtol:
            return PCGResult(x, k, res)
        z = precond(r)
        rz, rz_old = float(r @ z), rz
        p *= rz / rz_old
        p += z
    log.debug("PCG stopped at %d iterations, relative residual %.3g", max_iterations, res)
    return PCGResult(x, max_iterations, res)
