"""Dense-surface scores against a ground-truth mesh (used by :mod:`polarref.metrics`).

Protocol (Knapitsch et al. 2017, Tanks and Temples; Schoeps et al. 2017, ETH3D):

* ``tau`` is a distance tolerance, here a fraction (default 0.5%) of the GT scene diameter =
  largest distance between two GT mesh vertices (rotation invariant; from the convex hull).
* Accuracy distances: from each reconstructed point (a cloud's points, or area-uniform samples
  of a mesh) to the GT surface, exact point-to-triangle distance. Precision = share <= tau.
* Completeness distances: from each GT sample (area-uniform samples of the GT mesh, restricted
  to the part the cameras saw when a visibility mask is given) to the reconstruction: the
  nearest reconstructed point for a cloud, the exact distance to the surface for a mesh.
  Recall = share <= tau.
* F-score = 2 P R / (P + R) (0 when both are 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarref.metrics.distance import point_to_mesh_distance


@dataclass
class SurfaceScore:
    """One reconstruction (cloud or mesh) scored against the GT surface; distances in GT units."""

    kind: str                      # "cloud" | "mesh"
    tau: float
    tau_rel: float                 # tau / scene diameter
    num_points: int                # reconstructed points (or mesh samples) scored
    num_gt_samples: int
    accuracy_mean: float
    accuracy_median: float
    completeness_mean: float
    completeness_median: float
    precision: float
    recall: float
    fscore: float


def mesh_diameter(vertices: np.ndarray) -> float:
    """Largest distance between two vertices (V, 3) (exact, via the convex hull)."""
    from scipy.spatial import ConvexHull

    V = np.asarray(vertices, dtype=np.float64)
    try:
        V = V[ConvexHull(V).vertices]
    except Exception:  # flat or tiny input: the hull is undefined, use all vertices
        pass
    V = V - V.mean(0)
    sq = (V * V).sum(1)
    best = 0.0
    for s in range(0, len(V), 2048):  # chunked: a round mesh can have 10^4+ hull vertices
        d2 = sq[s: s + 2048, None] + sq[None, :] - 2.0 * V[s: s + 2048] @ V.T
        best = max(best, float(d2.max()) if d2.size else 0.0)
    return float(np.sqrt(max(best, 0.0)))


def sample_mesh(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int) -> np.ndarray:
    """(n, 3) points uniform by area on the triangle mesh."""
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(B - A, C - A), axis=1)
    rng = np.random.default_rng(seed)
    tri = rng.choice(len(F), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    return (1 - s)[:, None] * A[tri] + (s * (1 - r2))[:, None] * B[tri] + (s * r2)[:, None] * C[tri]


def _summary(kind, tau, diameter, acc, comp) -> SurfaceScore:
    p = float((acc <= tau).mean()) if len(acc) else 0.0
    r = float((comp <= tau).mean()) if len(comp) else 0.0
    f = 2 * p * r / (p + r) if p + r > 0 else 0.0
    med = lambda d: float(np.median(d)) if len(d) else float("nan")  # noqa: E731
    avg = lambda d: float(np.mean(d)) if len(d) else float("nan")  # noqa: E731
    return SurfaceScore(kind, float(tau), float(tau / diameter) if diameter > 0 else float("nan"),
                        len(acc), len(comp), avg(acc), med(acc), avg(comp), med(comp), p, r, f)


def score_cloud(points: np.ndarray, gt_vertices: np.ndarray, gt_faces: np.ndarray,
                gt_samples: np.ndarray, tau: float, diameter: float,
                max_points: int = 50_000, seed: int = 0) -> SurfaceScore:
    """Score a point cloud (P, 3) (subsampled to ``max_points``, seeded, for accuracy)."""
    from scipy.spatial import cKDTree

    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not len(P):
        return _summary("cloud", tau, diameter, np.zeros(0), np.full(len(gt_samples), np.inf))
    sub = P if len(P) <= max_points else P[np.random.default_rng(seed).choice(len(P), max_points, replace=False)]
    acc = point_to_mesh_distance(sub, gt_vertices, gt_faces)
    comp, _ = cKDTree(P).query(gt_samples, k=1)
    return _summary("cloud", tau, diameter, acc, comp)


def score_mesh(vertices: np.ndarray, faces: np.ndarray, gt_vertices: np.ndarray, gt_faces: np.ndarray,
               gt_samples: np.ndarray, tau: float, diameter: float, num_samples: int | None = None,
               seed: int = 0) -> SurfaceScore:
    """Score a triangle mesh: its area-uniform samples vs GT, GT samples vs its surface."""
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    # Zero-area triangles (Poisson output has a few) have no closest point; they add no surface.
    F = F[np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1) > 0]
    if not len(F):
        return _summary("mesh", tau, diameter, np.zeros(0), np.full(len(gt_samples), np.inf))
    S = sample_mesh(V, F, num_samples or len(gt_samples), seed)
    acc = point_to_mesh_distance(S, gt_vertices, gt_faces)
    comp = point_to_mesh_distance(gt_samples, V, F)
    return _summary("mesh", tau, diameter, acc, comp)
