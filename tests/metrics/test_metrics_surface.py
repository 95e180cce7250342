"""Exact point-to-triangle-mesh distance against brute force and analytic cases."""

import numpy as np

from polarref.metrics import closest_points_on_triangles, point_to_mesh_distance


def _cube():
    v = np.array([[x, y, z] for x in (0.0, 1) for y in (0.0, 1) for z in (0.0, 1)])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def _cube_distance(p):
    q = np.clip(p, 0, 1)
    outside = np.linalg.norm(p - q, axis=1)
    inside = np.min(np.concatenate([p, 1 - p], 1), axis=1)
    return np.where(outside > 0, outside, inside)


def test_cube_analytic():
    rng = np.random.default_rng(0)
    p = rng.uniform(-1, 2, (3000, 3))
    v, f = _cube()
    np.testing.assert_allclose(point_to_mesh_distance(p, v, f, k=2), _cube_distance(p), atol=1e-12)


def test_closest_point_is_a_minimum_on_random_triangles():
    rng = np.random.default_rng(1)
    A, B, C = (rng.normal(size=(2000, 3)) for _ in range(3))
    P = rng.normal(size=(2000, 3)) * 2
    Q = closest_points_on_triangles(P, A, B, C)
    d = np.linalg.norm(Q - P, axis=1)
    # dense barycentric sampling never beats the closed form (and comes close to it)
    u, w = np.meshgrid(np.linspace(0, 1, 60), np.linspace(0, 1, 60))
    keep = u + w <= 1
    u, w = u[keep], w[keep]
    S = A[:, None] + (B - A)[:, None] * u[None, :, None] + (C - A)[:, None] * w[None, :, None]
    ds = np.linalg.norm(S - P[:, None], axis=2).min(1)
    assert (d <= ds + 1e-12).all()
    assert np.median(ds - d) < 1e-2


def test_random_mesh_against_brute_force():
    rng = np.random.default_rng(2)
    v = rng.normal(size=(300, 3))
    f = rng.integers(0, 300, (400, 3))
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    p = rng.normal(size=(200, 3)) * 1.5
    got = point_to_mesh_distance(p, v, f, k=3)
    P = np.repeat(p, len(f), 0)
    F = np.tile(f, (len(p), 1))
    ref = np.linalg.norm(closest_points_on_triangles(P, v[F[:, 0]], v[F[:, 1]], v[F[:, 2]]) - P, axis=1)
    np.testing.assert_allclose(got, ref.reshape(len(p), -1).min(1), atol=1e-12)


def test_bounded_pair_batches_give_the_brute_force_distance():
    """One huge triangle makes every query ball hold the whole mesh (the 493-view UAV ground mesh
    needed 51.7 million pairs at once); batches of at most max_pairs must give the exact result."""
    rng = np.random.default_rng(5)
    v = np.vstack([rng.uniform(-1, 1, (300, 3)), [[-50, -50, -3], [50, -50, -3], [0, 60, -3]]])
    f = rng.integers(0, 300, (500, 3))
    f = np.vstack([f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])], [[300, 301, 302]]])
    p = rng.uniform(-1.5, 1.5, (150, 3))
    P = np.repeat(p, len(f), 0)
    F = np.tile(f, (len(p), 1))
    ref = np.linalg.norm(closest_points_on_triangles(P, v[F[:, 0]], v[F[:, 1]], v[F[:, 2]]) - P, axis=1)
    ref = ref.reshape(len(p), -1).min(1)
    for max_pairs in (1, 37, 10_000, 1_000_000):
        got = point_to_mesh_distance(p, v, f, k=3, chunk=64, max_pairs=max_pairs)
        np.testing.assert_allclose(got, ref, atol=1e-12)
