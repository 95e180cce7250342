"""SfM stages on synthetic inputs with known answers: features, matching, tracks, verification, PnP."""

import numpy as np
import pytest

from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3, rotation_angle_deg, skew, so3_exp
from polarref.sfm import features as F
from polarref.sfm.matching import MatchConfig, match_descriptors, select_pairs
from polarref.sfm.registration import RegisterConfig, estimate_pose
from polarref.sfm.tracks import build_tracks
from polarref.sfm.verification import VerifyConfig, verify_pair


def _blob_image(cx, cy, w=160, h=120, sigma=3.0):
    """A dark Gaussian blob centred at OpenCV pixel coordinates (cx, cy) on white."""
    y, x = np.mgrid[0:h, 0:w]
    g = 255 - 200 * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sigma**2))
    return np.repeat(g[:, :, None], 3, 2).round().astype(np.uint8)


def test_keypoints_follow_colmap_pixel_convention_and_rescale_exactly():
    img = _blob_image(70.0, 50.0)
    f = F.extract(img, "blob.png", F.FeatureConfig(max_num_features=10, contrast_threshold=0.01))
    assert len(f.keypoints) >= 1
    best = f.keypoints[np.argmin(np.linalg.norm(f.keypoints - [70.5, 50.5], axis=1))]
    assert np.linalg.norm(best - [70.5, 50.5]) < 0.05  # centre of OpenCV pixel (70, 50); OpenCV's own +0.25 bias removed
    big = np.repeat(np.repeat(img, 2, 0), 2, 1)  # 2x upsampled: blob at COLMAP (141, 101)
    f2 = F.extract(big, "big.png", F.FeatureConfig(max_num_features=10, contrast_threshold=0.01,
                                                    max_image_size=160))
    assert (f2.width, f2.height) == (320, 240)
    best2 = f2.keypoints[np.argmin(np.linalg.norm(f2.keypoints - [141, 101], axis=1))]
    assert np.linalg.norm(best2 - [141.0, 101.0]) < 0.3
    np.testing.assert_allclose(np.linalg.norm(f.descriptors, axis=1), 1.0, atol=2e-3)


def test_matching_recovers_a_permutation_and_rejects_ambiguous():
    rng = np.random.default_rng(0)
    d1 = F.normalize_descriptors(rng.uniform(0, 1, (300, 128)).astype(np.float32), True)
    perm = rng.permutation(300)
    d2 = F.normalize_descriptors(d1[perm] + rng.normal(scale=0.002, size=(300, 128)).astype(np.float32) ** 2, False)
    m = match_descriptors(d1, d2, MatchConfig(ratio=0.9))
    assert len(m) > 250
    assert (perm[m[:, 1]] == m[:, 0]).all()
    # duplicate a descriptor in image 2: the ratio test must drop that match
    d2b = np.concatenate([d2, d2[:1]], 0)
    m2 = match_descriptors(d1, d2b, MatchConfig(ratio=0.9))
    assert perm[0] not in m2[:, 0]
    assert len(m2) == len(m) - 1


def test_select_pairs():
    assert len(select_pairs(10, MatchConfig())) == 45
    seq = select_pairs(10, MatchConfig(pairing="sequential", sequential_overlap=2))
    assert len(seq) == 9 + 8 and (0, 2) in seq and (0, 3) not in seq
    c = np.array([[i, 0.0, 0.0] for i in range(10)])
    sp = select_pairs(10, MatchConfig(pairing="spatial", spatial_neighbors=1), centers=c)
    assert set(sp) == {(i, i + 1) for i in range(9)}
    with pytest.raises(PolarrefError, match="exhaustive_max_images"):
        select_pairs(300, MatchConfig())
    with pytest.raises(PolarrefError, match="pose-prior"):
        select_pairs(3, MatchConfig(pairing="spatial"))


