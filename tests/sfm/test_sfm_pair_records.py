"""match_pairs / verify_pairs return typed per-pair records (issue 29): PairMatches, VerifiedPairs."""

import dataclasses

import numpy as np
import pytest

from polarref.core.geometry import Rigid3, rotation_angle_deg, so3_exp
from polarref.sfm import features as F
from polarref.sfm.matching import MatchConfig, PairMatches, match_descriptors, match_pairs
from polarref.sfm.verification import VerifiedPairs, VerifyConfig, verify_pair, verify_pairs


def _descriptors(rng, n=200):
    base = F.normalize_descriptors(rng.uniform(0, 1, (n, 128)).astype(np.float32), True)
    perms = [np.arange(n)] + [rng.permutation(n) for _ in range(2)]
    return [F.normalize_descriptors(base[p] + rng.normal(scale=0.002, size=(n, 128)).astype(np.float32) ** 2, False)
            for p in perms], perms


def test_match_pairs_keeps_pair_order_and_equals_per_pair_matching():
    descs, perms = _descriptors(np.random.default_rng(0))
    pairs = [(1, 2), (0, 2), (0, 1)]   # not sorted: the record keeps the order asked for
    got = match_pairs(descs, pairs, MatchConfig(ratio=0.9))
    assert isinstance(got, PairMatches)
    assert list(got) == pairs and len(got) == 3
    for (i, j), m in got.items():
        np.testing.assert_array_equal(m, match_descriptors(descs[i], descs[j], MatchConfig(ratio=0.9)))
        # each match links the same base descriptor (the permutations are known)
        assert len(m) > 150 and (perms[i][m[:, 0]] == perms[j][m[:, 1]]).all()
    assert (0, 3) not in got
    with pytest.raises(KeyError):
        got[(0, 3)]
    with pytest.raises(dataclasses.FrozenInstanceError):
        got.pairs = ()


def test_pair_record_refuses_mismatched_lengths():
    with pytest.raises(ValueError, match="2 pairs but 1 entries"):
        PairMatches(((0, 1), (1, 2)), (np.zeros((0, 2), np.int32),))


def test_verify_pairs_returns_the_passing_pairs_with_their_pose():
    rng = np.random.default_rng(1)
    X = rng.uniform(-2, 2, (300, 3)) + [0, 0, 10]
    pose = Rigid3(so3_exp([0.02, -0.15, 0.03]), [-1.0, 0.1, 0.05])
    x1 = X[:, :2] / X[:, 2:]
    Xc = pose.apply(X)
    x2 = Xc[:, :2] / Xc[:, 2:] + rng.normal(scale=0.3 / 500, size=(300, 2))
    m = np.stack([np.arange(300)] * 2, 1).astype(np.int32)
    putative = PairMatches(((0, 1), (1, 2)), (m, m[:10]))   # (1, 2): too few matches, dropped
    got = verify_pairs([x1, x2, x2], putative, 500.0, VerifyConfig())
    assert isinstance(got, VerifiedPairs)
    assert list(got) == [(0, 1)]
    g = got[(0, 1)]
    assert g.pair == (0, 1) and g.num_matches == 300
    assert rotation_angle_deg(g.cam2_from_cam1.R, pose.R) < 0.5
    one = verify_pair(x1, x2, m, 500.0, VerifyConfig(), VerifyConfig().seed + 7919 * 0 + 1)
    np.testing.assert_array_equal(g.inliers, one.inliers)
