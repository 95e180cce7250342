"""pycolmap's incremental SfM on the same images with the same FIXED intrinsics (test reference).

Not a test module (no ``test_`` prefix); imported by tests/test_sfm_*.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def run_pycolmap(image_dir: Path, camera, work: Path, max_num_features: int = 4096,
                 max_image_size: int = 0, seed: int = 0):
    """Feature extraction, exhaustive matching, incremental mapping; the largest model.

    Intrinsics are held constant everywhere (see shared/notes/pycolmap-4.2.1.md).
    Returns a ``polarref.reconstruction.Reconstruction``.
    """
    import pycolmap

    from polarref.reconstruction import Reconstruction

    work.mkdir(parents=True, exist_ok=True)
    db = work / "database.db"
    if db.exists():
        db.unlink()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera.model
    reader.camera_params = ",".join(repr(float(v)) for v in np.asarray(camera.params))
    ext = pycolmap.FeatureExtractionOptions()
    ext.sift.max_num_features = max_num_features
    ext.num_threads = 1
    if max_image_size:
        ext.max_image_size = max_image_size
    pycolmap.extract_features(db, image_dir, camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=ext, device=pycolmap.Device.cpu)
    mopt = pycolmap.FeatureMatchingOptions()
    mopt.num_threads = 1
    pycolmap.match_exhaustive(db, matching_options=mopt, device=pycolmap.Device.cpu)
    opts = pycolmap.IncrementalPipelineOptions()
    opts.ba_refine_focal_length = opts.ba_refine_principal_point = opts.ba_refine_extra_params = False
    opts.mapper.abs_pose_refine_focal_length = opts.mapper.abs_pose_refine_extra_params = False
    opts.num_threads = 1
    opts.random_seed = seed
    recs = pycolmap.incremental_mapping(db, image_dir, work / "sparse", options=opts)
    if not recs:
        return None
    best = max(recs.values(), key=lambda r: r.num_reg_images())
    return Reconstruction.from_pycolmap(best)
