"""Strecha ground-truth cameras: parsing, convention check by epipolar geometry, bad input."""

from dataclasses import replace

import numpy as np
import pytest

from polarref.core.geometry import Rigid3
from polarref.io import FormatError
from polarref.io.strecha import (fundamental_matrix, read_strecha_camera, read_strecha_folder,
                                 sampson_error)


@pytest.fixture(scope="module")
def fountain(shared_data):
    return shared_data / "strecha_fountain-P11"


def test_reads_all_views(fountain):
    views = read_strecha_folder(fountain / "gt_dense_cameras")
    assert [v.name for v in views] == [f"{i:04d}.jpg" for i in range(11)]
    v = views[0]
    assert v.camera.model == "PINHOLE" and (v.camera.width, v.camera.height) == (3072, 2048)
    # K as stored, cx and cy + 0.5 (integer pixel centres -> COLMAP corner origin)
    np.testing.assert_allclose(v.camera.params, [2759.48, 2764.16, 1521.19, 1007.31])
    raw = read_strecha_folder(fountain / "gt_dense_cameras", pixel_offset=0.0)[0]
    np.testing.assert_allclose(raw.camera.principal_point, [1520.69, 1006.81])
    # the stored centre is the pose's centre; the stored R (rows 5-7) is world_from_cam
    np.testing.assert_allclose(v.cam_from_world.center, [-7.28137, -7.57667, 0.204446], atol=1e-9)
    np.testing.assert_allclose(v.cam_from_world.R.T[:, 0], [0.450927, -0.892535, 0.00679989],
                               atol=2e-6)


def test_read_ground_truth(fountain):
    from polarref.io.strecha import read_ground_truth
    rec = read_ground_truth(fountain / "gt_dense_cameras", ["0003.jpg", "0001.jpg"])
    assert [rec.images[i].name for i in (1, 2)] == ["0003.jpg", "0001.jpg"]
    assert len(rec.cameras) == 1  # fountain shares one K
    views = read_strecha_folder(fountain / "gt_dense_cameras")
    np.testing.assert_allclose(rec.images[1].cam_from_world.R, views[3].cam_from_world.R)
    with pytest.raises(FormatError, match="file not found"):
        read_ground_truth(fountain / "gt_dense_cameras", ["nope.jpg"])


def _sift_matches(path_a, path_b):
    cv2 = pytest.importorskip("cv2")
    sift = cv2.SIFT_create(nfeatures=4000)
    out = []
    for path in (path_a, path_b):
        img = cv2.imread(str(path), cv2.IMREAD_REDUCED_GRAYSCALE_4)  # quarter size: fast
        kps, desc = sift.detectAndCompute(img, None)
        out.append((np.array([k.pt for k in kps]) + 0.5, desc))  # OpenCV -> COLMAP pixels
    knn = cv2.BFMatcher().knnMatch(out[0][1], out[1][1], k=2)
    good = [m for m, n in knn if m.distance < 0.7 * n.distance]
    return (out[0][0][[g.queryIdx for g in good]], out[1][0][[g.trainIdx for g in good]])


def test_epipolar_consistency_of_sift_matches(fountain):
    views = read_strecha_folder(fountain / "gt_dense_cameras")
    ua, ub = _sift_matches(fountain / "images" / "0004.jpg", fountain / "images" / "0005.jpg")
    assert len(ua) > 300
    scale = 0.25
    va = replace(views[4], camera=views[4].camera.rescaled(scale))
    vb = replace(views[5], camera=views[5].camera.rescaled(scale))
    e = sampson_error(fundamental_matrix(va, vb), ua, ub) / scale  # in full-resolution px
    assert 0.05 < np.median(e) < 0.4 and np.mean(e < 4) > 0.9  # measured 0.18 px, 96 % < 4 px

    def world_to_cam(v):  # the other reading of rows 5-7
        R = v.cam_from_world.R.T
        return replace(v, cam_from_world=Rigid3(R, -R @ v.cam_from_world.center))

    e_wrong = sampson_error(fundamental_matrix(world_to_cam(va), world_to_cam(vb)), ua, ub) / scale
    assert np.median(e_wrong) > 50 * np.median(e)


def test_sampson_error_by_construction():
    rng = np.random.default_rng(0)
    from polarref.camera import Camera
    from polarref.io.strecha import StrechaView
    cam = Camera("PINHOLE", 640, 480, [500, 510, 320, 240])
    a = StrechaView("a", cam, Rigid3.identity(), np.zeros(3))
    b = StrechaView("b", cam, Rigid3.from_rotvec([0.05, -0.1, 0.02], [-1.0, 0.1, 0.05]), np.zeros(3))
    X = rng.uniform([-2, -2, 4], [2, 2, 8], (50, 3))
    ua = cam.project(a.cam_from_world.apply(X))
    ub = cam.project(b.cam_from_world.apply(X))
    F = fundamental_matrix(a, b)
    assert sampson_error(F, ua, ub).max() < 1e-9
    # a pure perpendicular shift of d px off the epipolar line gives Sampson error ~ d / sqrt(2)
    line = np.c_[ua, np.ones(50)] @ F.T
    normal = line[:, :2] / np.linalg.norm(line[:, :2], axis=1, keepdims=True)
    np.testing.assert_allclose(sampson_error(F, ua, ub + 0.3 * normal), 0.3 / np.sqrt(2), rtol=0.1)


GOOD = "100 0 50\n0 100 40\n0 0 1\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 2 3\n640 480\n"


@pytest.mark.parametrize("text, line, match", [
    (GOOD.replace("0 1 0\n", "0 1\n"), 6, "expected 3 values"),
    (GOOD.replace("1 2 3\n", "1 2 x\n"), 8, "bad number"),
    ("\n".join(GOOD.splitlines()[:8]) + "\n", 8, "expected 9 non-empty rows"),
    (GOOD.replace("1 0 0\n0 1 0", "2 0 0\n0 1 0"), 5, "not a rotation"),
    (GOOD.replace("640 480", "640 -1"), 9, "bad image size"),
])
def test_malformed_camera_files(tmp_path, text, line, match):
    path = tmp_path / "x.jpg.camera"
    path.write_text(text)
    with pytest.raises(FormatError, match=match) as info:
        read_strecha_camera(path)
    assert info.value.line == line and f"x.jpg.camera:{line}:" in str(info.value)


def test_minimal_good_file(tmp_path):
    path = tmp_path / "x.jpg.camera"
    path.write_text(GOOD)
    v = read_strecha_camera(path)
    assert v.name == "x.jpg"
    np.testing.assert_allclose(v.cam_from_world.center, [1, 2, 3])
