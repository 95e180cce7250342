"""F-score protocol on a unit sphere mesh: itself scores 1, a shifted copy scores as predicted.

For a sphere of radius r shifted by delta, a point at angle acos(c) from the shift direction
lies | sqrt(r^2 + 2 delta r c + delta^2) - r | from the other sphere, and c is uniform on [-1, 1]
for area-uniform samples, so precision = recall = F = the share of c in an interval computed in
closed form below (tau / delta when the interval lies inside [-1, 1]).
"""

import numpy as np
import pytest

from polarref.metrics.surface import mesh_diameter, sample_mesh, score_cloud, score_mesh
from synth.meshes import icosphere


def _expected_share(r: float, delta: float, tau: float) -> float:
    lo = ((r - tau) ** 2 - r * r - delta * delta) / (2 * delta * r)
    hi = ((r + tau) ** 2 - r * r - delta * delta) / (2 * delta * r)
    return (min(hi, 1.0) - max(lo, -1.0)) / 2.0


@pytest.fixture(scope="module")
def sphere():
    return icosphere(5)  # edge ~0.033: faces lie within 2e-4 of the unit sphere


def test_diameter_of_unit_sphere():
    V = icosphere(3)[0]  # antipodal vertex pairs: the diameter is exactly 2
    assert mesh_diameter(V) == pytest.approx(2.0, abs=1e-9)
    assert mesh_diameter(V * np.array([3.0, 1.0, 1.0])) == pytest.approx(6.0, abs=1e-9)


def test_mesh_against_itself_scores_one(sphere):
    V, F = sphere
    S = sample_mesh(V, F, 5000, seed=1)
    s = score_mesh(V, F, V, F, S, tau=0.01, diameter=2.0, num_samples=5000, seed=2)
    assert s.precision == 1.0 and s.recall == 1.0 and s.fscore == 1.0
    assert s.accuracy_median < 1e-12 and s.tau_rel == pytest.approx(0.005)
    # Its own samples as a cloud: spacing ~0.025 << tau = 0.05, so also 1.
    c = score_cloud(sample_mesh(V, F, 20000, seed=3), V, F, S, tau=0.05, diameter=2.0)
    assert c.fscore == 1.0


@pytest.mark.parametrize("delta_over_tau", [0.5, 4.0])
def test_shifted_copy_drops_as_predicted(sphere, delta_over_tau):
    V, F = sphere
    tau = 0.01
    delta = delta_over_tau * tau
    shifted = V + np.array([delta, 0.0, 0.0])
    S = sample_mesh(V, F, 8000, seed=4)
    s = score_mesh(shifted, F, V, F, S, tau=tau, diameter=2.0, num_samples=8000, seed=5)
    expected = _expected_share(1.0, delta, tau)
    # 8000 samples: binomial sd <= 0.0056; tessellation moves distances by <= 2e-4 (2% of tau).
    assert s.precision == pytest.approx(expected, abs=0.025)
    assert s.recall == pytest.approx(expected, abs=0.025)
    assert s.fscore == pytest.approx(expected, abs=0.025)
    if delta_over_tau < 1:
        assert s.fscore > 0.999
    else:
        assert s.fscore < 1.2 / delta_over_tau


def test_empty_reconstruction_scores_zero(sphere):
    V, F = sphere
    S = sample_mesh(V, F, 100, seed=0)
    s = score_cloud(np.zeros((0, 3)), V, F, S, tau=0.01, diameter=2.0)
    assert s.fscore == 0.0 and s.recall == 0.0 and s.num_points == 0
