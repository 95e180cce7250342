"""Peer solvers on the same problem: pycolmap's bundle adjuster (Ceres) and scipy least_squares.

Both report the one cost definition of this package (:func:`polarref.ba.solver.pixel_cost`,
projection regardless of depth) recomputed on their outputs, because COLMAP zeroes the
residual of a point behind its camera.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from polarref.ba.euclidean import Euclidean
from polarref.ba.options import BAOptions
from polarref.ba.problem import BAProblem
from polarref.ba.solver import behind_camera_xyz, pixel_cost
from polarref.core.geometry import so3_exp
from polarref.model.colmap import CeresSettings
from polarref.model.colmap import to_pycolmap


@dataclass
class PeerResult:
    name: str
    initial_cost: float
    final_cost: float
    final_rms_px: float
    iterations: int
    wall_s: float
    termination: str
    reported_cost: float  # the peer's own final cost (COLMAP: behind-camera residuals zeroed)
    behind_camera: int = -1  # observations whose point ends with depth <= 0 in its camera
    accepted_iterations: int = -1
    rejected_iterations: int = -1
    # what the solver actually used (CeresSettings fields, threads, linear solver, ...)
    settings: dict[str, str | int | float | bool] = field(default_factory=dict)
    # per LM step [iteration, accepted, seconds since the adjuster was created, Ceres' own
    # cost]; iteration 0 is the start (only with ``trace=True``)
    trace: list = field(default_factory=list)


# Ceres' linear solvers the bench sweeps (issue 35); this pycolmap's Ceres has SuiteSparse only
# (no Eigen sparse), so SPARSE_SCHUR runs on CHOLMOD
CERES_LINEAR_SOLVERS = ("DENSE_SCHUR", "SPARSE_SCHUR", "ITERATIVE_SCHUR")


def ceres_settings(options: BAOptions, which: str, threads: int, linear_solver: str = "",
                   max_solver_time_s: float = 0.0) -> CeresSettings:
    """``which`` = "colmap" (COLMAP's tolerances) or "ours" (the tolerances of ``options``);
    ``threads`` used for every residual count (the multi-threading floor is lifted);
    ``linear_solver`` one of CERES_LINEAR_SOLVERS ("" = COLMAP's rule by image count;
    ITERATIVE_SCHUR runs with SCHUR_JACOBI); ``max_solver_time_s`` > 0 caps Ceres' time."""
    if linear_solver and linear_solver not in CERES_LINEAR_SOLVERS:
        raise ValueError(f"unknown Ceres linear solver {linear_solver!r}")
    pre = "SCHUR_JACOBI" if linear_solver == "ITERATIVE_SCHUR" else ""
    tag = linear_solver.lower().replace("_", "-")
    if which == "colmap":
        return CeresSettings(f"ceres-colmap-tol-{tag + '-' if tag else ''}{threads}t",
                             max_num_iterations=options.max_iterations, num_threads=threads,
                             min_residuals_for_multithreading=1, linear_solver=linear_solver,
                             preconditioner=pre, max_solver_time_s=max_solver_time_s)
    if which == "ours":
        return CeresSettings(f"ceres-{tag + '-' if tag else 'our-tol-'}{threads}t",
                             options.function_tolerance, options.gradient_tolerance,
                             options.parameter_tolerance, options.max_iterations, threads, 1,
                             linear_solver, pre, max_solver_time_s)
    raise ValueError(f"unknown Ceres setting {which!r}")


def _cost_of(e: Euclidean, R, C, X, options: BAOptions):
    return pixel_cost(e.pixel_residuals(R, C, X), options.loss, options.loss_scale)


def _behind(problem: BAProblem, R, C, X) -> int:
    return behind_camera_xyz(R, C, X, problem.obs_cam, problem.obs_pt)


def _parse_ceres_progress(text: str, offset_s: float) -> list:
    """Ceres' per-iteration progress lines -> [[iteration, accepted, s, cost], ...].

    Columns: iter cost cost_change |gradient| |step| tr_ratio tr_radius ls_iter iter_time
    total_time; total_time counts from Solve(), so ``offset_s`` (pycolmap's set-up before it)
    is added. A step counts as accepted when its relative decrease passes Ceres' own
    min_relative_decrease (1e-3) with a positive cost change (monotone LM, COLMAP's setting)."""
    out = []
    for line in text.splitlines():
        f = line.split()
        if len(f) != 10 or not f[0].isdigit():
            continue
        it, cost, change, ratio, total = int(f[0]), float(f[1]), float(f[2]), float(f[5]), float(f[9])
        out.append([it, it == 0 or (change > 0 and ratio > 1e-3), offset_s + total, cost])
    return out


def _captured_stdout(fn):
    """(fn(), text fn wrote to file descriptor 1): Ceres prints its progress with C++ streams."""
    import ctypes
    import os
    import sys
    import tempfile

    sys.stdout.flush()
    libc = ctypes.CDLL(None)
    with tempfile.TemporaryFile() as f:
        saved = os.dup(1)
        os.dup2(f.fileno(), 1)
        try:
            value = fn()
        finally:
            libc.fflush(None)
            os.dup2(saved, 1)
            os.close(saved)
        f.seek(0)
        return value, f.read().decode(errors="replace")


def run_pycolmap(problem: BAProblem, options: BAOptions, ceres: CeresSettings = CeresSettings(),
                 trace: bool = False) -> PeerResult:
    """Ceres via pycolmap: intrinsics fixed (or refined as ``options.refine``, one camera per
    group), gauge TWO_CAMS_FROM_WORLD, same robust loss, stopping rules and threads from
    ``ceres`` (default: COLMAP's defaults). ``trace``: Ceres' per-iteration progress (its own
    cost and time since the adjuster was created) in ``PeerResult.trace``."""
    import pycolmap

    from polarref.ba.adapter import problem_to_reconstruction
    from polarref.model.colmap import (bundle_adjustment_config, bundle_adjustment_options,
                                       rigid_from_pycolmap)

    # image id = camera index + 1, point id = point index + 1 (kept by to_pycolmap)
    rec = to_pycolmap(problem_to_reconstruction(problem, shared_cameras=bool(options.refine)))
    # the same intrinsics groups as ours (options.refine, issue 19); none by default
    opts = bundle_adjustment_options(ceres, options.loss, options.loss_scale, tuple(options.refine))
    so = opts.ceres.solver_options
    config = bundle_adjustment_config(rec, list(rec.images))
    e = Euclidean(problem)
    c0, _ = _cost_of(e, problem.R, problem.C, problem.X, options)
    if trace:
        so.minimizer_progress_to_stdout = True
        so.logging_type = type(so.logging_type).PER_MINIMIZER_ITERATION
    t = time.perf_counter()
    adjuster = pycolmap.create_default_bundle_adjuster(opts, config, rec)
    t_created = time.perf_counter() - t
    if trace:
        summary, progress = _captured_stdout(adjuster.solve)
    else:
        summary = adjuster.solve()
    wall = time.perf_counter() - t
    cs = summary.ceres_summary
    N = problem.num_cameras
    R = np.empty((N, 3, 3))
    C = np.empty((N, 3))
    for i in range(N):
        pose = rigid_from_pycolmap(rec.images[i + 1].cam_from_world())
        R[i], C[i] = pose.R, pose.center
    X = np.array([rec.points3D[j + 1].xyz for j in range(problem.num_points)])
    if options.refine:  # final cost with the refined intrinsics
        from polarref.camera import Camera
        refined = problem.copy()
        refined.cameras = [Camera.from_pycolmap(rec.cameras[rec.images[i + 1].camera_id])
                           for i in range(N)]
        e = Euclidean(refined)
    c1, rms = _cost_of(e, R, C, X, options)
    used = {**dataclasses.asdict(ceres), "linear_solver_used": str(cs.linear_solver_type_used).split(".")[-1],
            "preconditioner_used": str(cs.preconditioner_type_used).split(".")[-1],
            "num_threads_used": int(cs.num_threads_used), "jacobi_scaling": bool(so.jacobi_scaling),
            "trust_region_strategy": str(so.trust_region_strategy_type).split(".")[-1],
            "sparse_library": str(so.sparse_linear_algebra_library_type).split(".")[-1],
            "dense_library": str(so.dense_linear_algebra_library_type).split(".")[-1],
            "initial_trust_region_radius": float(so.initial_trust_region_radius),
            "use_nonmonotonic_steps": bool(so.use_nonmonotonic_steps), "eta": float(so.eta)}
    # Ceres counts its iteration 0 (the initial evaluation) as a successful step: not an LM step.
    acc, rej = max(int(cs.num_successful_steps) - 1, 0), int(cs.num_unsuccessful_steps)
    return PeerResult(ceres.name, c0, c1, rms, acc + rej, wall, str(cs.termination_type).split(".")[-1],
                      float(cs.final_cost), _behind(problem, R, C, X), acc, rej, used,
                      _parse_ceres_progress(progress, t_created) if trace else [])


def _left_jacobian(w: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3), (N, 3) -> (N, 3, 3)."""
    from polarref.core.geometry import skew
    th = np.linalg.norm(w, axis=1)[:, None, None]
    small = th < 1e-6
    t = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th**2 / 24, (1 - np.cos(t)) / t**2)
    b = np.where(small, 1 / 6 - th**2 / 120, (t - np.sin(t)) / t**3)
    K = skew(w)
    return np.eye(3) + a * K + b * (K @ K)


_SCIPY_STATUS = {0: "max_nfev", 1: "gtol", 2: "ftol", 3: "xtol", 4: "ftol+xtol", -1: "error"}


def run_scipy(problem: BAProblem, options: BAOptions) -> PeerResult:
    """scipy.optimize.least_squares (trf, sparse Jacobian from our analytic kernel, lsmr).

    Same gauge as ours (the problem's ``cam_mask``); loss 'huber'/'cauchy' map to scipy's
    with f_scale = loss_scale on each residual component (scipy has no block losses).
    """
    import scipy.optimize
    import scipy.sparse

    e = Euclidean(problem)
    N, P, M = problem.num_cameras, problem.num_points, problem.num_observations
    cam_cols = np.flatnonzero(problem.cam_mask.reshape(-1))
    free_pt = ~problem.pt_fixed
    pt_cols = np.flatnonzero(np.repeat(free_pt, 3))
    nc = len(cam_cols)
    R0, C0, X0 = problem.R.copy(), problem.C.copy(), problem.X.copy()

    def unpack(x):
        d = np.zeros(6 * N)
        d[cam_cols] = x[:nc]
        d = d.reshape(N, 6)
        X = X0.reshape(-1).copy()
        X[pt_cols] = x[nc:]
        return so3_exp(d[:, :3]) @ R0, C0 + d[:, 3:], X.reshape(P, 3)

    rows = np.arange(2 * M).reshape(M, 2)
    # column layout: camera params (6N, masked) then point params (3P, masked)
    cols_c = 6 * problem.obs_cam[:, None] + np.arange(6)
    cols_p = 6 * N + 3 * problem.obs_pt[:, None] + np.arange(3)
    full_cols = np.concatenate([cols_c, cols_p], axis=1)  # (M, 9)
    keep = np.r_[cam_cols, 6 * N + pt_cols]
    colmap = -np.ones(6 * N + 3 * P, np.int64)
    colmap[keep] = np.arange(len(keep))
    rr = np.repeat(rows, 9, axis=1).reshape(-1)
    cc = colmap[np.tile(full_cols, (1, 2)).reshape(M, 2, 9).reshape(-1)]
    ok = cc >= 0
    n = len(keep)
    sparsity = scipy.sparse.coo_matrix((np.ones(ok.sum()), (rr[ok], cc[ok])), shape=(2 * M, n))

    def fun(x):
        R, C, X = unpack(x)
        return e.evaluate(R, C, X, jac=False)[0].reshape(-1)

    def jac(x):
        # x holds rotation vectors d with R = exp(d) R0: chain the left-increment Jacobian
        # with the left Jacobian of SO(3), J_l(d).
        R, C, X = unpack(x)
        _, Jp, Jc = e.evaluate(R, C, X, jac=True)
        d = np.zeros(6 * N)
        d[cam_cols] = x[:nc]
        Jl = _left_jacobian(d.reshape(N, 6)[:, :3])
        Jc = [Jc[0].copy()]
        Jc[0][:, :, :3] = Jc[0][:, :, :3] @ Jl[problem.obs_cam]
        vals = np.concatenate([Jc[0], Jp], axis=2).reshape(-1)
        return scipy.sparse.csr_matrix((vals[ok], (rr[ok], cc[ok])), shape=(2 * M, n))

    loss = {"trivial": "linear", "huber": "huber", "cauchy": "cauchy"}[options.loss]
    x0 = np.zeros(n)
    x0[nc:] = X0.reshape(-1)[pt_cols]
    c0, _ = _cost_of(e, R0, C0, X0, options)
    t = time.perf_counter()
    res = scipy.optimize.least_squares(fun, x0, jac=jac, jac_sparsity=sparsity, method="trf",
                                       loss=loss, f_scale=options.loss_scale, x_scale="jac",
                                       ftol=options.function_tolerance, xtol=1e-10, gtol=1e-10,
                                       max_nfev=max(1, options.max_iterations), tr_solver="lsmr")
    wall = time.perf_counter() - t
    R, C, X = unpack(res.x)
    c1, rms = _cost_of(e, R, C, X, options)
    return PeerResult("scipy", c0, c1, rms, int(res.nfev), wall,
                      _SCIPY_STATUS.get(int(res.status), str(res.status)), float(res.cost),
                      _behind(problem, R, C, X))
