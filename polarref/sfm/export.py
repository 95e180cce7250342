"""Our features and verified matches, for other tools (pycolmap's mapper in the comparison).

``compute_matches`` runs (or loads from cache) the first three stages exactly as
:func:`polarref.sfm.run_sfm` does; ``write_colmap_database`` writes them into a COLMAP database
so that ``pycolmap.incremental_mapping`` can run on the very same correspondences.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from polarref.errors import PolarrefError
from polarref.geometry import skew
from polarref.reconstruction import Reconstruction
from polarref.sfm.pipeline import (Matches, SfMConfig, cameras_for_images, load_images_and_features,
                                   match_and_verify)


def compute_matches(image_dir: str | Path, config: SfMConfig = SfMConfig(), camera=None,
                    gt: Reconstruction | None = None) -> tuple[Matches, list, np.ndarray, dict]:
    """Features + putative + verified matches of ``image_dir`` (cached like run_sfm).

    Returns:
        (matches, cameras, camera index per image, timings {stage: s}).
    """
    timings: dict = {}
    feats, _, fkey = load_images_and_features(Path(image_dir), config, timings)
    if len(feats) < 2:
        raise PolarrefError(f"{len(feats)} readable image(s) in {image_dir}; need at least 2")
    cameras, cam_idx = cameras_for_images([f.name for f in feats], [(f.width, f.height) for f in feats],
                                          camera, gt)
    return match_and_verify(feats, cameras, cam_idx, config, fkey, timings), cameras, cam_idx, timings


def write_colmap_database(db_path: str | Path, matches: Matches, cameras: list,
                          camera_of_image: np.ndarray, descriptors: bool = False) -> dict[str, int]:
    """Write cameras, images, keypoints (COLMAP convention), putative matches and the verified
    two-view geometries (CALIBRATED, with E and the relative pose) into a new database.

    Returns:
        {image name: COLMAP image_id}.
    Raises:
        PolarrefError: the database file already exists.
    """
    import pycolmap

    db_path = Path(db_path)
    if db_path.exists():
        raise PolarrefError(f"database {db_path} already exists; not touching it")
    db = pycolmap.Database.open(str(db_path))
    try:
        cam_ids = []
        for c in cameras:
            pc = c.to_pycolmap()
            # Without this flag COLMAP's mapper re-estimates the focal length despite
            # ba_refine_focal_length = False (measured: fx 386 -> 369, 0.74 deg rotation error).
            pc.has_prior_focal_length = True
            cam_ids.append(db.write_camera(pc))
        ids = {}
        for i, f in enumerate(matches.features):
            img = pycolmap.Image(name=f.name, camera_id=int(cam_ids[camera_of_image[i]]))
            image_id = db.write_image(img)
            ids[f.name] = image_id
            db.write_keypoints(image_id, np.asarray(f.keypoints, dtype=np.float32))
            if descriptors:
                d = np.clip(np.round(f.descriptors * 512.0), 0, 255).astype(np.uint8)
                db.write_descriptors(image_id, d)
        names = matches.names
        for (i, j), m in matches.putative.items():
            db.write_matches(ids[names[i]], ids[names[j]], m.astype(np.uint32))
        for (i, j), g in matches.geometries.items():
            tvg = pycolmap.TwoViewGeometry()
            tvg.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
            tvg.inlier_matches = g.inliers.astype(np.uint32)
            R, t = g.cam2_from_cam1.R, g.cam2_from_cam1.t
            tvg.E = skew(t) @ R
            tvg.cam2_from_cam1 = pycolmap.Rigid3d(pycolmap.Rotation3d(R), t)
            db.write_two_view_geometry(ids[names[i]], ids[names[j]], tvg)
    finally:
        db.close()
    return ids
