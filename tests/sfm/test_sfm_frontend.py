"""The front end on several threads (polarref.sfm.frontend) gives exactly the one-thread result,
and every stage of a run is in its stage record (polarref.sfm.stages)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from polarref.model.colmap import read_model
from polarref.sfm.frontend import chunked, thread_count
from polarref.sfm.pipeline import PRESETS, cameras_for_images, load_images_and_features, match_and_verify, run_sfm
from polarref.sfm.stages import StageClock


def _front_end(scene, threads: int):
    gt = read_model(scene / "gt")
    cfg = dataclasses.replace(PRESETS["small"], use_cache=False, threads=threads)
    clock = StageClock()
    feats, _, key = load_images_and_features(scene / "images", cfg, clock)
    cams, idx = cameras_for_images([f.name for f in feats], [(f.width, f.height) for f in feats], None, gt)
    return feats, match_and_verify(feats, cams, idx, cfg, key, clock), clock


def test_two_threads_give_the_one_thread_features_and_matches(comet_small_scene):
    f1, m1, c1 = _front_end(comet_small_scene, 1)
    f2, m2, c2 = _front_end(comet_small_scene, 2)
    for a, b in zip(f1, f2, strict=True):
        np.testing.assert_array_equal(a.keypoints, b.keypoints)
        np.testing.assert_array_equal(a.descriptors, b.descriptors)
    assert list(m1.putative) == list(m2.putative) and len(m1.putative) == 66  # 12 views, exhaustive
    for p in m1.putative:
        np.testing.assert_array_equal(m1.putative[p], m2.putative[p])
    assert list(m1.geometries) == list(m2.geometries) and len(m1.geometries) > 20
    for p, g in m1.geometries.items():
        np.testing.assert_array_equal(g.inliers, m2.geometries[p].inliers)
        np.testing.assert_array_equal(g.cam2_from_cam1.R, m2.geometries[p].cam2_from_cam1.R)
        np.testing.assert_array_equal(g.cam2_from_cam1.t, m2.geometries[p].cam2_from_cam1.t)
    # matching and verification share their tasks on threads: the stage is split, none is lost
    for c in (c1, c2):
        assert [s.stage for s in c.stages] == ["features", "matching", "verification"]
        assert all(s.wall_s > 0 and s.cpu_s > 0 for s in c.stages)
    total = sum(s.wall_s for s in c2.stages[1:])
    assert 0 < c2.get("verification").wall_s < total


def test_same_model_for_the_same_seed_on_one_and_two_threads(comet_small_scene):
    gt = read_model(comet_small_scene / "gt")
    cfg = dataclasses.replace(PRESETS["small"], use_cache=False)
    runs = [run_sfm(comet_small_scene / "images", None, dataclasses.replace(cfg, threads=t), gt=gt) for t in (1, 2)]
    a, b = (r.report.metrics for r in runs)
    assert a.registered_images == b.registered_images == 12
    assert a.tie_points == b.tie_points and a.reprojected_px == b.reprojected_px
    assert a.gt.rotation_error_deg_mean == pytest.approx(b.gt.rotation_error_deg_mean, abs=1e-12)
    for r in runs:  # every stage counted, in order, with its CPU time
        names = [s.stage for s in r.stages]
        assert names[:5] == ["features", "matching", "verification", "tracks", "mapping"]
        assert "total" in names and all(s.cpu_s is None or s.cpu_s >= 0 for s in r.stages)


def test_thread_count_and_chunks(monkeypatch):
    from polarref.core.execution import available_cores

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert thread_count(3) == 3 and thread_count(0) == available_cores()
    monkeypatch.setenv("OMP_NUM_THREADS", "1")  # a Dask worker's job: one core
    assert thread_count(0) == 1 and thread_count(2) == 2
    pairs = [(i, i + 1) for i in range(100)]
    parts = chunked(pairs, 2)
    assert [p for c in parts for p in c] == pairs and len(parts) == 15  # ~8 per thread: 7 pairs each (100 / 16)
    assert chunked(pairs[:3], 2) == [pairs[:3]]
