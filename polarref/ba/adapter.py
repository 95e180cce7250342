"""Reconstruction <-> BAProblem, and :func:`adjust`, the entry point the SfM pipeline calls."""

from __future__ import annotations

import numpy as np

from polarref.ba.options import BAOptions, BASummary
from polarref.ba.problem import BAProblem, prepare
from polarref.ba.entry import solve
from polarref.ba.intrinsics import default_groups
from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3
from polarref.model import build_reconstruction


def problem_from_reconstruction(rec, *, variable_image_ids=None, fixed_image_ids=None,
                                variable_point_ids=None) -> BAProblem:
    """Build a BAProblem from a :class:`polarref.model.Reconstruction`.

    Point set: ``variable_point_ids`` if given; else the points seen by the variable images
    when ``variable_image_ids`` is given; else all points. Every image observing a chosen point
    enters the problem; it is variable when listed in ``variable_image_ids`` (default: all) and
    not in ``fixed_image_ids``.
    """
    if not rec.images or not rec.points3D:
        raise PolarrefError(f"bundle adjustment: empty reconstruction ({len(rec.images)} images, "
                            f"{len(rec.points3D)} points)")
    fixed = set(int(i) for i in (fixed_image_ids or ()))
    variable = (set(int(i) for i in rec.images) if variable_image_ids is None
                else set(int(i) for i in variable_image_ids))
    unknown = (fixed | variable) - set(rec.images)
    if unknown:
        raise PolarrefError(f"bundle adjustment: unknown image ids {sorted(unknown)[:5]}")
    variable -= fixed
    if variable_point_ids is not None:
        pids = sorted(int(p) for p in variable_point_ids)
        missing = [p for p in pids if p not in rec.points3D]
        if missing:
            raise PolarrefError(f"bundle adjustment: unknown point ids {missing[:5]}")
    elif variable_image_ids is not None:
        chosen = set()
        for i in variable:
            ids = rec.images[i].point3D_ids
            chosen.update(int(p) for p in ids[ids >= 0] if int(p) in rec.points3D)
        pids = sorted(chosen)
    else:
        pids = sorted(rec.points3D)
    if not pids:
        raise PolarrefError("bundle adjustment: no 3D points to adjust")
    obs, image_ids, _ = rec.flat_observations(pids)
    if len(image_ids) == 0:
        raise PolarrefError("bundle adjustment: the chosen points have no observations")
    known = obs.image >= 0
    imgs = [rec.images[int(i)] for i in image_ids]
    R = np.array([im.cam_from_world.R for im in imgs])
    C = np.array([im.cam_from_world.center for im in imgs])
    X = np.array([rec.points3D[p].xyz for p in pids], np.float64)
    cam_fixed = np.array([int(i) not in variable for i in image_ids])
    problem = BAProblem(cameras=[rec.cameras[im.camera_id] for im in imgs], R=R, C=C, X=X,
                        obs=obs,
                        cam_fixed=cam_fixed, image_ids=image_ids,
                        point_ids=np.array(pids, np.int64))
    problem.exclusions["observations_unknown_image"] = int((~known).sum())
    # images of one camera id share intrinsics when they are refined
    cam_ids = np.array([im.camera_id for im in imgs])
    problem.camera_group = np.unique(cam_ids, return_inverse=True)[1].astype(np.int64)
    return problem


def write_back(rec, problem: BAProblem) -> None:
    """Copy the adjusted variable poses and the points back into ``rec``."""
    t = problem.cam_from_world_t()
    for k, i in enumerate(problem.image_ids):
        if problem.cam_mask is not None and problem.cam_mask[k].any():
            rec.images[int(i)].cam_from_world = Rigid3(problem.R[k], t[k])
    for k, p in enumerate(problem.point_ids):
        rec.points3D[int(p)].xyz = problem.X[k].copy()
    for k, i in enumerate(problem.image_ids):  # refined intrinsics (unchanged when held fixed)
        cid = rec.images[int(i)].camera_id
        if rec.cameras[cid] != problem.cameras[k]:
            rec.cameras[cid] = problem.cameras[k]


def problem_to_reconstruction(problem: BAProblem, shared_cameras: bool = False):
    """A Reconstruction holding the problem's cameras, poses, points and observations.

    Camera id = image id = index + 1; with ``shared_cameras`` one camera per intrinsics group
    instead (camera id = group + 1, ``problem.camera_group`` or equal intrinsics; the last
    camera of a group stands for it).
    """
    N = problem.num_cameras
    groups = np.arange(N)
    if shared_cameras:
        groups = (default_groups(problem.cameras) if problem.camera_group is None
                  else np.asarray(problem.camera_group))
    cameras = {int(g): problem.cameras[i] for i, g in enumerate(groups)}
    t = problem.cam_from_world_t()
    return build_reconstruction([cameras[g] for g in range(len(cameras))], groups,
                                [Rigid3(problem.R[i], t[i]) for i in range(N)],
                                [f"img_{i:05d}" for i in range(N)], problem.obs, problem.X)


def adjust(rec, options: BAOptions = BAOptions(), *, variable_image_ids=None,
           fixed_image_ids=None, variable_point_ids=None) -> BASummary:
    """Bundle-adjust a Reconstruction in place (poses, points; intrinsics if ``options.refine``).

    Args:
        rec: :class:`polarref.model.Reconstruction`.
        options: solver options; ``options.param`` picks the parameterization (parallax forms
            convert XYZ -> parallax landmarks, solve, and convert back).
        variable_image_ids: images whose poses are refined (default: all).
        fixed_image_ids: images held fixed (wins over variable_image_ids).
        variable_point_ids: points refined (default: all, or those seen by the variable images).

    Returns:
        BASummary. Gauge: see :func:`polarref.ba.problem.fix_gauge` (``summary.gauge``).
    """
    problem = problem_from_reconstruction(rec, variable_image_ids=variable_image_ids,
                                          fixed_image_ids=fixed_image_ids,
                                          variable_point_ids=variable_point_ids)
    prepare(problem)
    summary = solve(problem, options, prepared=True)
    write_back(rec, problem)
    return summary
