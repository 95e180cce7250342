"""Flops of one LM iteration of our Schur path, counted from the problem's structure, and the
machine's dense GEMM rate measured in the same process (the roofline of issue 35).

Counts are for the Euclidean form's structure (one camera slot per observation); the
three-slot forms add anchor slots and are not counted here. Per observation in a variable
camera (2 residual rows): the normal-equation blocks U (6x6), W (6x3), V (3x3) and the
gradients take 2 * 2 * (36 + 18 + 9 + 9) = 288 flops; the Schur complement takes, per entry,
``W V^-1`` (6x3 times 3x3: 108) and its share of the right-hand side (36), and per pair of
entries of one point (both triangles' worth counted once, diagonal included, L (L + 1) / 2
pairs for a track of L variable cameras) one 6x3 by 3x6 product (216). Dense Cholesky of the
reduced system of n = 6 Nv unknowns: n^3 / 3, plus 2 n^2 for the two triangular solves. The
sparse LU and PCG paths are not counted (their flops depend on fill-in / CG iterations).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

BUILD_PER_OBS = 288
SCHUR_PER_ENTRY = 108 + 36
SCHUR_PER_PAIR = 216


@dataclass(frozen=True)
class IterationFlops:
    """Flops of one LM step (see module docstring); factorisation None unless dense Cholesky."""

    build: float          # normal equations (once per accepted step)
    schur: float          # Schur complement (every step, accepted or rejected)
    factorisation: float | None
    num_unknowns: int     # 6 * variable cameras


def lm_flops(obs_cam: np.ndarray, obs_pt: np.ndarray, cam_var: np.ndarray, num_points: int,
             dense: bool) -> IterationFlops:
    """Flops from the observations' cameras (M,), points (M,) and the variable cameras (N,)."""
    keep = cam_var[obs_cam]
    L = np.bincount(obs_pt[keep], minlength=num_points).astype(np.float64)
    M = float(keep.sum())
    n = 6 * int(cam_var.sum())
    pairs = float((L * (L + 1) / 2).sum())
    fact = n**3 / 3.0 + 2.0 * n**2 if dense else None
    return IterationFlops(BUILD_PER_OBS * M, SCHUR_PER_ENTRY * M + SCHUR_PER_PAIR * pairs, fact, n)


def gemm_gflops(threads: int, n: int = 1500, repeats: int = 3, seed: int = 0) -> float:
    """Best-of-``repeats`` GFLOP/s of numpy's float64 (n x n) @ (n x n) with ``threads`` BLAS
    threads (threadpoolctl): the machine's dense rate, measured beside the solves."""
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(seed)
    a, b = rng.standard_normal((n, n)), rng.standard_normal((n, n))
    best = float("inf")
    with threadpool_limits(limits=threads, user_api="blas"):
        a @ b  # first call: thread start-up, page faults of the output
        for _ in range(repeats):
            t = time.perf_counter()
            a @ b
            best = min(best, time.perf_counter() - t)
    return 2.0 * n**3 / best / 1e9