def test_tracks_chain_and_conflict_dropped():
    # image0 kp0 - image1 kp0 - image2 kp0 : one track of 3
    # image0 kp1 - image1 kp1, image1 kp1 - image2 kp1, image2 kp1 - image0 kp2 : holds kp1 and kp2 of image0
    inl = {(0, 1): np.array([[0, 0], [1, 1]]), (1, 2): np.array([[0, 0], [1, 1]]),
           (0, 2): np.array([[2, 1]])}
    t = build_tracks([3, 2, 2], inl)
    assert t.num_tracks == 1 and t.num_conflicting == 1
    assert sorted(zip(t.image.tolist(), t.keypoint.tolist())) == [(0, 0), (1, 0), (2, 0)]
    assert t.start.tolist() == [0, 3]
    # split: BFS from image 1's keypoint 1 keeps (0,1) (1,1) (2,1); image 0's keypoint 2 is left alone
    s = build_tracks([3, 2, 2], inl, conflicts="split")
    assert s.num_tracks == 2 and s.num_conflicting == 1
    got = {tuple(sorted(zip(s.image[a:b].tolist(), s.keypoint[a:b].tolist())))
           for a, b in zip(s.start[:-1], s.start[1:])}
    assert got == {((0, 0), (1, 0), (2, 0)), ((0, 1), (1, 1), (2, 1))}


def _two_view(rng, n=400, outliers=100):
    X = rng.uniform(-2, 2, (n, 3)) + [0, 0, 10]
    pose = Rigid3(so3_exp([0.02, -0.15, 0.03]), [-1.0, 0.1, 0.05])
    x1 = X[:, :2] / X[:, 2:]
    Xc = pose.apply(X)
    x2 = Xc[:, :2] / Xc[:, 2:]
    x2 = x2 + rng.normal(scale=0.3 / 500, size=x2.shape)
    bad = rng.choice(n, outliers, replace=False)
    x2[bad] += rng.uniform(-0.1, 0.1, (outliers, 2))
    return X, pose, x1, x2, bad


def test_verification_recovers_relative_pose_and_outliers():
    rng = np.random.default_rng(1)
    X, pose, x1, x2, bad = _two_view(rng)
    m = np.stack([np.arange(len(X))] * 2, 1)
    g = verify_pair(x1, x2, m, 500.0, VerifyConfig(), seed=3)
    assert g is not None
    # the Sampson-optimal estimate is 0.33 deg off here (noise, narrow field); plain RANSAC 2.5
    assert rotation_angle_deg(g.cam2_from_cam1.R, pose.R) < 1.0
    t_dir = pose.t / np.linalg.norm(pose.t)
    # the baseline direction is the weakest part in a 23-degree field (measured 1.4 deg at 4 px)
    assert np.degrees(np.arccos(np.clip(g.cam2_from_cam1.t @ t_dir, -1, 1))) < 2.5
    inl = set(g.inliers[:, 0].tolist())
    good = set(range(len(X))) - set(bad.tolist())
    assert len(inl & good) > 0.95 * len(good)
    # a displaced match is still an inlier when it lands near its epipolar line: judge every
    # accepted match by its distance to the TRUE epipolar line (px at f = 500)
    E = skew(pose.t) @ pose.R
    a = np.c_[x1, np.ones(len(x1))]
    b = np.c_[x2, np.ones(len(x2))]
    line = a @ E.T
    dist = np.abs(np.einsum("ij,ij->i", b, line)) / np.linalg.norm(line[:, :2], axis=1) * 500
    accepted = np.array(sorted(inl))
    assert dist[accepted].max() < 6.0
    assert len(inl & set(bad.tolist())) < 0.25 * len(bad)
    # same seed, same answer
    g2 = verify_pair(x1, x2, m, 500.0, VerifyConfig(), seed=3)
    np.testing.assert_array_equal(g.inliers, g2.inliers)
    # too few matches -> None
    assert verify_pair(x1, x2, m[:10], 500.0, VerifyConfig(), seed=3) is None


