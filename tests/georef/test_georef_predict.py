"""The priors-only prediction (georef/predict.py): the per-draw linear model against a known
similarity, and its mean square over many draws against the closed-form expectation."""

import numpy as np
import pytest

from polarref.core.geometry import skew
from polarref.georef.predict import datum_error, predict_priors_only


def _block(rng, n=60):
    """Centres of a two-line flight at 100 m over check points on the ground."""
    t = np.linspace(-200, 200, n // 2)
    C = np.concatenate([np.c_[t, np.full_like(t, -40), np.full_like(t, 100)],
                        np.c_[t[::-1], np.full_like(t, 40), np.full_like(t, 100)]])
    G = np.c_[rng.uniform(-180, 180, 12), rng.uniform(-60, 60, 12), rng.uniform(-3, 3, 12)]
    return C, G


def _rot(w):
    th = np.linalg.norm(w)
    K = skew(w / th)
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def test_datum_error_of_a_similarity_is_its_displacement():
    """Priors that are the true centres moved by a small similarity: the linear model's check
    error is that similarity's displacement of the check points (first order)."""
    rng = np.random.default_rng(3)
    C, G = _block(rng)
    t, w, ls = np.array([0.3, -0.2, 0.5]), np.array([2e-5, -1e-5, 3e-5]), 1e-5
    o = C.mean(0)
    move = lambda X: o + np.exp(ls) * (X - o) @ _rot(w).T + t  # noqa: E731
    sig = np.tile([2.0, 2.0, 4.0], (len(C), 1))
    got = datum_error(C, sig, G, move(C) - C)
    want = move(G) - G
    assert np.abs(got - want).max() < 1e-4 * np.abs(want).max()
    # noise added on top moves the fitted datum: the check is not vacuous
    noisy = move(C) - C + rng.normal(0, 2.0, C.shape)
    assert np.abs(datum_error(C, sig, G, noisy) - want).max() > 1e-2


@pytest.mark.parametrize("rho, attitude", [(0.0, False), (0.9, False), (0.9, True)])
def test_mean_square_of_draws_matches_the_expectation(rho, attitude):
    """Draws of AR(1) prior errors (and attitude errors) through datum_error: their pooled
    RMSE matches predict_priors_only within the sampling error of 4000 draws."""
    rng = np.random.default_rng(11)
    C, G = _block(rng)
    n = len(C)
    sig = np.tile([2.0, 2.0, 4.0], (n, 1))
    R = np.array([_rot(rng.normal(0, 0.05, 3)) for _ in range(n)]) if attitude else None
    srot = np.radians(1.0) if attitude else None
    L = np.linalg.cholesky(rho ** np.abs(np.subtract.outer(np.arange(n), np.arange(n))) + 1e-12 * np.eye(n))
    sq = []
    for _ in range(4000):
        e = L @ rng.normal(size=(n, 3)) * sig
        d = (L @ rng.normal(size=(n, 3))) * srot if attitude else None
        sq.append(datum_error(C, sig, G, e, R, srot, d) ** 2)
    got = np.sqrt(np.concatenate(sq).mean(0))
    want = predict_priors_only(C, sig, G, rho, R, srot)
    for g, w in zip(got, (want.rmse_x, want.rmse_y, want.rmse_z)):
        assert 0.93 < g / w < 1.07
