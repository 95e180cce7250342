"""Controlled bundle-adjustment experiments behind the claims scorecard.

All problems come from ``polarref.ba.synthetic`` (pycolmap's synthetic dataset, fixed seeds),
so the truth is exact. Every parameterization of :mod:`polarref.ba` is run on the same problem.

* timing/convergence: one problem, each parameterization, repeated; traces kept for plots.
* conditioning: the Gauss-Newton matrix J^T J (gauge columns removed) and the reduced camera
  system (Schur complement) at the true solution; raw and Jacobi-scaled condition numbers
  (raw numbers depend on units - metres vs radians - so the scaled ones are the fair figure).
* correlation: per-point 3x3 blocks of the marginal covariance (J^T J)^-1; mean absolute
  off-diagonal correlation coefficient of the structure variables (XYZ vs parallax form).
* robustness: 10 % gross outliers (30-60 px) with the Huber loss; and low parallax (camera
  centres shrunk towards their mean). Rotation error after Sim3 alignment vs truth.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

TIMING_PROBLEM = (12, 300)     # cameras, points
SMALL_PROBLEM = (10, 150)      # dense J^T J stays small: 10*6 + 150*3 columns
ROBUST_PROBLEM = (10, 200)
TIMING_REPEATS = 3
ROBUST_SEEDS = 5
OUTLIER_FRACTION = 0.10
LOW_PARALLAX_SHRINK = 0.03     # camera-centre spread kept (3 %): near-pure rotation


def _params() -> tuple[str, ...]:
    from polarref.ba import PARAMS
    return tuple(PARAMS)


def _rotation_error_deg(rec, truth) -> float:
    from polarref.geometry import rotation_angle_deg, umeyama

    ids = sorted(set(rec.images) & set(truth.images))
    src = np.array([rec.images[i].cam_from_world.center for i in ids])
    dst = np.array([truth.images[i].cam_from_world.center for i in ids])
    sim = umeyama(src, dst)
    errs = [float(rotation_angle_deg(sim.transform_pose(rec.images[i].cam_from_world).R,
                                     truth.images[i].cam_from_world.R)) for i in ids]
    return float(np.mean(errs))


def _pairwise_rotation_error_deg(rec, truth) -> float:
    """Mean angle between estimated and true relative rotations R_i R_j^T over all pairs (gauge-free)."""
    from polarref.geometry import rotation_angle_deg

    ids = sorted(set(rec.images) & set(truth.images))
    Re = np.array([rec.images[i].cam_from_world.R for i in ids])
    Rt = np.array([truth.images[i].cam_from_world.R for i in ids])
    a, b = np.triu_indices(len(ids), 1)
    rel_e = Re[a] @ np.swapaxes(Re[b], 1, 2)
    rel_t = Rt[a] @ np.swapaxes(Rt[b], 1, 2)
    return float(np.mean(rotation_angle_deg(rel_e, rel_t)))


def _adjust(rec, param: str, **opts):
    from polarref.ba import BAOptions, adjust
    return adjust(rec, BAOptions(param=param, **opts))


def timing(seed: int, deadline: float) -> dict:
    from polarref.ba.synthetic import clone, synthetic_reconstruction

    init, truth = synthetic_reconstruction(*TIMING_PROBLEM, seed=seed)
    out: dict = {"problem": f"synthetic {TIMING_PROBLEM[0]} cameras x {TIMING_PROBLEM[1]} points, "
                            f"0.5 px noise, seed {seed}", "params": {}}
    for param in _params():
        runs, trace, err = [], [], ""
        for rep in range(TIMING_REPEATS):
            if time.perf_counter() > deadline and runs:
                break
            rec = clone(init)
            try:
                s = _adjust(rec, param)
            except Exception as exc:  # one broken parameterization must not hide the others
                err = f"{type(exc).__name__}: {exc}"
                break
            runs.append({"wall_s": s.wall_s, "iterations": s.iterations, "final_rms_px": s.final_rms_px,
                         "final_pixel_cost": s.final_pixel_cost,
                         "rotation_error_deg": _rotation_error_deg(rec, truth)})
            if rep == 0:
                trace = [[r.iteration, r.wall_s, r.cost] for r in s.trace if r.accepted]
                trace.insert(0, [0, 0.0, s.initial_cost])
        out["params"][param] = {"runs": runs, "trace": trace, "error": err}
    return out


def _dense_system(problem, param_obj):
    """J (rows, free columns) at the current estimate, with the column groups of each point."""
    R, C = problem.R, problem.C
    pts = param_obj.init_points()
    r, Jp, Jc = param_obj.evaluate(R, C, pts, jac=True)
    M, k = r.shape
    N, P = problem.num_cameras, problem.num_points
    dp = pts.shape[1]
    J = np.zeros((M * k, 6 * N + dp * P))
    rows = np.arange(M)[:, None] * k + np.arange(k)[None, :]
    # Each slot's Jacobian covers columns (c0, c1) of its camera's 6-column block (default: all 6).
    cols = getattr(param_obj, "slot_cols", None) or [(0, 6)] * len(Jc)
    for s, Js in enumerate(Jc):
        cams = param_obj.slot_cams[s]
        c0, c1 = cols[s]
        for m in range(M):
            J[rows[m], 6 * cams[m] + c0:6 * cams[m] + c1] += Js[m]
    for m in range(M):
        p = problem.obs_pt[m]
        J[rows[m], 6 * N + dp * p:6 * N + dp * (p + 1)] += Jp[m]
    free = np.concatenate([problem.cam_mask.reshape(-1), np.ones(dp * P, bool)])
    return J[:, free], int(free[:6 * N].sum()), dp, P


def _cond(A: np.ndarray) -> float:
    w = np.linalg.eigvalsh(0.5 * (A + A.T))
    return float(w[-1] / w[0]) if w[0] > 0 else float("inf")


def conditioning(seed: int) -> dict:
    """Condition numbers and structure correlations at the true solution of a small problem."""
    from polarref.ba import BAOptions, problem_from_reconstruction
    from polarref.ba.problem import prepare
    from polarref.ba.solver import make_param
    from polarref.ba.synthetic import synthetic_reconstruction

    _, truth = synthetic_reconstruction(*SMALL_PROBLEM, seed=seed, noise_px=0.0)
    out: dict = {"problem": f"synthetic {SMALL_PROBLEM[0]} cameras x {SMALL_PROBLEM[1]} points at the "
                            f"true solution, seed {seed}", "params": {}}
    for param in _params():
        try:
            problem = problem_from_reconstruction(truth)
            prepare(problem)
            obj = make_param(problem, BAOptions(param=param))
            J, nc, dp, P = _dense_system(problem, obj)
            H = J.T @ J
            d = np.sqrt(np.clip(np.diag(H), 1e-300, None))
            Hs = H / d[:, None] / d[None, :]
            U, Wm, V = H[:nc, :nc], H[:nc, nc:], H[nc:, nc:]
            Vinv = np.linalg.inv(V)
            S = U - Wm @ Vinv @ Wm.T
            ds = np.sqrt(np.clip(np.diag(S), 1e-300, None))
            cov = np.linalg.inv(H)[nc:, nc:]
            corrs = []
            for i in range(P):
                b = cov[dp * i:dp * (i + 1), dp * i:dp * (i + 1)]
                sd = np.sqrt(np.diag(b))
                c = b / sd[:, None] / sd[None, :]
                corrs += list(np.abs(c[np.triu_indices(dp, 1)]))
            out["params"][param] = {
                "cond_JtJ": _cond(H), "cond_JtJ_scaled": _cond(Hs),
                "cond_schur": _cond(S), "cond_schur_scaled": _cond(S / ds[:, None] / ds[None, :]),
                "mean_abs_point_corr": float(np.mean(corrs)), "max_abs_point_corr": float(np.max(corrs)),
                "point_params": dp, "residuals_per_obs": int(J.shape[0] // max(1, len(problem.obs_pt))),
                "error": ""}
        except Exception as exc:
            out["params"][param] = {"error": f"{type(exc).__name__}: {exc}"}
    return out


def _shrink_baseline(init, truth, factor: float, noise_px: float, seed: int):
    """Move GT centres towards their mean by ``factor`` and re-synthesize keypoints with noise."""
    from polarref.geometry import Rigid3

    rng = np.random.default_rng(seed + 1000)
    cs = np.array([im.cam_from_world.center for im in truth.images.values()])
    mean = cs.mean(0)
    for i, im in truth.images.items():
        R = im.cam_from_world.R
        C = mean + factor * (im.cam_from_world.center - mean)
        im.cam_from_world = Rigid3(R, -R @ C)
        # initial pose: same perturbation as before, re-centred
        Ri = init.images[i].cam_from_world.R
        Ci = mean + factor * (init.images[i].cam_from_world.center - mean)
        init.images[i].cam_from_world = Rigid3(Ri, -Ri @ Ci)
    for pid, p in truth.points3D.items():
        for image_id, idx in p.track:
            im = truth.images[int(image_id)]
            cam = truth.cameras[im.camera_id]
            uv = cam.project(im.cam_from_world.apply(p.xyz)[None])[0]
            uv_noisy = uv + rng.normal(0.0, noise_px, 2)
            truth.images[int(image_id)].keypoints[int(idx)] = uv
            init.images[int(image_id)].keypoints[int(idx)] = uv_noisy


def robustness(seed: int, deadline: float) -> dict:
    from polarref.ba.synthetic import clone, synthetic_reconstruction

    out: dict = {"outliers": {}, "low_parallax": {}, "seeds_run": 0,
                 "problem": f"synthetic {ROBUST_PROBLEM[0]} cameras x {ROBUST_PROBLEM[1]} points, "
                            f"0.5 px noise; outliers {OUTLIER_FRACTION:.0%} of observations "
                            f"displaced 30-60 px (Huber, scale 1 px); low parallax: centre spread "
                            f"x{LOW_PARALLAX_SHRINK}"}
    for param in _params():
        out["outliers"][param] = {"rotation_error_deg": [], "errors": []}
        out["low_parallax"][param] = {"rotation_error_deg": [], "errors": []}
    for k in range(ROBUST_SEEDS):
        if time.perf_counter() > deadline and k > 0:
            break
        s = seed + k
        init_o, truth_o = synthetic_reconstruction(*ROBUST_PROBLEM, seed=s, outlier_fraction=OUTLIER_FRACTION)
        init_l, truth_l = synthetic_reconstruction(*ROBUST_PROBLEM, seed=s, rot_deg=0.05,
                                                   point_sigma=0.005, center_sigma=0.0005)
        _shrink_baseline(init_l, truth_l, LOW_PARALLAX_SHRINK, 0.5, s)
        for param in _params():
            for key, init, truth, opts in (("outliers", init_o, truth_o, {"loss": "huber", "loss_scale": 1.0}),
                                           ("low_parallax", init_l, truth_l, {})):
                rec = clone(init)
                try:
                    _adjust(rec, param, **opts)
                    out[key][param]["rotation_error_deg"].append(_pairwise_rotation_error_deg(rec, truth))
                except Exception as exc:
                    out[key][param]["errors"].append(f"{type(exc).__name__}: {exc}")
        out["seeds_run"] = k + 1
    return out


def run_all(seed: int, budget_s: float, out_json: Path) -> dict:
    """Run every experiment within roughly ``budget_s``; the JSON also goes to ``out_json``."""
    t0 = time.perf_counter()
    deadline = t0 + budget_s
    result: dict = {}
    for name, fn in (("conditioning", lambda: conditioning(seed)),
                     ("timing", lambda: timing(seed, t0 + 0.4 * budget_s)),
                     ("robustness", lambda: robustness(seed, deadline))):
        tic = time.perf_counter()
        try:
            result[name] = fn()
        except Exception as exc:
            log.exception("experiment %s failed", name)
            result[name] = {"error": f"{type(exc).__name__}: {exc}"}
        result.setdefault("wall_s", {})[name] = time.perf_counter() - tic
    out_json.parent.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps(result, indent=1, default=float))
    return result
