"""Bundle adjustment of a :class:`MapState`: polarref's adjusters straight from its arrays.

``ba="colmap"`` runs pycolmap's Ceres adjuster (the reference); every other name runs
``polarref.ba.adjust`` with that parameterization. Intrinsics are held constant unless
``refine`` names groups (focal, pp, dist); refined cameras are copied back into the state and
the cached bearings of their observations recomputed.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3
from polarref.model import Image, Point3D, Reconstruction
from polarref.sfm.ba_runs import BARun, ColmapBARun, ExportedBA

log = logging.getLogger(__name__)

from polarref.ba.parameterization import SFM_BA_NAMES as BA_NAMES  # noqa: E402  (the one registry)
from polarref.model.colmap import to_pycolmap
from polarref.ba.export_problem import ExportedOptions, MapperResult  # noqa: E402


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

    prec = to_pycolmap(rec)
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
    return ColmapBARun(loss, wall, list(refine), **{
        key: float(getattr(cs, key)) for key in ("initial_cost", "final_cost", "num_successful_steps",
                                                 "num_unsuccessful_steps") if hasattr(cs, key)})


def problem_from_state(state, variable: list[int], fixed: list[int], track_ids=None):
    """A :class:`polarref.ba.BAProblem` straight from the map arrays (no Reconstruction).

    Holds the points ``track_ids`` (default: every point) and their active observations in the
    ``variable`` and ``fixed`` images; images are ordered by index and points by track, as
    :func:`polarref.ba.problem_from_reconstruction` orders them, so both give the same solve.
    Returns None when no observation is left.
    """
    from polarref.ba import BAProblem
    from polarref.model.observations import Observations

    tr = state.tracks
    imgs = np.unique(np.asarray(list(variable) + list(fixed), np.int64))
    in_img = np.zeros(len(state.keypoints), bool)
    in_img[imgs] = True
    obs = state.obs_of_tracks(track_ids)
    obs = obs[state.active[obs] & in_img[tr.image[obs]] & state.has_point[tr.track[obs]]]
    if not len(obs):
        return None
    pts, obs_pt = np.unique(tr.track[obs], return_inverse=True)
    imgs, obs_cam = np.unique(tr.image[obs], return_inverse=True)
    var = np.zeros(len(state.keypoints), bool)
    var[list(variable)] = True
    var[list(fixed)] = False
    cam_of = state.camera_of_image[imgs]
    p = BAProblem(cameras=[state.cameras[c] for c in cam_of], R=state.R[imgs].copy(),
                  C=state.centers()[imgs] if len(imgs) else np.zeros((0, 3)), X=state.X[pts].copy(),
                  obs=Observations.from_arrays(obs_cam.astype(np.int64), obs_pt.astype(np.int64),
                                               state.uv[obs].copy()),
                  cam_fixed=~var[imgs], image_ids=imgs + 1,
                  point_ids=pts + 1)
    p.camera_group = np.unique(cam_of, return_inverse=True)[1].astype(np.int64)
    return p


def _write_back_state(state, problem) -> None:
    """Copy the adjusted variable poses, the points and refined intrinsics into ``state``."""
    from polarref.sfm import rays as R_

    imgs = np.asarray(problem.image_ids, np.int64) - 1
    moved = problem.cam_mask.any(1)
    t = problem.cam_from_world_t()
    state.R[imgs[moved]] = problem.R[moved]
    state.t[imgs[moved]] = t[moved]
    state.X[np.asarray(problem.point_ids, np.int64) - 1] = problem.X
    for k, i in enumerate(imgs):
        c = int(state.camera_of_image[i])
        if state.cameras[c] != problem.cameras[k]:
            state.cameras[c] = problem.cameras[k]
            obs = np.flatnonzero(state.camera_of_image[state.tracks.image] == c)
            state.ray[obs] = R_.bearings(problem.cameras[k], state.uv[obs])


def adjust(state, variable: list[int], fixed: list[int], ba: str, max_iterations: int,
           loss: str = "trivial", track_ids=None, refine: tuple = (),
           function_tolerance: float = 1e-6, priors=None, export: bool = False) -> BARun:
    """Adjust poses of ``variable`` images and the points (``track_ids`` or all) in place, and
    the intrinsics groups ``refine`` of the cameras involved.

    polarref's adjusters get their problem straight from the map arrays (only the window's
    observations are gathered); pycolmap's goes through a Reconstruction.
    ``priors`` (a :class:`polarref.sfm.priors_hook.PriorHook`) adds the pose priors of the
    variable cameras (our adjusters only). Returns the typed record of the run (the adjuster's
    summary with its iteration trace); with ``export`` (our adjusters only) it also holds a copy
    of the problem as it entered the solver and the solve's result (``BARun.exported``).
    """
    if ba not in BA_NAMES:
        raise PolarrefError(f"unknown bundle adjuster {ba!r}; choose one of {', '.join(BA_NAMES)}")
    if ba == "colmap":
        rec = to_reconstruction(state, sorted(set(variable) | set(fixed)), track_ids)
        if not rec.points3D:
            return BARun(ba, skipped="no points")
        info = BARun(ba, colmap=_colmap_adjust(rec, list(variable), list(fixed), max_iterations, loss,
                                               tuple(refine)))
        _read_back(state, rec, list(variable))
        return info
    from polarref.ba import BAOptions, prepare, solve

    problem = problem_from_state(state, variable, fixed, track_ids)
    if problem is None:
        return BARun(ba, skipped="no points")
    if priors is not None:
        problem.priors = priors.for_problem(problem)
    opts = BAOptions(param=ba, loss=loss, max_iterations=max_iterations, refine=tuple(refine),
                     function_tolerance=function_tolerance)
    entered = problem.copy() if export else None
    prepare(problem)
    summary = solve(problem, opts, prepared=True)
    _write_back_state(state, problem)
    summary.points_state = None  # internal landmark parameters: not part of the record
    run = BARun(ba, summary=summary)
    if entered is not None:
        run.exported = ExportedBA(entered, ExportedOptions(ba, loss, max_iterations, function_tolerance,
                                                           tuple(opts.refine)), _result(problem, summary))
    return run


def _result(problem, summary) -> MapperResult:
    """The solved (prepared) problem's poses and points, by id, with the solve's costs."""
    return MapperResult(float(summary.initial_cost), float(summary.final_cost), int(summary.iterations),
                        np.asarray(problem.image_ids).copy(), problem.R.copy(), problem.C.copy(),
                        np.asarray(problem.point_ids).copy(), problem.X.copy())
