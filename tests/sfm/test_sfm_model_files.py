"""Model files of ``polarref sfm``: PLY read by a standard reader, binary model equal to the text one."""

import numpy as np
import pytest

from polarref.ba.synthetic import synthetic_reconstruction
from polarref.sfm.model_files import write_model


@pytest.fixture
def model():
    _, rec = synthetic_reconstruction(5, 80, seed=7, noise_px=0.3)
    rng = np.random.default_rng(1)
    for p in rec.points3D.values():
        p.color = rng.integers(0, 256, 3).astype(np.uint8)
        p.error = float(rng.uniform(0.1, 0.9))
    return rec


def test_ply_opens_with_plyfile_and_matches_the_model(model, tmp_path):
    plyfile = pytest.importorskip("plyfile", reason="plyfile (test extra) not installed")
    write_model(model, tmp_path / "m", "text")
    ply = plyfile.PlyData.read(str(tmp_path / "m" / "points3D.ply"))
    assert ply.text is False and ply.byte_order == "<"
    v = ply["vertex"]
    ids = sorted(model.points3D)
    assert len(v) == len(ids) == 80
    xyz = np.column_stack([v["x"], v["y"], v["z"]]).astype(np.float64)
    want = np.array([model.points3D[i].xyz for i in ids])
    np.testing.assert_allclose(xyz, want, rtol=2e-7, atol=1e-6 * np.abs(want).max())
    rgb = np.column_stack([v["red"], v["green"], v["blue"]])
    np.testing.assert_array_equal(rgb, [model.points3D[i].color for i in ids])


def test_binary_model_reads_back_equal_to_text(model, tmp_path):
    import pycolmap

    write_model(model, tmp_path / "txt", "text")
    write_model(model, tmp_path / "bin", "binary")
    assert not (tmp_path / "bin" / "cameras.txt").exists() and (tmp_path / "bin" / "images.bin").exists()
    a, b = pycolmap.Reconstruction(str(tmp_path / "txt")), pycolmap.Reconstruction(str(tmp_path / "bin"))
    assert sorted(a.images) == sorted(b.images) == sorted(model.images)
    assert sorted(a.points3D) == sorted(b.points3D) == sorted(model.points3D)
    for i in a.images:
        pa, pb = a.images[i].cam_from_world(), b.images[i].cam_from_world()
        np.testing.assert_allclose(pa.matrix(), pb.matrix(), atol=1e-12)
        np.testing.assert_allclose(pa.matrix()[:, 3], model.images[i].cam_from_world.t, atol=1e-12)
        assert a.images[i].name == b.images[i].name
        np.testing.assert_allclose([p.xy for p in a.images[i].points2D], [p.xy for p in b.images[i].points2D])
    for k in a.points3D:
        pa, pb = a.points3D[k], b.points3D[k]
        np.testing.assert_allclose(pa.xyz, pb.xyz, rtol=1e-15)
        np.testing.assert_array_equal(pa.color, pb.color)
        assert [(e.image_id, e.point2D_idx) for e in pa.track.elements] == \
            [(e.image_id, e.point2D_idx) for e in pb.track.elements]
    for c in a.cameras:
        np.testing.assert_allclose(a.cameras[c].params, b.cameras[c].params, rtol=1e-15)
    # Switching format leaves one model in the folder, not two.
    write_model(model, tmp_path / "bin", "text")
    assert not (tmp_path / "bin" / "images.bin").exists() and (tmp_path / "bin" / "images.txt").exists()


def test_bad_format_and_nan_points_are_refused(model, tmp_path):
    with pytest.raises(ValueError, match="unknown model format"):
        write_model(model, tmp_path / "m", "ply")
    next(iter(model.points3D.values())).xyz = np.array([np.nan, 0.0, 0.0])
    with pytest.raises(ValueError, match="non-finite"):
        write_model(model, tmp_path / "m2", "text")
