"""Georeferenced adjustment of a finished model and its check-point record (metres).

The model is moved into the priors' frame by a similarity (from the prior centres, else from
the control points triangulated in the model), with priors or control points on then by the
similarity that fits them as the BA weights them (georef/datum.py), then bundle-adjusted with
the pose priors and the control points as residual blocks (polarref.ba.priors). Check points
never enter the adjustment: they are triangulated from their marks in the final model and
compared with their given coordinates.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from polarref.ba import BAOptions, prepare, problem_from_reconstruction, solve, write_back
from polarref.ba.priors import AttitudePriors, BAPriors, CentrePriors, ControlPoints, PriorTerms
from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3, Sim3, umeyama
from polarref.georef.datum import DatumPriors, weighted_similarity
from polarref.georef.formats import MIN_CONTROL_POINTS, Georef, Role

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CheckPointStats:
    """Check-point errors (estimate - given), metres."""

    count: int
    rmse_x: float
    rmse_y: float
    rmse_z: float
    rmse_horizontal: float
    mean_3d: float
    max_3d: float


@dataclass(frozen=True)
class AerotriangulationRecord:
    form: str
    num_control: int
    num_check: int
    num_priors: int
    sigma0: float          # a-posteriori sigma of unit weight of the final adjustment
    redundancy: int
    check: CheckPointStats | None
    gauge: str
    iterations: int


@dataclass(frozen=True)
class Triangulated:
    """Ground points intersected from their marks: ids (K,) and xyz (K, 3), metres."""

    ids: tuple[str, ...]
    xyz: np.ndarray

    def matched(self, points) -> tuple[tuple, np.ndarray]:
        """(the points of ``points`` that were triangulated, in their order; their estimates (M, 3))."""
        at = {gid: k for k, gid in enumerate(self.ids)}
        found = tuple(p for p in points if p.id in at)
        return found, self.xyz[[at[p.id] for p in found]].reshape(-1, 3)


def triangulate_marks(rec, marks, ids) -> Triangulated:
    """Least-squares ray intersection of each point in ``ids`` from its marks in registered
    images of ``rec`` (>= 2 needed; points with fewer are left out)."""
    by_name = {im.name: im for im in rec.images.values()}
    got, xyz = [], []
    for gid in ids:
        A, b = np.zeros((3, 3)), np.zeros(3)
        n = 0
        for m in marks:
            im = by_name.get(m.image)
            if m.id != gid or im is None:
                continue
            ray = np.asarray(rec.cameras[im.camera_id].unproject(m.uv[None]), float)[0]
            if not np.isfinite(ray).all():
                continue
            d = im.cam_from_world.R.T @ (ray / np.linalg.norm(ray))
            P = np.eye(3) - np.outer(d, d)
            A += P
            b += P @ im.cam_from_world.center
            n += 1
        if n >= 2:
            got.append(gid)
            xyz.append(np.linalg.solve(A, b))
    return Triangulated(tuple(got), np.array(xyz, float).reshape(-1, 3))


def check_stats(est: Triangulated, points) -> CheckPointStats | None:
    found, X = est.matched(points)
    if not found:
        return None
    d = X - np.array([p.xyz for p in found])
    rm = np.sqrt((d**2).mean(0))
    n3 = np.linalg.norm(d, axis=1)
    return CheckPointStats(len(d), *map(float, rm), float(np.hypot(rm[0], rm[1])),
                           float(n3.mean()), float(n3.max()))


def ba_priors(georef: Georef, names: list[str], image_sigma_px: float, mark_sigma_px: float,
              use_priors: bool = True, use_control: bool = True) -> BAPriors:
    """The BA's prior blocks for problem cameras named ``names`` (control points only)."""
    idx = {n: k for k, n in enumerate(names)}
    centres = attitudes = control = None
    pri = [p for p in georef.priors if p.name in idx] if use_priors else []
    if pri:
        centres = CentrePriors(np.array([idx[p.name] for p in pri]),
                               np.array([p.centre for p in pri]),
                               np.array([np.diag(1.0 / p.sigma) for p in pri]))
        att = [p for p in pri if p.R is not None]
        if att:
            attitudes = AttitudePriors(np.array([idx[p.name] for p in att]),
                                       np.array([p.R for p in att]),
                                       np.radians([p.sigma_angle_deg for p in att]))
    ctl = georef.of_role(Role.CONTROL) if use_control else ()
    if ctl:
        gi = {p.id: k for k, p in enumerate(ctl)}
        mk = [m for m in georef.marks_of(gi) if m.image in idx]
        control = ControlPoints(np.array([p.xyz for p in ctl]),
                                np.array([np.diag(1.0 / p.sigma) for p in ctl]),
                                np.array([gi[m.id] for m in mk], np.int64),
                                np.array([idx[m.image] for m in mk], np.int64),
                                np.array([m.uv for m in mk]).reshape(-1, 2), mark_sigma_px,
                                tuple(gi))
    return BAPriors(centres, attitudes, control, image_sigma_px)


