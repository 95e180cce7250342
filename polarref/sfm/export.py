"""Our features and verified matches, for other tools (pycolmap's mapper in the comparison).

``compute_matches`` runs (or loads from cache) the first three stages exactly as
:func:`polarref.sfm.run_sfm` does; ``write_colmap_database`` writes them into a COLMAP database
so that ``pycolmap.incremental_mapping`` can run on the very same correspondences.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from polarref.core.errors import PolarrefError
from polarref.model import Reconstruction
from polarref.sfm.pipeline import (Matches, SfMConfig, cameras_for_images, load_images_and_features,
                                   match_and_verify)
from polarref.sfm.stages import StageClock, StageCost


def compute_matches(image_dir: str | Path, config: SfMConfig = SfMConfig(), camera=None,
                    gt: Reconstruction | None = None) -> tuple[Matches, list, np.ndarray, tuple[StageCost, ...]]:
    """Features + putative + verified matches of ``image_dir`` (cached like run_sfm).

    Returns:
        (matches, cameras, camera index per image, the stages' costs).
    """
    clock = StageClock()
    feats, _, fkey = load_images_and_features(Path(image_dir), config, clock)
    if len(feats) < 2:
        raise PolarrefError(f"{len(feats)} readable image(s) in {image_dir}; need at least 2")
    cameras, cam_idx = cameras_for_images([f.name for f in feats], [(f.width, f.height) for f in feats],
                                          camera, gt)
    return match_and_verify(feats, cameras, cam_idx, config, fkey, clock), cameras, cam_idx, tuple(clock.stages)


def write_colmap_database(db_path: str | Path, matches: Matches, cameras: list,
                          camera_of_image: np.ndarray, descriptors: bool = False,
                          overwrite: bool = False) -> tuple[int, ...]:
    """Write cameras (with ``has_prior_focal_length``), images, keypoints (COLMAP convention),
    putative matches and the verified two-view geometries (CALIBRATED, with E and the relative
    pose) into a new database, via :func:`polarref.peers.colmap_sfm.import_features`.

    Returns:
        the COLMAP image_id of each image, in ``matches.names`` order.
    Raises:
        PolarrefError: the database file already exists and ``overwrite`` is False.
    """
    from polarref.peers.colmap_sfm import import_features

    if descriptors and any(f.descriptors is None for f in matches.features):
        raise PolarrefError("the descriptors of these matches were not loaded: call "
                            "polarref.sfm.pipeline.ensure_descriptors first")
    done = import_features(Path(db_path), list(cameras), matches.names, [f.keypoints for f in matches.features],
                           matches.putative, camera_of_image=camera_of_image, verified=matches.geometries,
                           descriptors=[f.descriptors for f in matches.features] if descriptors else None,
                           overwrite=overwrite)
    return done.image_ids
