"""Triangulation: MOCI two-view midpoint (ATBD 5.3), MOCI N-view least squares (ATBD 6.2), DLT.

All functions are vectorized over points. Rays are given in world coordinates as a centre
``C`` and a direction ``v`` (any length unless stated). Degenerate geometry is flagged per point
(``parallel``, ``behind``) rather than raised, because a batch always holds a few; pass
``strict=True`` to raise :class:`DegenerateTriangulation` instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.core.errors import PolarrefError

PARALLEL_SIN = 1e-9  # |v0 x v1| / (|v0| |v1|) below this: rays treated as parallel


class DegenerateTriangulation(PolarrefError):
    """Parallel rays or a point behind a camera when ``strict=True``."""


@dataclass
class Triangulated:
    """Batch result.

    Attributes:
        X: (N, 3) points (NaN where parallel).
        parallel: (N,) rays (nearly) parallel: no unique solution.
        behind: (N,) the point lies behind at least one camera (ray parameter <= 0).
    """

    X: np.ndarray
    parallel: np.ndarray
    behind: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        return ~(self.parallel | self.behind)


def _check(res: Triangulated, strict: bool, what: str) -> Triangulated:
    if strict and not res.valid.all():
        n_par, n_beh = int(res.parallel.sum()), int((res.behind & ~res.parallel).sum())
        raise DegenerateTriangulation(f"{what}: {n_par} point(s) with parallel rays, "
                                      f"{n_beh} point(s) behind a camera")
    return res


def midpoint_two_view(C0: np.ndarray, v0: np.ndarray, C1: np.ndarray, v1: np.ndarray,
                      strict: bool = False) -> Triangulated:
    """Midpoint of the common perpendicular of two skew rays, exactly as MOCI ATBD section 5.3.

    With ``c = v0 x v1``, ``n0 = v1 x c`` and ``n1 = v0 x (v1 x v0)``:
    ``s0 = C0 + ((C1 - C0).n0 / (v0.n0)) v0``, ``s1 = C1 + ((C0 - C1).n1 / (v1.n1)) v1``,
    ``m = (s0 + s1) / 2``. The ray parameters must be positive (point in front of both).

    Args:
        C0, C1: (N, 3) ray origins (camera centres); v0, v1: (N, 3) directions.
    """
    C0, v0, C1, v1 = (np.asarray(a, dtype=np.float64).reshape(-1, 3) for a in (C0, v0, C1, v1))
    c = np.cross(v0, v1)
    n0 = np.cross(v1, c)
    n1 = np.cross(v0, np.cross(v1, v0))
    sin = np.linalg.norm(c, axis=1) / np.maximum(np.linalg.norm(v0, axis=1) * np.linalg.norm(v1, axis=1), 1e-300)
    parallel = sin < PARALLEL_SIN
    den0 = np.where(parallel, 1.0, np.einsum("ij,ij->i", v0, n0))
    den1 = np.where(parallel, 1.0, np.einsum("ij,ij->i", v1, n1))
    t0 = np.einsum("ij,ij->i", C1 - C0, n0) / den0
    t1 = np.einsum("ij,ij->i", C0 - C1, n1) / den1
    s0 = C0 + t0[:, None] * v0
    s1 = C1 + t1[:, None] * v1
    X = 0.5 * (s0 + s1)
    X[parallel] = np.nan
    behind = ~parallel & ((t0 <= 0) | (t1 <= 0))
    return _check(Triangulated(X, parallel, behind), strict, "two-view midpoint")


def nview_least_squares(C: np.ndarray, d: np.ndarray, group: np.ndarray, num_groups: int,
                        strict: bool = False, min_eig: float = 1e-12) -> Triangulated:
    """MOCI N-view "3 by 3" least squares (ATBD 6.2), one 3x3 system per point.

    Solves ``sum_i (I - d_i d_i^T) X = sum_i (I - d_i d_i^T) C_i``: the point minimizing the sum
    of squared perpendicular distances to the rays.

    Args:
        C: (O, 3) ray origins; d: (O, 3) directions (normalized here).
        group: (O,) int point index of each ray, in [0, num_groups).
        min_eig: the smallest eigenvalue of the 3x3 matrix, divided by the number of rays, below
            which the rays are flagged parallel (it equals sin^2 of the angular spread, roughly).
    """
    C = np.asarray(C, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    group = np.asarray(group, dtype=np.int64)
    P = np.eye(3) - d[:, :, None] * d[:, None, :]  # (O, 3, 3) projector orthogonal to each ray
    A = np.zeros((num_groups, 3, 3))
    b = np.zeros((num_groups, 3))
    np.add.at(A, group, P)
    np.add.at(b, group, np.einsum("oij,oj->oi", P, C))
    count = np.bincount(group, minlength=num_groups).astype(np.float64)
    eig_min = np.linalg.eigvalsh(A)[:, 0] / np.maximum(count, 1.0)
    parallel = (count < 2) | (eig_min < min_eig)
    A_safe = np.where(parallel[:, None, None], np.eye(3), A)
    X = np.linalg.solve(A_safe, b[:, :, None])[:, :, 0]
    X[parallel] = np.nan
    depth = np.einsum("ij,ij->i", X[group] - C, d)
    behind_obs = ~(depth > 0) & ~parallel[group]
    behind = np.bincount(group, weights=behind_obs, minlength=num_groups) > 0
    return _check(Triangulated(X, parallel, behind), strict, "N-view least squares")


def dlt(cam_from_world: np.ndarray, xy: np.ndarray, group: np.ndarray, num_groups: int,
        strict: bool = False) -> Triangulated:
    """Linear (DLT) triangulation from normalized image coordinates (Hartley & Zisserman 12.2).

    Args:
        cam_from_world: (O, 3, 4) [R | t] of the camera of each observation.
        xy: (O, 2) normalized coordinates (x/z, y/z) of each observation.
        group: (O,) point index of each observation.
    """
    Pm = np.asarray(cam_from_world, dtype=np.float64).reshape(-1, 3, 4)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    group = np.asarray(group, dtype=np.int64)
    rows = np.concatenate([xy[:, :1] * Pm[:, 2] - Pm[:, 0], xy[:, 1:] * Pm[:, 2] - Pm[:, 1]], 0)
    rows = rows / np.linalg.norm(rows, axis=1, keepdims=True)  # equilibrate (H&Z 4.4)
    g2 = np.concatenate([group, group])
    M = np.zeros((num_groups, 4, 4))
    np.add.at(M, g2, rows[:, :, None] * rows[:, None, :])  # A^T A per point
    w, V = np.linalg.eigh(M)
    Xh = V[:, :, 0]
    count = np.bincount(group, minlength=num_groups)
    parallel = (count < 2) | (np.abs(Xh[:, 3]) < 1e-12) | (w[:, 1] < 1e-14 * np.maximum(w[:, 3], 1e-300))
    X = Xh[:, :3] / np.where(parallel, 1.0, Xh[:, 3])[:, None]
    X[parallel] = np.nan
    depth = np.einsum("oj,oj->o", Pm[:, 2, :3], X[group]) + Pm[:, 2, 3]
    behind = np.bincount(group, weights=~(depth > 0) & ~parallel[group], minlength=num_groups) > 0
    return _check(Triangulated(X, parallel, behind), strict, "DLT")


def triangulation_angles_deg(X: np.ndarray, C: np.ndarray, group: np.ndarray, num_groups: int) -> np.ndarray:
    """Largest angle (deg) between any two rays ``X - C_i`` of each point, (num_groups,).

    Args:
        X: (num_groups, 3) points; C: (O, 3) camera centre of each observation; group: (O,).
    """
    group = np.asarray(group, dtype=np.int64)
    r = X[group] - C
    length = np.linalg.norm(r, axis=1)
    # a point at a camera centre (or not finite) has no ray direction: its angle is 0, so every
    # min-angle test drops it (dividing by the 0 length gave NaN and numpy's warning)
    degenerate = ~(length > 0) | ~np.isfinite(length)
    r = np.where(degenerate[:, None], 0.0, r) / np.where(degenerate, 1.0, length)[:, None]
    count = np.bincount(group, minlength=num_groups)
    # rays ordered by (track length, group): the groups of one length form an (n, L, 3) block,
    # so a few long tracks do not pad every short one to their length (cost sum n_L L^2)
    order = np.lexsort((group, count[group]))
    g, r = group[order], r[order]
    cosmin = np.ones(num_groups)
    pos = 0
    for L in np.unique(count[g]):
        n = int((count == L).sum())
        blk = r[pos:pos + n * L].reshape(n, L, 3)
        cosmin[g[pos:pos + n * L:L]] = np.einsum("gik,gjk->gij", blk, blk).reshape(n, -1).min(axis=1)
        pos += n * L
    ang = np.degrees(np.arccos(np.clip(cosmin, -1.0, 1.0)))
    ang[np.bincount(group, weights=degenerate, minlength=num_groups) > 0] = 0.0
    return ang
