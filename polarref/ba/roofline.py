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

Bytes of the block-sparse Schur kernel (``kernels_jit.schur_blocks``) per LM step, float64 and
int64 at 8 bytes, in two models that bracket its memory traffic:

* compulsory: every array it touches, once. Per entry W_e (6x3: 144) and its camera (8); per
  point L^-1 (72), L^-1 g (24), its entry range (8) and point index (8); per entry pair its
  block index (8); per camera-pair block one read and one write (2 x 288); the right-hand
  side (Nv x 6) read and written once (96 per camera).
* per update: as compulsory, but each entry pair reads and writes its 6x6 block (576) and each
  entry its right-hand-side row (96) from memory, as when the blocks do not stay in cache
  between the points that update them.

The arithmetic intensity is the Schur flops over these bytes; the bandwidth roof is
``min(GEMM rate, intensity x bandwidth)`` with the bandwidth of a STREAM triad measured in the
same run (``a = b + s c``, 24 bytes per element: two reads and one write, STREAM's count).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from polarref.ba import kernels

BUILD_PER_OBS = 288
SCHUR_PER_ENTRY = 108 + 36
SCHUR_PER_PAIR = 216
WORD = 8
ENTRY_BYTES = (18 + 1) * WORD           # W_e and its camera
POINT_BYTES = (9 + 3 + 1 + 1) * WORD    # L^-1, L^-1 g, entry range, point index
PAIR_INDEX_BYTES = WORD                 # the entry pair's block index
BLOCK_RW_BYTES = 2 * 36 * WORD          # one 6x6 block read and written
RHS_RW_BYTES = 2 * 6 * WORD             # one camera's right-hand-side row read and written
TRIAD_BYTES = 3 * WORD                  # per element of a = b + s c


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


@dataclass(frozen=True)
class SchurTraffic:
    """Flops and bytes of the block-sparse Schur kernel per LM step (module docstring)."""

    flops: float
    compulsory_bytes: float
    per_update_bytes: float
    entries: int          # (point, variable camera) pairs
    points: int           # points with an entry
    pairs: int            # entry pairs a <= b of one point
    blocks: int           # distinct camera-pair blocks of S (ca <= cb)
    cameras: int          # variable cameras

    def intensity(self, per_update: bool) -> float:
        """Flops per byte in one of the two traffic models."""
        return self.flops / (self.per_update_bytes if per_update else self.compulsory_bytes)


def _entries(obs_cam: np.ndarray, obs_pt: np.ndarray, cam_var: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct (point, camera) entries in variable cameras, sorted by point then camera."""
    keep = cam_var[obs_cam]
    n = np.int64(len(cam_var))
    key = np.unique(obs_pt[keep].astype(np.int64) * n + obs_cam[keep])
    return key // n, key % n


def camera_pair_blocks(pt: np.ndarray, cam: np.ndarray, num_cameras: int) -> tuple[int, int]:
    """(entry pairs, distinct camera-pair blocks) of entries sorted by point then camera: the
    pairs (a, a + d) within one point for every offset d, keyed by their two cameras."""
    pairs, keys, d = len(pt), [cam.astype(np.int64) * (num_cameras + 1)], 1   # the diagonal blocks
    while d < len(pt):
        same = pt[d:] == pt[:-d]
        if not same.any():
            break
        pairs += int(same.sum())
        keys.append(cam[:-d][same].astype(np.int64) * num_cameras + cam[d:][same])
        d += 1
    return pairs, len(np.unique(np.concatenate(keys)))


def schur_traffic(obs_cam: np.ndarray, obs_pt: np.ndarray, cam_var: np.ndarray) -> SchurTraffic:
    """The kernel's flops and bytes per LM step in both models, from the observations."""
    pt, cam = _entries(obs_cam, obs_pt, cam_var)
    pairs, blocks = camera_pair_blocks(pt, cam, len(cam_var))
    E, P, Nv = len(pt), len(np.unique(pt)), int(cam_var.sum())
    flops = float(SCHUR_PER_ENTRY * E + SCHUR_PER_PAIR * pairs)
    shared = float(ENTRY_BYTES * E + POINT_BYTES * P + PAIR_INDEX_BYTES * pairs)
    return SchurTraffic(flops, shared + BLOCK_RW_BYTES * blocks + RHS_RW_BYTES * Nv,
                        shared + BLOCK_RW_BYTES * pairs + RHS_RW_BYTES * E, E, P, pairs, blocks, Nv)


def roof(intensity: float, bandwidth_gbs: float, peak_gflops: float) -> float:
    """The roofline's attainable GFLOP/s: min(peak, intensity x bandwidth)."""
    return min(peak_gflops, intensity * bandwidth_gbs)


def triad_gbs(n: int = 1 << 24, repeats: int = 5, clock=time.perf_counter) -> float | None:
    """Best-of-``repeats`` GB/s of a one-thread STREAM triad ``a = b + s c`` over ``n`` float64
    (3 x 128 MiB by default, far beyond any cache), counted as TRIAD_BYTES per element, timed
    by ``clock``; None without the compiled kernels (numpy's triad makes a temporary)."""
    if not kernels.available():
        return None
    a, b, c = np.zeros(n), np.ones(n), np.full(n, 2.0)
    kernels.triad(a, b, c, 3.0)  # compile/load, and the output's page faults
    best = float("inf")
    for _ in range(repeats):
        t = clock()
        kernels.triad(a, b, c, 3.0)
        best = min(best, clock() - t)
    return TRIAD_BYTES * n / best / 1e9


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
