"""Real data: Strecha fountain-P11 (11 photos, 3072x2048, GT cameras).

Features are detected on images downscaled to 1024x683 (INTER_AREA) and the keypoints scaled
back to full resolution, so the full-resolution GT camera is used unchanged (pycolmap likewise
with ``max_image_size=1024``).
"""

import dataclasses

import numpy as np
import pytest

from polarref import metrics as M
from polarref.peers.colmap_sfm import ColmapSfMOptions, run_sift_sfm
from polarref.model import Image, Reconstruction
from polarref.sfm.pipeline import PRESETS, run_sfm, with_ba
from polarref.model.colmap import from_pycolmap


def _fountain_gt(root):
    from polarref.io.strecha import read_strecha_folder

    views = read_strecha_folder(root / "gt_dense_cameras")
    gt = Reconstruction()
    gt.cameras[1] = views[0].camera
    for k, v in enumerate(views, start=1):
        assert np.allclose(v.camera.params, views[0].camera.params)
        gt.images[k] = Image(k, v.name, 1, v.cam_from_world)
    return gt


@pytest.mark.slow  # ~1-2 min: 8192 features on 11 images, exhaustive matching
def test_fountain_all_registered_and_accurate(shared_data, tmp_path):
    root = shared_data / "strecha_fountain-P11"
    gt = _fountain_gt(root)
    cfg = dataclasses.replace(with_ba(PRESETS["fountain"], "euclidean"), cache_dir=str(tmp_path / "cache"))
    ours = run_sfm(root / "images", tmp_path / "ours", cfg, gt=gt).report.to_json()
    run = run_sift_sfm(root / "images", gt.cameras[1], tmp_path / "colmap",
                       ColmapSfMOptions(max_num_features=8192, max_image_size=1024))
    ref = from_pycolmap(run.reconstruction)
    ref_m = M.evaluate(ref, gt, num_images=11)
    print("ours", ours["metrics"]["registered_images"], ours["metrics"]["tie_points"], ours["metrics"]["reprojected_px"],
          ours["metrics"]["mean_reprojection_error_px"], ours["metrics"]["gt"]["rotation_error_deg_mean"],
          ours["metrics"]["gt"]["rotation_error_deg_max"], ours["metrics"]["gt"]["center_error_rel_mean"], ours["runtime_s"].get("total"))
    print("pycolmap", ref_m.registered_images, ref_m.tie_points, ref_m.reprojected_px,
          ref_m.mean_reprojection_error_px, ref_m.gt.rotation_error_deg_mean, ref_m.gt.rotation_error_deg_max,
          ref_m.gt.center_error_rel_mean)
    # measured: ours 11/11, 0.031 deg mean (0.047 max), 5612 points, 0.385 px
    assert ours["metrics"]["registered_images"] == 11
    assert 0.0 < ours["metrics"]["gt"]["rotation_error_deg_mean"] <= 0.2
    assert ours["metrics"]["gt"]["center_error_rel_mean"] < 0.01
    assert 0.05 < ours["metrics"]["mean_reprojection_error_px"] < 1.0
    assert ours["metrics"]["tie_points"] >= 0.9 * ref_m.tie_points
