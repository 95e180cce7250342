"""pycolmap's pose-prior mapper as the peer (peers/colmap_priors.py): the priors reach its
database and its model comes out in the priors' frame."""

import os

import numpy as np
import pytest

from polarref.core.errors import PolarrefError


def _linked(scene, tmp_path):
    for name in ("images", "gt", "depth", "mesh.ply", "scene.json"):
        os.symlink(os.path.realpath(scene / name), tmp_path / name)


@pytest.mark.slow
def test_prior_mapper_model_is_in_the_priors_frame(uav_small_scene, tmp_path):
    from polarref.georef.formats import load_georef
    from polarref.model.colmap import from_pycolmap, read_model
    from polarref.peers.colmap_priors import run_prior_mapper, similarity_to_control, write_pose_priors
    from polarref.peers.colmap_sfm import extract_and_match_sift
    from synth.uav import gcp_layout

    _linked(uav_small_scene, tmp_path)
    g, m, p = gcp_layout(tmp_path, 4, 4, 0.5, 0)
    gt = read_model(tmp_path / "gt")
    names = sorted(im.name for im in gt.images.values())
    geo = load_georef(names, p, g, m)
    db = tmp_path / "db" / "database.db"
    extract_and_match_sift(tmp_path / "images", next(iter(gt.cameras.values())), db)
    with pytest.raises(PolarrefError, match="database lacks"):
        write_pose_priors(db, geo.priors + (geo.priors[0].__class__("nope.png", np.zeros(3), np.ones(3)),))
    run = run_prior_mapper(db, tmp_path / "images", tmp_path / "map", geo.priors)
    rec = from_pycolmap(run.reconstruction)
    by = {im.name: im.cam_from_world.center for im in gt.images.values()}
    d = np.array([im.cam_from_world.center - by[im.name] for im in rec.images.values()])
    # no alignment applied: metres from the truth (2 m / 4 m priors), not an arbitrary frame
    assert len(d) == 12 and np.sqrt((d**2).mean()) < 6.0
    # the similarity onto the control points brings the check points to decimetres
    from polarref.georef.adjust import check_stats, triangulate_marks
    from polarref.georef.formats import Role

    assert similarity_to_control(rec, geo) == 4
    chk = geo.of_role(Role.CHECK)
    st = check_stats(triangulate_marks(rec, geo.marks, [q.id for q in chk]), chk)
    assert st.count == 4 and st.rmse_horizontal < 0.5
