"""The matcher's column-max mutual check (issue 34) gives exactly the column-argmax matches,
ties between identical descriptors included (they take the argmax path)."""

from __future__ import annotations

import numpy as np
import pytest

from polarref.sfm import matching as M


def _unit(rng, n, d=128):
    x = rng.standard_normal((n, d)).astype(np.float32)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def _brute(d1, d2, cfg):
    """Independent reference: the full similarity matrix, first-index argmax both ways."""
    s = d1 @ d2.T
    best = s.argmax(1)
    s1 = s[np.arange(len(d1)), best]
    t = s.copy()
    t[np.arange(len(d1)), best] = -np.inf
    s2 = t.max(1)
    dist = lambda v: np.sqrt(np.maximum(2.0 - 2.0 * v, 0.0))
    keep = (dist(s1) <= cfg.max_distance) & (dist(s1) < cfg.ratio * dist(s2))
    keep &= s.argmax(0)[best] == np.arange(len(d1))
    return np.stack([np.flatnonzero(keep), best[keep]], 1).astype(np.int32)


@pytest.mark.parametrize("n1,n2", [(700, 900), (2500, 300), (40, 5000)])
def test_column_max_path_equals_the_argmax_reference(n1, n2):
    rng = np.random.default_rng(n1 + n2)
    d1 = _unit(rng, n1)
    # d2: noisy copies of some of d1 (true matches) plus distractors
    k = min(n1, n2) // 2
    d2 = np.concatenate([d1[rng.choice(n1, k, replace=False)] + 0.15 * _unit(rng, k), _unit(rng, n2 - k)])
    d2 /= np.linalg.norm(d2, axis=1, keepdims=True)
    cfg = M.MatchConfig()
    fast = M._match_mutual_by_column_max(d1, d2, cfg)
    assert fast is not None
    ref = M._match_by_column_argmax(d1, d2, cfg)
    assert len(ref) > k // 3        # the test has matches to compare
    np.testing.assert_array_equal(fast, ref)
    np.testing.assert_array_equal(M.match_descriptors(d1, d2, cfg), _brute(d1, d2, cfg))


def test_tied_columns_take_the_argmax_path_and_its_first_row_rule():
    rng = np.random.default_rng(7)
    d1 = _unit(rng, 300)
    d1[200] = d1[50]                     # two rows identical: column maxima tied between them
    d2 = d1[rng.permutation(300)] + 0.05 * _unit(rng, 300)
    d2 /= np.linalg.norm(d2, axis=1, keepdims=True)
    cfg = M.MatchConfig(ratio=1.01)      # let the tied pair pass the ratio test: only the mutual rule decides
    assert M._match_mutual_by_column_max(d1, d2, cfg) is None
    got = M.match_descriptors(d1, d2, cfg)
    np.testing.assert_array_equal(got, _brute(d1, d2, cfg))
    assert 50 in got[:, 0] and 200 not in got[:, 0]     # the first of the tied rows keeps the match


def test_float16_descriptors_match_as_their_float32_values():
    """The features hold float16 descriptors (memory at 631 views): matching them gives the
    matches of their exact float32 values, and the independent brute force agrees."""
    rng = np.random.default_rng(11)
    a = _unit(rng, 700).astype(np.float16)
    b = np.concatenate([a[:400].astype(np.float32) + 0.01 * _unit(rng, 400), _unit(rng, 300)])
    b = (b / np.linalg.norm(b, axis=1, keepdims=True)).astype(np.float16)
    cfg = M.MatchConfig()
    got = M.match_descriptors(a, b, cfg)
    want = M.match_descriptors(a.astype(np.float32), b.astype(np.float32), cfg)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got, _brute(a.astype(np.float32), b.astype(np.float32), cfg))
    assert 300 <= len(got) <= 400
