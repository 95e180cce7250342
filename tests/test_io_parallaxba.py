"""ParallaxBA files: reading, the verified Euler convention, writing, bad input."""

import itertools

import numpy as np
import pytest

from polarref.geometry import axis_rotation, so3_exp
from polarref.io import FormatError
from polarref.io.parallaxba import (cam_from_world_rotation, euler_from_cam_from_world,
                                    read_parallaxba, reprojection_errors, triangulate_dlt,
                                    write_parallaxba)


@pytest.fixture(scope="module")
def fakepile(shared_data):
    return read_parallaxba(shared_data / "parallaxba_fakepile")


def test_counts_and_anchors(fakepile):
    p = fakepile
    assert (p.num_cameras, p.num_points, len(p.obs_uv)) == (47, 11318, 26050)
    assert np.array_equal(p.main_anchor, p.obs_camera[p.track_start[:-1]])
    np.testing.assert_allclose(p.K, [[1071.18, 0, 646.269], [0, 1070.36, 350.651], [0, 0, 1]])
    np.testing.assert_allclose(p.R @ np.swapaxes(p.R, 1, 2), np.broadcast_to(np.eye(3), p.R.shape),
                               atol=1e-14)
    camera = p.camera()
    assert camera.model == "PINHOLE" and camera.fx == 1071.18


def _alternatives(euler):
    a, b, g = euler.T
    rot = {"x": (0, g), "y": (1, b), "z": (2, a)}
    for order in itertools.permutations("xyz"):
        for transpose in (False, True):
            for sign in (1, -1):
                R = np.eye(3)
                for ax in order:
                    R = R @ axis_rotation(rot[ax][0], sign * rot[ax][1])
                yield "".join(order), transpose, sign, np.swapaxes(R, 1, 2) if transpose else R


def test_verified_convention_beats_every_alternative(fakepile):
    p = fakepile
    e = reprojection_errors(p, triangulate_dlt(p))
    assert not np.isnan(e).any()  # every observation in front of its camera
    med = np.median(e)
    assert 0.3 < med < 1.0  # measured 0.632 px (initial, noisy demo poses)
    others = []
    for order, transpose, sign, R in _alternatives(p.euler):
        if np.allclose(R, p.R):
            continue
        ea = reprojection_errors(p, triangulate_dlt(p, R), R)
        others.append(np.nanmedian(ea))
    assert len(others) == 22  # 24 combinations, two of them equal to the verified one
    assert min(others) > 10 * med


def test_cameras_look_at_the_scene(fakepile):
    p = fakepile
    X = triangulate_dlt(p)
    to_scene = np.median(X, axis=0) - p.centers
    to_scene /= np.linalg.norm(to_scene, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.sum(p.R[:, 2, :] * to_scene, axis=1)))
    assert angle.max() < 35  # measured max 29 deg; the README read literally gives up to 163 deg
    a, b, g = p.euler.T
    literal = axis_rotation(0, g) @ axis_rotation(1, b) @ axis_rotation(2, a)
    assert np.degrees(np.arccos(np.sum(literal[:, 2, :] * to_scene, axis=1))).max() > 90


def test_euler_round_trip():
    rng = np.random.default_rng(0)
    R = so3_exp(rng.normal(size=(100, 3)))
    np.testing.assert_allclose(cam_from_world_rotation(euler_from_cam_from_world(R)), R, atol=1e-13)


def test_write_read_round_trip(fakepile, tmp_path):
    write_parallaxba(fakepile, tmp_path)
    again = read_parallaxba(tmp_path)
    for field in fakepile.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(again, field), getattr(fakepile, field))


def _folder(tmp_path, cam="0 0 0 0 0 0\n0.1 0 0 1 0 0\n", feat="2 0 1 2 1 3 4\n",
            K="100 0 50\n0 100 40\n0 0 1\n"):
    (tmp_path / "Cam.txt").write_text(cam)
    (tmp_path / "Feature.pmba").write_text(feat)
    (tmp_path / "intrinsic_matrix.txt").write_text(K)
    return tmp_path


@pytest.mark.parametrize("kwargs, fname, line, match", [
    (dict(cam="0 0 0 0 0 0\n0.1 0 0 1 0\n"), "Cam.txt", 2, "expected 6 values"),
    (dict(feat="2 0 1 2 1 3 4\n3 0 1 2 1 3 4\n"), "Feature.pmba", 2, "needs 10 fields"),
    (dict(feat="2 0 1 2 5 3 4\n"), "Feature.pmba", 1, "camera index out of range"),
    (dict(feat="2 0 1 2 0 3 4\n"), "Feature.pmba", 1, "listed twice"),
    (dict(feat="2 0 1 2 1 3 x\n"), "Feature.pmba", 1, "bad number"),
    (dict(K="100 0 50\n0 100\n0 0 1\n"), "intrinsic_matrix.txt", 2, "expected 3 K entries"),
])
def test_malformed_files_name_file_and_line(tmp_path, kwargs, fname, line, match):
    folder = _folder(tmp_path, **kwargs)
    with pytest.raises(FormatError, match=match) as info:
        read_parallaxba(folder)
    assert info.value.line == line and info.value.path.name == fname
    assert f"{fname}:{line}:" in str(info.value)


def test_minimal_good_folder(tmp_path):
    p = read_parallaxba(_folder(tmp_path))
    assert p.num_points == 1 and p.main_anchor.tolist() == [0]
    np.testing.assert_allclose(p.t[1], -p.R[1] @ [1, 0, 0])


def test_to_reconstruction(fakepile):
    from polarref.io.parallaxba import parallaxba_to_reconstruction
    rec = parallaxba_to_reconstruction(fakepile)
    assert len(rec.images) == 47 and rec.num_observations == 26050
    e_rec = np.sort(rec.reprojection_errors())
    e = np.sort(reprojection_errors(fakepile, triangulate_dlt(fakepile)))
    np.testing.assert_allclose(e_rec, e, rtol=1e-9, atol=1e-9)
    # main anchors survive: the first track element of each point is its main anchor image
    first = np.array([rec.points3D[j + 1].track[0, 0] - 1 for j in range(fakepile.num_points)])
    np.testing.assert_array_equal(first, fakepile.main_anchor)
