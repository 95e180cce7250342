"""Bundle adjustment of a :class:`MapState` through the shared :class:`Reconstruction` type.

``ba="colmap"`` runs pycolmap's Ceres adjuster (the reference); every other name runs
``polarref.ba.adjust`` with that parameterization. Intrinsics are held constant unless
``refine`` names groups (focal, pp, dist); refined cameras are copied back into the state and
the cached bearings of their observations recomputed.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

import numpy as np

from polarref.errors import PolarrefError
from polarref.geometry import Rigid3
from polarref.reconstruction import Image, Point3D, Reconstruction

if TYPE_CHECKING:
    from polarref.sfm.report import BARun, ColmapBARun

log = logging.getLogger(__name__)

from polarref.ba.parameterization import SFM_BA_NAMES as BA_NAMES  # noqa: E402  (the one registry)


def to_reconstruction(state, image_ids=None, track_ids=None, colors=None) -> Reconstruction:
    """Reconstruction with image id = index + 1, point id = track + 1, camera id = index + 1.

    Args:
        image_ids: image indices to include (default: all registered).
        track_ids: tracks whose points to include (default: all with a point); only their active
            observations in included images are written.
        colors: optional list of (K_i, 3) uint8 keypoint colours.
    """
    tr = state.tracks
    imgs = np.flatnonzero(state.registered) if image_ids is None else np.asarray(image_ids)
    tids = np.flatnonzero(state.has_point) if track_ids is None else np.asarray(track_ids)
    rec = Reconstruction()
    for c, cam in enumerate(state.cameras):
        rec.cameras[c + 1] = cam
    in_img = np.zeros(len(state.keypoints), bool)
    in_img[imgs] = True
    obs = np.flatnonzero(state.active & in_img[tr.image] & state.track_mask(tids)[tr.track])
    for i in imgs:
        i = int(i)
        rec.images[i + 1] = Image(i + 1, state.names[i], int(state.camera_of_image[i]) + 1,
                                  state.pose(i), state.keypoints[i],
                                  np.full(len(state.keypoints[i]), -1, np.int64))
    o_sorted = obs[np.argsort(tr.track[obs], kind="stable")]
    tk = tr.track[o_sorted]
    bounds = np.flatnonzero(np.diff(tk)) + 1
    for grp in np.split(o_sorted, bounds) if len(o_sorted) else []:
        t = int(tr.track[grp[0]])
        rows = np.stack([tr.image[grp] + 1, tr.keypoint[grp]], 1).astype(np.int64)
        col = colors[tr.image[grp[0]]][tr.keypoint[grp[0]]] if colors is not None else np.zeros(3, np.uint8)
        rec.points3D[t + 1] = Point3D(state.X[t].copy(), rows, -1.0, np.asarray(col, np.uint8))
        for im, kp in zip(tr.image[grp], tr.keypoint[grp]):
            rec.images[int(im) + 1].point3D_ids[int(kp)] = t + 1
    return rec


def _read_back(state, rec: Reconstruction, variable: list[int]) -> None:
    for i in variable:
        state.set_pose(i, rec.images[i + 1].cam_from_world)
    for pid, p in rec.points3D.items():
        state.X[pid - 1] = p.xyz
    for cid, cam in rec.cameras.items():
        c = cid - 1
        if state.cameras[c] != cam:
            from polarref.sfm import rays as R_

            state.cameras[c] = cam
            obs = np.flatnonzero(state.camera_of_image[state.tracks.image] == c)
            state.ray[obs] = R_.bearings(cam, state.uv[obs])


def _colmap_adjust(rec: Reconstruction, variable: list[int], fixed: list[int], max_iterations: int,
                   loss: str, refine: tuple = ()) -> ColmapBARun:
    import pycolmap

    from polarref.model.colmap import CeresSettings, bundle_adjustment_config, bundle_adjustment_options

    prec = rec.to_pycolmap()
    cfg = bundle_adjustment_config(prec, [i + 1 for i in variable + fixed], [i + 1 for i in fixed],
                                   constant_intrinsics=not refine)
    opts = bundle_adjustment_options(CeresSettings("sfm", function_tolerance=1e-6, max_num_iterations=max_iterations,
                                                   num_threads=1), loss, 1.0, refine)
    t0 = time.perf_counter()
    ba = pycolmap.create_default_bundle_adjuster(opts, cfg, prec)
    summary = ba.solve()
    cs = summary.ceres_summary if hasattr(summary, "ceres_summary") else summary
    wall = time.perf_counter() - t0
    for i in variable:
        pose = prec.images[i + 1].cam_from_world()
        rec.images[i + 1].cam_from_world = Rigid3(pose.rotation.matrix(), pose.translation)
    for pid, p in prec.points3D.items():
        rec.points3D[pid].xyz = np.array(p.xyz)
    if refine:
        from polarref.camera import Camera

        for cid in rec.cameras:
            rec.cameras[cid] = Camera.from_pycolmap(prec.cameras[cid])
    from polarref.sfm.report import ColmapBARun

    return ColmapBARun(loss, wall, list(refine), **{
        key: float(getattr(cs, key)) for key in ("initial_cost", "final_cost", "num_successful_steps",
                                                 "num_unsuccessful_steps") if hasattr(cs, key)})


def adjust(state, variable: list[int], fixed: list[int], ba: str, max_iterations: int,
           loss: str = "trivial", track_ids=None, refine: tuple = ()) -> BARun:
    """Adjust poses of ``variable`` images and the points (``track_ids`` or all) in place, and
    the intrinsics groups ``refine`` of the cameras involved.

    Returns the typed record of the run (the adjuster's summary with its iteration trace).
    """
    from polarref.sfm.report import BARun

    if ba not in BA_NAMES:
        raise PolarrefError(f"unknown bundle adjuster {ba!r}; choose one of {', '.join(BA_NAMES)}")
    rec = to_reconstruction(state, sorted(set(variable) | set(fixed)), track_ids)
    if not rec.points3D:
        return BARun(ba, skipped="no points")
    if ba == "colmap":
        info = BARun(ba, colmap=_colmap_adjust(rec, list(variable), list(fixed), max_iterations, loss,
                                               tuple(refine)))
    else:
        from polarref.ba import BAOptions, adjust as ba_adjust

        opts = BAOptions(param=ba, loss=loss, max_iterations=max_iterations, refine=tuple(refine))
        summary = ba_adjust(rec, opts, variable_image_ids=[i + 1 for i in variable],
                            fixed_image_ids=[i + 1 for i in fixed])
        summary.points_state = None  # internal landmark parameters: not part of the record
        info = BARun(ba, summary=summary)
    _read_back(state, rec, list(variable))
    return info
