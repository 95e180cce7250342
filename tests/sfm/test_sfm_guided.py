"""Guided matching (track continuation) on an exact synthetic three-view scene."""

import numpy as np
import pytest

from polarref.camera import Camera
from polarref.core.geometry import Rigid3, so3_exp
from polarref.sfm import features as F
from polarref.sfm import rays as R_
from polarref.sfm.guided import GuidedConfig, guided_extend
from polarref.sfm.state import MapState, TriangulationConfig
from polarref.sfm.tracks import build_tracks


def _three_views(rng, n=60):
    cam = Camera("PINHOLE", 640, 480, np.array([500.0, 500.0, 320.0, 240.0]))
    X = rng.uniform(-2, 2, (n, 3)) + [0, 0, 12]
    poses = [Rigid3(np.eye(3), np.zeros(3)), Rigid3(so3_exp([0, -0.1, 0]), [-1.5, 0, 0.1]),
             Rigid3(so3_exp([0.02, 0.12, 0]), [1.6, 0.2, -0.1])]
    uv = [R_.project(cam, p.apply(X)) for p in poses]
    return cam, X, poses, uv, _descriptors(rng, n)


def _descriptors(rng, n):
    # peaky histograms: unrelated RootSIFT descriptors then lie > 0.7 apart, as most real ones do
    return F.normalize_descriptors(rng.uniform(0, 1, (n, 128)) ** 8, root_sift=True).astype(np.float32)



def test_guided_matching_finds_the_known_correspondences_and_skips_ambiguous():
    rng = np.random.default_rng(0)
    cam, X, poses, uv, desc = _three_views(rng)
    n = len(X)
    # image 2: the true keypoints in a shuffled order, plus decoys 0.3 px off the projections of
    # points 0-4 (unrelated descriptors: must lose) and 5-9 (copies of the true descriptor: ambiguous)
    perm = rng.permutation(n)
    kp2 = np.concatenate([uv[2][perm], uv[2][:10] + [0.3, 0.0]])
    unrelated = _descriptors(rng, 5)
    d2 = np.concatenate([desc[perm], unrelated, desc[5:10]])
    keypoints = [uv[0], uv[1], kp2]
    descriptors = [desc, desc, d2.astype(np.float32)]
    tracks = build_tracks([n, n, len(kp2)], {(0, 1): np.stack([np.arange(n)] * 2, 1)})
    state = MapState(["a", "b", "c"], [cam], np.zeros(3, np.int64), keypoints, tracks, TriangulationConfig())
    for i, p in enumerate(poses):
        state.set_pose(i, p)
    assert state.triangulate(np.arange(tracks.num_tracks)) == n
    point_of_track = tracks.keypoint[tracks.image == 0][np.argsort(tracks.track[tracks.image == 0])]
    np.testing.assert_allclose(state.X[np.arange(n)], X[point_of_track], atol=1e-8)

    added = guided_extend(state, [2], descriptors, GuidedConfig(enabled=True, radius_px=1.0))
    assert added == n - 5  # every point except the 5 ambiguous ones
    new = np.flatnonzero(tracks.image == 2)
    assert len(new) == added and state.active[new].all()
    true_point = np.where(tracks.keypoint[new] < n, perm[np.minimum(tracks.keypoint[new], n - 1)], -1)
    np.testing.assert_array_equal(true_point, point_of_track[tracks.track[new]])
    assert not np.isin(point_of_track[tracks.track[new]], np.arange(5, 10)).any()
    assert np.allclose(state.errors(new), 0.0, atol=1e-6)
    # nothing left to add: a second pass finds only the ambiguous points again and skips them
    assert guided_extend(state, [2], descriptors, GuidedConfig(enabled=True, radius_px=1.0)) == 0
    with pytest.raises(ValueError, match="already belong"):
        state.add_observations(np.array([2]), tracks.keypoint[new[:1]], np.array([0]))


def test_guided_matching_rejects_far_or_dissimilar_keypoints():
    rng = np.random.default_rng(1)
    cam, X, poses, uv, desc = _three_views(rng, n=30)
    n = len(X)
    other = _descriptors(rng, n)
    # image 2: half the keypoints 3 px off (outside the radius), half with unrelated descriptors
    kp2 = uv[2].copy()
    kp2[: n // 2] += [3.0, 0.0]
    d2 = desc.copy()
    d2[n // 2:] = other[n // 2:]
    tracks = build_tracks([n, n, n], {(0, 1): np.stack([np.arange(n)] * 2, 1)})
    state = MapState(["a", "b", "c"], [cam], np.zeros(3, np.int64), [uv[0], uv[1], kp2], tracks,
                     TriangulationConfig())
    for i, p in enumerate(poses):
        state.set_pose(i, p)
    state.triangulate(np.arange(tracks.num_tracks))
    assert guided_extend(state, [2], [desc, desc, d2], GuidedConfig(enabled=True, radius_px=2.0)) == 0
    # with a radius that reaches the shifted ones, exactly those are found
    assert guided_extend(state, [2], [desc, desc, d2], GuidedConfig(enabled=True, radius_px=3.5)) == n // 2