def align_to_datum(rec, georef: Georef, use_priors: bool, use_control: bool) -> None:
    """Move ``rec`` (in place) into the priors' frame by the least-squares similarity."""
    src, dst = [], []
    by_name = {im.name: im for im in rec.images.values()}
    if use_priors:
        for p in georef.priors:
            if p.name in by_name:
                src.append(by_name[p.name].cam_from_world.center)
                dst.append(p.centre)
    if use_control and len(src) < MIN_CONTROL_POINTS:
        ctl = georef.of_role(Role.CONTROL)
        found, X = triangulate_marks(rec, georef.marks, [p.id for p in ctl]).matched(ctl)
        src += list(X)
        dst += [p.xyz for p in found]
    try:
        sim = umeyama(np.array(src), np.array(dst))
    except ValueError as exc:
        raise PolarrefError(f"georeferencing: cannot place the model in the priors' frame ({exc})") from exc
    _move(rec, sim)


def _move(rec, sim: Sim3) -> None:
    for im in rec.images.values():
        pose = sim.transform_pose(im.cam_from_world)
        im.cam_from_world = Rigid3(pose.R, pose.t)
    for p in rec.points3D.values():
        p.xyz = sim.apply(p.xyz[None])[0]


def datum_priors(rec, georef: Georef, use_priors: bool, use_control: bool) -> DatumPriors:
    """The priors of ``rec``'s registered images (centres, attitudes) and its control points
    (triangulated from their marks in ``rec``), weighted as ba_priors weights them."""
    by_name = {im.name: im for im in rec.images.values()}
    pri = [p for p in georef.priors if p.name in by_name] if use_priors else []
    src = [by_name[p.name].cam_from_world.center for p in pri]
    dst = [p.centre for p in pri]
    W = [np.diag(1.0 / p.sigma) for p in pri]
    att = [p for p in pri if p.R is not None]
    if use_control:
        ctl = georef.of_role(Role.CONTROL)
        found, X = triangulate_marks(rec, georef.marks, [p.id for p in ctl]).matched(ctl)
        src += list(X)
        dst += [p.xyz for p in found]
        W += [np.diag(1.0 / p.sigma) for p in found]
    return DatumPriors(np.array(src).reshape(-1, 3), np.array(dst).reshape(-1, 3),
                       np.array(W).reshape(-1, 3, 3),
                       np.array([by_name[p.name].cam_from_world.R for p in att]).reshape(-1, 3, 3),
                       np.array([p.R for p in att]).reshape(-1, 3, 3),
                       np.radians([p.sigma_angle_deg for p in att]).reshape(-1))


def place_by_priors(rec, georef: Georef, use_priors: bool, use_control: bool) -> None:
    """Move ``rec`` (in place) by the similarity that best fits the priors the BA will use
    (polarref.georef.datum: where the BA's optimum lies for a rigid block, and where LM does
    not reliably get from the centres' unweighted fit)."""
    align_to_datum(rec, georef, True, True)
    dp = datum_priors(rec, georef, use_priors, use_control)
    if len(dp.src) < MIN_CONTROL_POINTS:
        return
    try:
        _move(rec, weighted_similarity(dp))
    except ValueError as exc:
        raise PolarrefError(f"georeferencing: cannot place the model on its priors ({exc})") from exc


