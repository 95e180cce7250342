"""Helpers for the synth tests: run pycolmap on a rendered scene with GT intrinsics fixed."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from polarref.geometry import Rigid3, rotation_angle_deg, umeyama
from synth.scene import Scene


def run_pycolmap(scene: Scene, work: Path, max_features: int = 4000) -> dict:
    """Extract SIFT, match exhaustively and map incrementally with fixed GT intrinsics.

    Returns {"registered", "total", "rot_err_deg" (per registered image), "center_err_rel"}.
    """
    import pycolmap

    work = Path(work)
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    db = work / "db.db"
    cam = scene.camera
    ext = pycolmap.FeatureExtractionOptions()
    ext.sift.max_num_features = max_features
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    reader.camera_params = ",".join(repr(float(p)) for p in cam.params)
    pycolmap.extract_features(db, scene.root / "images", image_names=[v.name for v in scene.views],
                              camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=ext, device=pycolmap.Device.cpu)
    pycolmap.match_exhaustive(db, device=pycolmap.Device.cpu)
    opts = pycolmap.IncrementalPipelineOptions()
    opts.ba_refine_focal_length = False
    opts.ba_refine_principal_point = False
    opts.ba_refine_extra_params = False
    opts.mapper.abs_pose_refine_focal_length = False
    opts.mapper.abs_pose_refine_extra_params = False
    opts.num_threads = 2
    recs = pycolmap.incremental_mapping(db, scene.root / "images", work / "sparse", options=opts)
    if not recs:
        return {"registered": 0, "total": len(scene.views), "rot_err_deg": np.array([np.inf]),
                "center_err_rel": np.inf}
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    gt = {v.name: v.cam_from_world for v in scene.views}
    names, est = [], []
    for image in rec.images.values():
        if not image.has_pose:
            continue
        m = image.cam_from_world().matrix()
        names.append(image.name)
        est.append(Rigid3(m[:, :3], m[:, 3]))
    src = np.array([e.center for e in est])
    dst = np.array([gt[n].center for n in names])
    sim = umeyama(src, dst)
    aligned = [sim.transform_pose(e) for e in est]
    rot = np.array([rotation_angle_deg(a.R, gt[n].R) for a, n in zip(aligned, names)])
    cerr = np.array([np.linalg.norm(a.center - gt[n].center) for a, n in zip(aligned, names)])
    return {"registered": len(names), "total": len(scene.views), "rot_err_deg": rot,
            "center_err_rel": float(cerr.mean() / scene.radius),
            "points": rec.num_points3D()}
