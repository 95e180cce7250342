"""The large-problem generator (ba/scale_synth.py): seeded, and its statistics are the stated ones.

Every bound is two-sided and derived from the spec: track length 1 + Geometric(p), p = 1 / (mean - 1)
has mean ``mean_track`` and P(L = 2) = p (clipping at 60 removes (1 - p)^59 ~ 2e-9 of the mass);
the outlier count is Binomial(M, share); inlier pixel errors are N(0, noise^2) per coordinate.
The tolerances are ~5 standard errors at scale-1e5's size.
"""

import numpy as np
import pytest

from polarref.ba.scale_synth import SCALE_SPECS, FOCAL_PX, ScaleSpec, generate, parse_spec
from polarref.core.geometry import so3_exp, so3_log

SPEC = SCALE_SPECS["scale-1e5"]


@pytest.fixture(scope="module")
def gen():
    return generate(SPEC, seed=3)


def _bal_project(bal) -> np.ndarray:
    """BAL's own model, written independently of the generator: x = R X + t, uv = -f x[:2] / x[2]."""
    R = so3_exp(bal.rotvec)
    cam, pt = bal.obs.image, bal.obs.point
    x = np.einsum("mij,mj->mi", R[cam], bal.points[pt]) + bal.t[cam]
    return -bal.intrinsics[cam, :1] * x[:, :2] / x[:, 2:], x[:, 2]


def test_seeded_determinism(gen):
    again = generate(SPEC, seed=3)
    for a, b in ((gen.initial, again.initial), (gen.truth, again.truth)):
        for f in ("rotvec", "t", "intrinsics", "points"):
            assert np.array_equal(getattr(a, f), getattr(b, f))
        assert np.array_equal(a.obs.uv, b.obs.uv) and np.array_equal(a.obs.image, b.obs.image)
    assert np.array_equal(gen.outlier, again.outlier)
    other = generate(SPEC, seed=4)
    assert not np.array_equal(other.initial.obs.uv[:100], gen.initial.obs.uv[:100])
    assert parse_spec("scale-1e5:4") == (SPEC, 4) and parse_spec("scale-1e6") == (SCALE_SPECS["scale-1e6"], 0)
    for bad in ("scale-1e4", "scale-1e5:x", "scale-1e5:-1"):
        with pytest.raises(ValueError, match="unknown scale problem"):
            parse_spec(bad)
    with pytest.raises(ValueError, match="mean track > 2"):
        generate(ScaleSpec(10, 1000, mean_track=2.0))


def test_size_and_track_lengths(gen):
    M, L = gen.initial.num_observations, gen.track_length
    assert SPEC.num_observations <= M < SPEC.num_observations + SPEC.max_track   # within one track
    assert L.sum() == M and len(L) == gen.initial.num_points == len(gen.truth.points)
    assert np.array_equal(np.bincount(gen.initial.obs.point, minlength=len(L)), L)
    assert L.min() == 2 and L.max() <= SPEC.max_track
    p = 1.0 / (SPEC.mean_track - 1.0)
    n = len(L)
    sd_mean = np.sqrt(1 - p) / p / np.sqrt(n)
    assert abs(L.mean() - SPEC.mean_track) < 5 * sd_mean
    share2 = (L == 2).mean()
    assert abs(share2 - p) < 5 * np.sqrt(p * (1 - p) / n)
    # geometric tail: P(L = k + 1) / P(L = k) = 1 - p
    counts = np.bincount(L)
    assert counts[3] / counts[2] == pytest.approx(1 - p, abs=0.03)
    assert counts[4] / counts[3] == pytest.approx(1 - p, abs=0.04)


def test_tracks_see_distinct_cameras_inside_the_window(gen):
    obs = gen.initial.obs
    key = obs.point * SPEC.num_cameras + obs.image
    assert len(np.unique(key)) == len(key)              # a camera sees a point at most once
    order = np.argsort(obs.point, kind="stable")
    cam, pt = obs.image[order], obs.point[order]
    first = cam[np.searchsorted(pt, pt)]                 # the track's first camera
    span = (cam - first) % SPEC.num_cameras
    assert span.max() < SPEC.window and span.max() >= SPEC.window // 2


def test_noise_and_outliers(gen):
    uv0, uvt = gen.initial.obs.uv, gen.truth.obs.uv
    M = len(uv0)
    share = gen.outlier.mean()
    assert abs(share - SPEC.outlier_share) < 5 * np.sqrt(SPEC.outlier_share * (1 - SPEC.outlier_share) / M)
    err = uv0 - uvt
    inl = err[~gen.outlier]
    sd = inl.std()
    assert abs(sd - SPEC.noise_px) < 5 * SPEC.noise_px / np.sqrt(2 * inl.size)
    assert abs(inl.mean()) < 5 * SPEC.noise_px / np.sqrt(inl.size)
    mag = np.linalg.norm(err[gen.outlier], axis=1)       # displacement in [a, 2a] plus noise
    slack = 6 * SPEC.noise_px
    assert mag.min() > SPEC.outlier_px - slack and mag.max() < 2 * SPEC.outlier_px + slack
    assert np.median(mag) == pytest.approx(1.5 * SPEC.outlier_px, rel=0.03)   # uniform magnitude
    assert np.linalg.norm(inl, axis=1).max() < slack     # no inlier carries an outlier's error


def test_truth_is_consistent_bal_and_start_is_perturbed_as_stated(gen):
    uv, depth = _bal_project(gen.truth)
    assert np.abs(uv - gen.truth.obs.uv).max() < 1e-9                # noise-free pixels, BAL model
    assert (depth < 0).all()                                         # BAL: in front means z < 0
    assert (gen.truth.intrinsics == [FOCAL_PX, 0.0, 0.0]).all()
    N = SPEC.num_cameras
    dR = so3_log(so3_exp(gen.initial.rotvec) @ so3_exp(gen.truth.rotvec).transpose(0, 2, 1))
    sd_rot = np.degrees(np.sqrt((dR**2).mean()))
    assert abs(sd_rot - SPEC.rot_deg) < 5 * SPEC.rot_deg / np.sqrt(2 * 3 * N)
    dX = gen.initial.points - gen.truth.points
    assert abs(dX.std() - SPEC.xyz_sigma) < 5 * SPEC.xyz_sigma / np.sqrt(2 * dX.size)
    C0 = -np.einsum("nji,nj->ni", so3_exp(gen.initial.rotvec), gen.initial.t)
    Ct = -np.einsum("nji,nj->ni", so3_exp(gen.truth.rotvec), gen.truth.t)
    dC = C0 - Ct
    assert abs(dC.std() - SPEC.xyz_sigma) < 5 * SPEC.xyz_sigma / np.sqrt(2 * dC.size)
    assert np.linalg.norm(Ct, axis=1).min() > 9.9            # the ring of radius 10
