"""polarref.peers.colmap_sfm: options, database import and bad input (no images needed).

The end-to-end runs (pycolmap SIFT + mapping vs ground truth) are in test_sfm_pipeline.py,
test_sfm_export.py and test_synth_render.py.
"""

import numpy as np
import pytest

from polarref.camera import Camera
from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3, so3_exp
from polarref.peers import colmap_sfm as C

CAM = Camera("PINHOLE", 320, 240, [386.27, 386.27, 160.0, 120.0])


def test_options_hold_intrinsics_fixed_in_both_mappers():
    opts = C.ColmapSfMOptions(seed=7, num_threads=1)
    inc = C.incremental_options(opts)
    assert not (inc.ba_refine_focal_length or inc.ba_refine_principal_point or inc.ba_refine_extra_params)
    assert not (inc.mapper.abs_pose_refine_focal_length or inc.mapper.abs_pose_refine_extra_params)
    assert inc.random_seed == inc.mapper.random_seed == 7 and inc.num_threads == 1
    glo = C.global_options(opts).mapper.bundle_adjustment
    assert not (glo.refine_focal_length or glo.refine_principal_point or glo.refine_extra_params)
    assert C.global_options(opts).random_seed == 7


@pytest.mark.parametrize("kw", [dict(seed=-1), dict(num_threads=0), dict(max_num_features=0)])
def test_bad_options_raise(kw):
    with pytest.raises(ValueError):
        C.ColmapSfMOptions(**kw)


def _two_images(rng):
    kps = [rng.uniform(0, 240, (30, 2)), rng.uniform(0, 240, (25, 2))]
    m = np.stack([np.arange(20), np.arange(20)[::-1]], 1)
    return kps, m


def test_import_writes_prior_focal_and_canonical_pairs(tmp_path):
    import pycolmap

    rng = np.random.default_rng(0)
    kps, m = _two_images(rng)
    pose = Rigid3(so3_exp(np.array([0.0, 0.1, 0.02])), np.array([1.0, 0.0, 0.0]))

    class Geom:  # given as (1, 0): stored as (0, 1) with the inverse pose and swapped columns
        inliers = m[:15, ::-1]
        cam2_from_cam1 = pose.inverse()

    done = C.import_features(tmp_path / "db.db", CAM, ["a.png", "b.png"], kps, {(1, 0): m[:, ::-1]},
                                     verified={(1, 0): Geom()})
    ids = dict(zip(["a.png", "b.png"], done.image_ids))
    assert len(set(done.image_ids)) == 2 and done.import_s >= 0.0 and done.verification_s is None
    db = pycolmap.Database.open(str(tmp_path / "db.db"))
    try:
        (cam,) = db.read_all_cameras()
        assert cam.has_prior_focal_length and np.allclose(cam.params, CAM.params)
        assert np.allclose(db.read_keypoints(ids["b.png"])[:, :2], kps[1], atol=1e-4)
        assert np.array_equal(db.read_matches(ids["a.png"], ids["b.png"]), m)
        (geom,) = db.read_two_view_geometries()[1]
        assert np.array_equal(geom.inlier_matches, m[:15])
        assert np.allclose(geom.cam2_from_cam1.rotation.matrix(), pose.R, atol=1e-9)
        assert np.allclose(geom.cam2_from_cam1.translation, pose.t, atol=1e-9)
    finally:
        db.close()
    assert C.count_verified_pairs(tmp_path / "db.db") == 1
    with pytest.raises(PolarrefError, match="already exists"):
        C.import_features(tmp_path / "db.db", CAM, ["a.png", "b.png"], kps, {})
    C.import_features(tmp_path / "db.db", CAM, ["a.png", "b.png"], kps, {}, overwrite=True)
    assert C.count_verified_pairs(tmp_path / "db.db") == 0


def test_import_bad_input(tmp_path):
    rng = np.random.default_rng(1)
    kps, m = _two_images(rng)
    with pytest.raises(PolarrefError, match="keypoint arrays"):
        C.import_features(tmp_path / "a.db", CAM, ["a.png"], kps, {})
    with pytest.raises(PolarrefError, match="camera_of_image"):
        C.import_features(tmp_path / "b.db", [CAM], ["a.png", "b.png"], kps, {}, camera_of_image=[0, 1])
    with pytest.raises(PolarrefError, match="negative"):
        C.import_features(tmp_path / "c.db", CAM, ["a.png", "b.png"], kps, {(0, 1): m - 5}, verified={})
    assert not any(tmp_path.glob("*.db"))  # bad input leaves no partial database
    with pytest.raises(PolarrefError, match="unknown pycolmap mapper"):
        C.run_mapper(tmp_path / "c.db", tmp_path, tmp_path / "sparse", "hybrid")
