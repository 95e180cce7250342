"""Our features and verified matches written into a COLMAP database and mapped by pycolmap."""

import pytest

from polarref import metrics as M
from polarref.core.errors import PolarrefError
from polarref.peers.colmap_sfm import run_mapper
from polarref.model import Reconstruction
from polarref.sfm.export import compute_matches, write_colmap_database
from polarref.sfm.pipeline import PRESETS
from polarref.model.colmap import from_pycolmap, read_model


def test_pycolmap_maps_our_matches_with_fixed_intrinsics(request, tmp_path, monkeypatch):
    import dataclasses

    import pycolmap

    try:
        scene = request.getfixturevalue("comet_small_scene")
    except (ImportError, ModuleNotFoundError) as exc:
        pytest.skip(f"comet_small_scene unavailable: {exc}")
    gt = read_model(scene / "gt")
    cfg = dataclasses.replace(PRESETS["small"], cache_dir=str(tmp_path / "cache"))
    matches, cams, idx, _ = compute_matches(scene / "images", cfg, gt=gt)
    ids = write_colmap_database(tmp_path / "db.db", matches, cams, idx)
    assert len(ids) == len(set(ids)) == len(matches.names)
    with pytest.raises(PolarrefError, match="already exists"):
        write_colmap_database(tmp_path / "db.db", matches, cams, idx)
    pdb = pycolmap.Database.open(str(tmp_path / "db.db"))
    try:  # without the prior flag the incremental mapper re-estimates the focal length
        assert all(c.has_prior_focal_length for c in pdb.read_all_cameras())
        assert {im.image_id: im.name for im in pdb.read_all_images()} == dict(zip(ids, matches.names))
    finally:
        pdb.close()
    run = run_mapper(tmp_path / "db.db", scene / "images", tmp_path / "sparse", "incremental")
    rec = from_pycolmap(run.reconstruction)
    m = M.evaluate(rec, gt)
    # measured: 12/12, 1076 points, 0.19 px, 0.18 deg (focal held at GT 386.27; 369 and 0.74 deg
    # when the database camera lacks has_prior_focal_length)
    assert m.registered_images == len(matches.names)
    assert rec.cameras[1].params.tolist() == pytest.approx(list(gt.cameras[1].params), abs=1e-9)
    assert 0.0 < m.gt.rotation_error_deg_mean < 0.4
    assert 0.02 < m.mean_reprojection_error_px < 0.6