def test_pnp_recovers_pose_with_outliers():
    rng = np.random.default_rng(2)
    X, pose, _, x2, bad = _two_view(rng)
    est = estimate_pose(x2, X, 500.0, RegisterConfig(), seed=0)
    assert est is not None
    assert rotation_angle_deg(est.cam_from_world.R, pose.R) < 0.05
    assert np.linalg.norm(est.cam_from_world.center - pose.center) < 0.02
    assert len(set(est.inliers.tolist()) & set(bad.tolist())) < 5
    assert estimate_pose(x2[:10], X[:10], 500.0, RegisterConfig(), seed=0) is None


def test_root_sift_dot_product_is_the_hellinger_kernel():
    rng = np.random.default_rng(4)
    a, b = rng.uniform(0, 5, (2, 128))
    ra, rb = F.normalize_descriptors(np.stack([a, b]), root_sift=True)
    hellinger = np.sum(np.sqrt(a / a.sum() * b / b.sum()))
    assert abs(float(ra @ rb) - hellinger) < 1e-6
    la, lb = F.normalize_descriptors(np.stack([a, b]), root_sift=False)
    assert abs(float(la @ lb) - a @ b / np.linalg.norm(a) / np.linalg.norm(b)) < 1e-6


def test_initial_pair_prefers_parallax_over_inlier_count():
    from polarref.sfm.initial_pair import InitConfig, choose_initial_pair
    from polarref.sfm.verification import TwoViewGeometry

    rng = np.random.default_rng(5)
    X = rng.uniform(-1, 1, (300, 3)) + [0, 0, 6]
    rays = [X / np.linalg.norm(X, axis=1, keepdims=True)]
    geoms = {}
    for j, baseline in ((1, 0.05), (2, 3.0)):  # pair (0, 1): tiny baseline; (0, 2): wide
        pose = Rigid3(np.eye(3), [-baseline, 0, 0])
        Xc = pose.apply(X)
        rays.append(Xc / np.linalg.norm(Xc, axis=1, keepdims=True))
        n = 300 if j == 1 else 200  # the narrow pair has more inliers
        t = pose.t / np.linalg.norm(pose.t)
        geoms[(0, j)] = TwoViewGeometry((0, j), np.stack([np.arange(n)] * 2, 1), Rigid3(pose.R, t), n)
    init = choose_initial_pair(geoms, rays, InitConfig())
    assert init.pair == (0, 2) and init.min_angle_deg == 16.0 and init.num_points > 100
    with pytest.raises(PolarrefError, match="no image pair"):
        choose_initial_pair({}, rays, InitConfig())


def test_coarse_selection_keeps_coarse_octaves_first():
    # two blob sizes: the response of SIFT's finest octave picks the small blobs, "coarse" the large ones
    y, x = np.mgrid[0:240, 0:320]
    g = np.full((240, 320), 230.0)
    for k, (cx, cy) in enumerate([(40 + 60 * i, 50 + 70 * j) for i in range(5) for j in range(3)]):
        s = 2.0 if k % 2 else 7.0
        g -= 180 * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s**2))
    img = np.repeat(g[:, :, None], 3, 2).round().astype(np.uint8)
    full = F.extract(img, "b.png", F.FeatureConfig(max_num_features=100000))
    n = len(full.keypoints) // 2
    coarse = F.extract(img, "b.png", F.FeatureConfig(max_num_features=n, selection="coarse"))
    resp = F.extract(img, "b.png", F.FeatureConfig(max_num_features=n))
    assert len(coarse.keypoints) == len(resp.keypoints) == n
    # the coarse choice is a subset of all keypoints and holds the largest scales
    d = np.linalg.norm(coarse.keypoints[:, None] - full.keypoints[None], axis=2).min(1)
    assert d.max() < 1e-9
    assert np.median(coarse.scales) > np.median(resp.scales)
    assert coarse.scales.max() == pytest.approx(full.scales.max())
    with pytest.raises(ValueError, match="selection"):
        F.extract(img, "b.png", F.FeatureConfig(selection="octave"))
