"""pycolmap's pose-prior mapping (COLMAP 4.x): the peer of our georeferenced adjustment (issue 33).

API used (pycolmap 4.2.1): the database ``pose_priors`` table, written with
``Database.write_pose_prior(PosePrior(position, position_covariance,
coordinate_system=CARTESIAN, corr_data_id=image.data_id))``, and the incremental pipeline with
``IncrementalPipelineOptions.use_prior_position = True`` (COLMAP's former ``pose_prior_mapper``):
the database cache loads the priors, and every global BA is a ``PosePriorBundleAdjuster``, which
first aligns the model to the prior positions by a RANSAC similarity and then adds one position
residual per image weighted by its covariance (trivial loss unless
``use_robust_loss_on_prior_position``). COLMAP takes position priors only: attitude priors and
ground control points have no place in it, so a "priors + GCPs" row for pycolmap is its
prior-mapped model moved by a similarity onto the control points (see :func:`similarity_to_control`),
not an adjustment.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from polarref.core.errors import PolarrefError
from polarref.core.geometry import umeyama
from polarref.georef.adjust import triangulate_marks
from polarref.georef.formats import Georef, PosePrior, Role
from polarref.model.colmap import incremental_options
from polarref.peers.colmap_sfm import ColmapSfMOptions, ColmapSfMRun, copy_database, largest_model


def _pycolmap():
    import pycolmap

    return pycolmap


def write_pose_priors(db_path: Path, priors: Sequence[PosePrior]) -> int:
    """Position priors (diagonal covariance from the sigmas) into the database's ``pose_priors``
    table, matched to its images by name; returns how many were written."""
    pycolmap = _pycolmap()
    db = pycolmap.Database.open(str(db_path))
    try:
        by_name = {im.name: im for im in db.read_all_images()}
        missing = [p.name for p in priors if p.name not in by_name]
        if missing:
            raise PolarrefError(f"{db_path}: pose prior for image {missing[0]!r}, which the database lacks")
        db.clear_pose_priors()
        for p in priors:
            db.write_pose_prior(pycolmap.PosePrior(
                position=np.asarray(p.centre, float), position_covariance=np.diag(np.asarray(p.sigma, float) ** 2),
                coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN,
                corr_data_id=by_name[p.name].data_id))
        return int(db.num_pose_priors())
    finally:
        db.close()


def run_prior_mapper(db_path: Path, image_dir: Path, out_dir: Path, priors: Sequence[PosePrior],
                     opts: ColmapSfMOptions = ColmapSfMOptions(), *, robust_loss: bool = False) -> ColmapSfMRun:
    """Incremental mapping of (a private copy of) ``db_path`` with ``priors`` in its global BA.

    The output model is in the priors' frame (metres), as pycolmap leaves it."""
    pycolmap = _pycolmap()
    out_dir = Path(out_dir)
    db = copy_database(db_path, out_dir / "database.db")
    write_pose_priors(db, priors)
    options = incremental_options(opts)
    options.use_prior_position = True
    options.use_robust_loss_on_prior_position = robust_loss
    t0 = time.perf_counter()
    recs = pycolmap.incremental_mapping(str(db), str(image_dir), str(out_dir / "sparse"), options=options)
    return largest_model(recs, db, time.perf_counter() - t0)


def similarity_to_control(rec, georef: Georef) -> int:
    """Move ``rec`` (our Reconstruction, in place) by the least-squares similarity taking its
    triangulated control points onto their given coordinates; returns how many were used.

    This is what a pycolmap user can do with GCPs: a 7-parameter transformation after the
    mapping, no adjustment (the model's shape is unchanged)."""
    ctl = georef.of_role(Role.CONTROL)
    used, X = triangulate_marks(rec, georef.marks, [p.id for p in ctl]).matched(ctl)
    if len(used) < 3:
        raise PolarrefError(f"similarity to control points: {len(used)} triangulated, 3 needed")
    sim = umeyama(X, np.array([p.xyz for p in used]))
    for im in rec.images.values():
        im.cam_from_world = sim.transform_pose(im.cam_from_world)
    for p in rec.points3D.values():
        p.xyz = sim.apply(p.xyz[None])[0]
    return len(used)
