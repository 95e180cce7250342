"""Cached features load without their descriptors; matching loads them only when it runs.

Issue 14's memory target: at 631 views of 4096 features the descriptors are 0.66 GB (float16,
as they are held; float32 copies were 1.3 GB), and a run whose matches are cached never reads them.
"""

import dataclasses

import cv2
import numpy as np
import pytest

from polarref.camera import Camera
from polarref.core.errors import PolarrefError
from polarref.sfm import feature_cache as FC
from polarref.sfm import features as F
from polarref.sfm.pipeline import SfMConfig, ensure_descriptors, load_images_and_features, match_and_verify
from polarref.sfm.stages import StageClock


def _images(folder, n=3, seed=0):
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur((rng.uniform(0, 255, (260, 340))).astype(np.uint8), (0, 0), 2.0)
    folder.mkdir()
    for k in range(n):  # shifted crops of one texture: plenty of true matches between any two
        crop = base[10 + 4 * k:250 + 4 * k - 8, 12 + 6 * k:332 + 6 * k - 12]
        cv2.imwrite(str(folder / f"im{k}.png"), np.repeat(crop[:, :, None], 3, 2))
    return folder


@pytest.fixture
def cached(tmp_path):
    images = _images(tmp_path / "images")
    cfg = SfMConfig(features=F.FeatureConfig(max_num_features=300, contrast_threshold=0.01),
                    cache_dir=str(tmp_path / "cache"))
    clock = StageClock()
    eager, _, key = load_images_and_features(images, cfg, clock)
    assert clock.get("features").cached is False
    return images, cfg, key, eager


def test_cached_features_load_without_descriptors_and_fill_in_exactly(cached):
    images, cfg, key, eager = cached
    clock = StageClock()
    lazy, _, key2 = load_images_and_features(images, cfg, clock)
    assert clock.get("features").cached is True and key2 == key
    assert all(f.descriptors is None for f in lazy)
    for a, b in zip(eager, lazy):
        np.testing.assert_array_equal(a.keypoints, b.keypoints)
    ensure_descriptors(lazy, cfg, key)
    for a, b in zip(eager, lazy):
        assert b.descriptors.dtype == np.float16 and b.descriptors.shape == (len(b.keypoints), 128)
        assert a.descriptors.dtype == np.float16  # held as rounded: no float32 copy per image
        np.testing.assert_array_equal(a.descriptors, b.descriptors)  # the cache's float16 is exact


def test_matching_from_lazy_features_equals_eager(cached):
    images, cfg, key, eager = cached
    cam = Camera("PINHOLE", eager[0].width, eager[0].height, [300.0, 300.0, eager[0].width / 2, eager[0].height / 2])
    idx = np.zeros(len(eager), np.int64)
    ref = match_and_verify(eager, [cam], idx, dataclasses.replace(cfg, use_cache=False), key, StageClock())
    lazy, _, _ = load_images_and_features(images, cfg, StageClock())
    got = match_and_verify(lazy, [cam], idx, cfg, key, StageClock())  # no matches cache yet: loads descriptors
    assert all(f.descriptors is not None for f in lazy)
    assert set(ref.putative) == set(got.putative) and len(ref.putative) == 3
    assert sum(len(m) for m in ref.putative.values()) > 50
    for p in ref.putative:
        np.testing.assert_array_equal(ref.putative[p], got.putative[p])
    again, _, _ = load_images_and_features(images, cfg, StageClock())
    clock = StageClock()
    match_and_verify(again, [cam], idx, cfg, key, clock)  # matches cached: descriptors never read
    assert clock.get("matching").cached is True and all(f.descriptors is None for f in again)


def test_descriptors_of_other_images_or_a_vanished_cache_are_refused(cached, tmp_path):
    images, cfg, key, eager = cached
    lazy, _, _ = load_images_and_features(images, cfg, StageClock())
    with pytest.raises(ValueError, match="other images"):
        FC.load_descriptors(next((tmp_path / "cache").glob("features-*.npz")), lazy[:2])
    for f in (tmp_path / "cache").glob("features-*.npz"):
        f.unlink()
    with pytest.raises(PolarrefError, match="vanished"):
        ensure_descriptors(lazy, cfg, key)


def test_twin_features_stage_names_a_cached_load(tmp_path):
    """A twin's features stage that only loaded cached features says so instead of calling the
    load time the extraction time (the table compares it with pycolmap's extraction)."""
    from polarref.compare.run.jobs import ours_features
    from polarref.compare.twins.pipeline import FEATURES_CACHED

    images = _images(tmp_path / "images")
    pairs = tmp_path / "pairs.txt"
    pairs.write_text("im0.png im1.png\nim1.png im2.png\nim0.png im2.png\n")
    w, h = cv2.imread(str(images / "im0.png")).shape[1::-1]
    cam = {"model": "PINHOLE", "width": w, "height": h, "params": [300.0, 300.0, w / 2, h / 2]}
    first = ours_features(str(images), cam, "default", str(tmp_path / "cache"), str(pairs))
    again = ours_features(str(images), cam, "default", str(tmp_path / "cache"), str(pairs))
    assert "features" in first.stage_runtime_s and FEATURES_CACHED not in first.stage_runtime_s
    assert FEATURES_CACHED in again.stage_runtime_s and "features" not in again.stage_runtime_s
    # never silently dropped: the extraction time measured when the cache was made stands beside
    # the load time, and so does the matching's (matches cached too)
    extracted = again.stage_runtime_s["features (measured when the cache was made)"]
    assert 0.3 * first.stage_runtime_s["features"] < extracted <= first.stage_runtime_s["features"]
    matched = again.stage_runtime_s["matching (measured when the cache was made)"]
    assert matched == pytest.approx(first.stage_runtime_s["matching"] + first.stage_runtime_s["verification"],
                                    rel=1e-9)
    assert "matching (loaded from an earlier run's cache)" in again.stage_runtime_s
    assert first.verified_pairs == again.verified_pairs == 3


def test_save_streams_the_npz_that_savez_would_write(tmp_path):
    """features.save writes member by member (issue 34: the features stage's peak memory): the
    archive holds np.savez's members, dtypes and values (descriptors as float16 on disk, exact),
    and the extra memory of saving 40 images of 4096 features stays far below the ~42 MB of their
    float16 copies."""
    import resource

    rng = np.random.default_rng(3)
    feats = [F.Features(f"{i:03d}.png", 64, 48, rng.random((4096, 2)) * 40,
                        rng.random((4096, 128)).astype(np.float16).astype(np.float32), rng.random(4096),
                        rng.random(4096), rng.integers(0, 255, (4096, 3), dtype=np.uint8)) for i in range(40)]
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    F.save(tmp_path / "ours.npz", feats)
    grew_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    ref = dict(F._arrays(feats))
    np.savez(tmp_path / "ref.npz", **ref)
    with np.load(tmp_path / "ours.npz") as a, np.load(tmp_path / "ref.npz") as b:
        assert sorted(a.files) == sorted(b.files) and len(a.files) == 2 + 5 * 40
        for k in b.files:
            assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]), k
        assert a["de7"].dtype == np.float16
    back = F.load(tmp_path / "ours.npz")
    assert all(np.array_equal(x.descriptors, y.descriptors) and x.name == y.name for x, y in zip(feats, back))
    assert grew_mb < 20, grew_mb