def georeference(rec, georef: Georef, form: str, *, use_priors: bool = True,
                 use_control: bool = True, image_sigma_px: float = 0.5,
                 mark_sigma_px: float = 0.5, max_iterations: int = 100) -> AerotriangulationRecord:
    """Georeferenced BA of ``rec`` (in place) in ``form`` and its check-point record.

    With neither priors nor control points (``use_*`` False) the model is only aligned, by the
    priors' centres, and adjusted without prior blocks ("priors off")."""
    ids = sorted(rec.images)
    names = [rec.images[i].name for i in ids]
    have_p = use_priors and any(p.name in names for p in georef.priors)
    have_c = use_control and bool(georef.of_role(Role.CONTROL))
    if have_p or have_c:
        place_by_priors(rec, georef, have_p, have_c)
    else:
        align_to_datum(rec, georef, True, True)
    problem = problem_from_reconstruction(rec)
    pnames = [rec.images[int(i)].name for i in problem.image_ids]
    if have_p or have_c:
        problem.priors = ba_priors(georef, pnames, image_sigma_px, mark_sigma_px, have_p, have_c)
    prepare(problem)
    summary = solve(problem, BAOptions(param=form, max_iterations=max_iterations), prepared=True)
    write_back(rec, problem)
    if not (have_p or have_c):  # unconstrained: its gauge is arbitrary, re-placed as aligned
        align_to_datum(rec, georef, True, True)
    dof, cost = _redundancy(problem, summary)
    checks = georef.of_role(Role.CHECK)
    est = triangulate_marks(rec, georef.marks, [p.id for p in checks])
    return AerotriangulationRecord(
        form, len(georef.of_role(Role.CONTROL)) if have_c else 0, len(checks),
        len(georef.priors) if have_p else 0,
        float(np.sqrt(2.0 * cost / image_sigma_px**2 / dof)) if dof > 0 else float("nan"),
        int(dof), check_stats(est, checks), summary.gauge, summary.iterations)


def evaluate(rec, georef: Georef, label: str, *, use_priors: bool, image_sigma_px: float = 0.5,
             mark_sigma_px: float = 0.5, gauge: str = "") -> AerotriangulationRecord:
    """The record of a model adjusted elsewhere (a peer's), nothing moved: its sigma0 counts the
    pixel residuals and, with ``use_priors``, the centre/attitude priors it was adjusted with."""
    problem = problem_from_reconstruction(rec)
    names = [rec.images[int(i)].name for i in problem.image_ids]
    have_p = use_priors and any(p.name in names for p in georef.priors)
    if have_p:
        problem.priors = ba_priors(georef, names, image_sigma_px, mark_sigma_px, True, False)
    prepare(problem)
    dof, cost = _redundancy(problem, None)
    checks = georef.of_role(Role.CHECK)
    est = triangulate_marks(rec, georef.marks, [p.id for p in checks])
    return AerotriangulationRecord(
        label, 0, len(checks), len(georef.priors) if have_p else 0,
        float(np.sqrt(2.0 * cost / image_sigma_px**2 / dof)) if dof > 0 else float("nan"),
        int(dof), check_stats(est, checks), gauge, 0)


def _redundancy(problem, summary) -> tuple[int, float]:
    """(observations - unknowns, final Euclidean-pixel + prior cost): form-independent."""

    res = problem.obs_uv - _project(problem)
    cost = 0.5 * float((res**2).sum())
    n_obs = 2 * problem.num_observations
    n_par = 6 * int(problem.cam_mask.any(1).sum()) + 3 * problem.num_points
    if problem.priors is not None:
        t = PriorTerms(problem.priors, problem.cameras, problem.priors.image_sigma_px)
        r = t.residuals(problem.R, problem.C, problem.control_X if problem.control_X is not None
                        else np.zeros((0, 3)))
        cost += r.cost()
        n_obs += r.centre.size + r.attitude.size + r.gcp_prior.size + r.gcp_pixel.size
        n_par += 3 * t.G
    else:
        n_par -= 7
    return n_obs - n_par, cost


def _project(problem) -> np.ndarray:
    out = np.empty((problem.num_observations, 2))
    Xc = np.einsum("mij,mj->mi", problem.R[problem.obs_cam],
                   problem.X[problem.obs_pt] - problem.C[problem.obs_cam])
    for c in np.unique(problem.obs_cam):
        sel = problem.obs_cam == c
        out[sel] = problem.cameras[c].project(Xc[sel])
    return out
