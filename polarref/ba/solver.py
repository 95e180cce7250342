"""Levenberg-Marquardt (Ceres-style trust region or Nielsen / ParallaxBA damping) and
Gauss-Newton, with point blocks eliminated by Schur.

Robust losses use IRLS-style reweighting: each residual block and its Jacobian rows are
scaled by ``sqrt(rho'(s))`` (no Triggs second-order correction), which gives the exact
gradient of ``1/2 sum rho(s)`` and a Gauss-Newton Hessian that is positive semi-definite.
Damping follows Ceres' LM: ``(J^T J + mu D) dx = -g`` with ``D = diag(J^T J)`` clipped to
[1e-6, 1e32] and ``mu = 1 / radius``; the radius grows by ``1 / max(1/G, 1 - (2 rho - 1)^3)``
after a step with gain ratio ``rho > 1e-3`` and shrinks by a doubling factor otherwise. Ceres
has G = 3; ours ``options.max_radius_growth`` (30): only a step whose model was near exact
(rho > 0.94) grows the radius more than 3x, which saves the iterations a well-modelled problem
spends shrinking the damping (options.py has the measurement).
With ``D = diag(J^T J)`` the damping is Jacobi-scaled (Ceres' ``jacobi_scaling``), so the
mixed units of angles, parallax angles and centres do not bias the step.

``damping="nielsen"`` is ParallaxBA's LM (Nielsen 1999, Madsen et al. "Methods for non-linear
least squares", eq. 3.14-3.16): ``(J^T J + mu I) dx = -g``, ``mu0 = tau * max diag(J^T J)``
(tau = 1e-6), a step is kept if the gain ratio is > 0, then ``mu *= max(1/3, 1 - (2 rho - 1)^3)``
and ``nu = 2``; otherwise ``mu *= nu, nu *= 2``. ``solver="gn"`` takes every finite undamped
step (ParallaxBA's GN mode). Each form's default is in options.py (measured). In LM the gauge
may be released during the solve (gauge.py). The trace records mu and the gain ratio.

The normal equations are built from per-slot camera Jacobians (schur.py); parallax forms
hand over their anchors' Jacobians factored (anchor_terms.py).

Box bounds on point parameters (``param.point_bounds()``, parallax forms: omega in
[0, pi - margin]) are handled as a projected trust-region step: (1) a component at its bound
whose gradient points outward is *active* for the iteration (its Jacobian column is zeroed,
so the step is solved with it held, and the gradient test uses the projected gradient);
(2) a step that leaves the box is clipped onto it, and the gain ratio then uses the
Gauss-Newton model decrease of the *clipped* step, obtained exactly from the damped normal
equations (no extra Jacobian products). A step is accepted only if the true cost decreases,
so clipping never breaks the monotone decrease; unclipped steps are unchanged.

The whole solve runs with ``options.blas_threads`` BLAS threads (threadpoolctl; 1 by
default: the BLAS calls here are small and a multi-threaded BLAS on a busy machine was 45x
slower in the Cholesky).
"""

from __future__ import annotations

import dataclasses
import logging
import sys
import time

import numpy as np

from polarref.ba.losses import rho as loss_rho
from polarref.ba.options import (DEFAULT_DAMPING, DEFAULT_LM_GAUGE, BAOptions, BASummary,
                                 IterationRecord)
from polarref.ba.parameterization import (AnchoredJacobians, BoundedPoints, Parameterization,
                                          Staged, make_param)
from polarref.ba.priors import PriorTerms
from polarref.ba.problem import BAProblem, prepare
from polarref.ba import chunked, row_map
from polarref.ba.kernels import use_kernels
from polarref.ba.reduced_solve import ReducedSolver, choose
from polarref.ba.schur import SchurStructure
from polarref.ba.xspace import AnchorElimination, xspace_note
from polarref.core import heap
from polarref.core.geometry import so3_exp

log = logging.getLogger(__name__)

_MIN_DIAG, _MAX_DIAG = 1e-6, 1e32  # Ceres' min/max_lm_diagonal
_MIN_RELATIVE_DECREASE = 1e-3
_MAX_NIELSEN_MU = 1e32  # Nielsen damping above this: no step decreases the cost


def resolve_damping(options: BAOptions) -> str:
    """The LM damping strategy for ``options``: its own, or the form's measured default
    (``DEFAULT_DAMPING``, see options.py)."""
    return options.damping or DEFAULT_DAMPING[options.param]


def initial_nielsen_mu(tau: float, diag_u: np.ndarray, mask_v: np.ndarray, V: np.ndarray,
                       pt_fixed: np.ndarray) -> float:
    """``tau * max diag(J^T J)`` over the free camera columns (diag_u, mask_v (Nv, 6)) and the
    free points' blocks V (P, 3, 3): Nielsen's / ParallaxBA's initial damping."""
    dv = np.diagonal(V, axis1=1, axis2=2)[~pt_fixed]
    top = max(float((diag_u * mask_v).max(initial=0.0)), float(dv.max(initial=0.0)))
    return tau * top if top > 0 else tau


def _robust(r: np.ndarray, groups, loss: str, scale: float):
    """Cost and per-residual-row weights sqrt(rho') for residuals (M, k)."""
    cost = 0.0
    w = None if loss == "trivial" else np.ones(r.shape)
    for a, b in groups:
        s = np.einsum("mk,mk->m", r[:, a:b], r[:, a:b]) if b - a > 1 else r[:, a] ** 2
        val, d1 = loss_rho(loss, s, scale)
        cost += 0.5 * float(val.sum())
        if w is not None:
            w[:, a:b] = np.sqrt(d1)[:, None]
    return cost, w


def _pixel_residuals(param, R, C, pts, r: np.ndarray | None) -> np.ndarray:
    """Pixel residuals (M, 2) at (R, C, pts): the rows of ``r`` (the unweighted residuals
    evaluated there, or None) where the form says they hold them bitwise (``pixel_part``),
    else evaluated again (two ray passes per solve that a mapper's ~500 local BAs paid)."""
    part = getattr(param, "pixel_part", None)
    px = part(r) if part is not None and r is not None else None
    return px if px is not None else param.pixel_residuals(R, C, pts)


def pixel_cost(res_px: np.ndarray, loss: str, scale: float) -> tuple[float, float]:
    """(1/2 sum rho(|r|^2), RMS of residual components) of pixel residuals (M, 2)."""
    s = np.einsum("mk,mk->m", res_px, res_px)
    val, _ = loss_rho(loss, s, scale)
    return 0.5 * float(val.sum()), float(np.sqrt(s.mean() / 2.0))


def behind_camera_xyz(R, C, X, obs_cam, obs_pt, compiled: bool = False) -> int:
    """Observations whose point X (P, 3) has depth <= 0 in its camera (R (N,3,3), C (N,3));
    ``compiled``: in one pass (kernels.count_behind; it runs twice per solve, and the gathers
    here were 3 % of a mapper's local BA)."""
    if compiled:
        from polarref.ba import kernels
        return int(kernels.count_behind(R, C, X, obs_cam, obs_pt))
    # row gathers by take (the same numbers as R[obs_cam, 2]): a third of the time
    Rz = np.ascontiguousarray(R[:, 2])
    z = np.einsum("mj,mj->m", Rz.take(obs_cam, 0), X.take(obs_pt, 0) - C.take(obs_cam, 0))
    return int(np.count_nonzero(z <= 0))


def _reduced_solver(options: BAOptions, nv: int) -> tuple[ReducedSolver, int]:
    """(solver of the reduced system, the dense_max_cameras that gives it the S it needs:
    dense for Cholesky, sparse for LU; PCG takes either, dense up to options' limit)."""
    choice = choose(options.reduced_solver, nv, options.dense_max_cameras,
                    options.pcg_min_cameras)
    if choice is ReducedSolver.DENSE_CHOLESKY:
        return choice, max(options.dense_max_cameras, nv)
    if choice is ReducedSolver.SPARSE_LU:
        return choice, min(options.dense_max_cameras, nv - 1)
    return choice, options.dense_max_cameras


def _clipped_model(a_lin, q_damp, g_p, dp, delta, D_p, V, mu) -> float:
    """Gauss-Newton model decrease ``-g^T s - 1/2 s^T H s`` of the clipped step ``s = dx +
    delta`` (delta on point components only). With ``(H + mu D) dx = -g`` (the LM system):
    ``dx^T H dx = a_lin - q_damp`` and ``(H dx)_p = -g_p - mu D_p dp`` on point rows, and
    ``delta^T H delta`` needs only the per-point blocks V (point blocks are diagonal in H).
    For delta = 0 this equals the LM model ``1/2 (a_lin + q_damp)``."""
    d_H_dx = -float((delta * (g_p + mu * D_p * dp)).sum())
    d_H_d = float(np.einsum("pi,pij,pj->", delta, V, delta))
    return a_lin - float((g_p * delta).sum()) - 0.5 * ((a_lin - q_damp) + 2.0 * d_H_dx + d_H_d)


def solve(problem: BAProblem, options: BAOptions, *, prepared: bool = False,
          param: Parameterization | None = None) -> BASummary:
    """Run LM on ``problem`` (updated in place: R, C, X). See module docstring."""
    if options.refine:  # self-calibration wraps this solver: polarref.ba.entry.solve
        raise ValueError("solver.solve holds intrinsics fixed; use polarref.ba.solve to refine "
                         f"{','.join(options.refine)}")
    with heap.solve_scope():  # LM iterations reuse the last one's pages (core/heap.py)
        if options.blas_threads is None:
            return _solve(problem, options, prepared, param)
        with _blas_controller().limit(limits=options.blas_threads, user_api="blas"):
            return _solve(problem, options, prepared, param)


_BLAS: list = []  # (len(sys.modules) when made, threadpoolctl's controller of the BLAS)


def _blas_controller():
    """Entering ``threadpool_limits`` scans the loaded libraries again (~2.4 ms per call, as
    long as a warm synth-20 solve's structure build); the controller is made once, and again
    after an import: a BLAS loaded later (another extension's) would escape the limit (the
    test suite's order once showed one at 2 threads inside a 1-thread solve)."""
    if not _BLAS or _BLAS[0][0] != len(sys.modules):
        from threadpoolctl import ThreadpoolController
        _BLAS[:] = [(len(sys.modules), ThreadpoolController())]
    return _BLAS[0][1]


def _solve(problem: BAProblem, options: BAOptions, prepared: bool, param) -> BASummary:
    t0 = time.perf_counter()
    if not prepared:
        prepare(problem)
    if param is None:
        param = make_param(problem, options)
    held = None
    if options.solver == "lm" and (options.lm_gauge or DEFAULT_LM_GAUGE[options.param]) == "free":
        from polarref.ba import gauge
        held = gauge.release(problem)
    summary = _stages(problem, options, param, t0)
    if held is not None:
        summary.num_variable_cameras = int(held.mask.any(1).sum())
        if gauge.restore(problem, held):
            summary.gauge += "; LM ran in the free gauge, result mapped back by a similarity"
        else:
            summary.gauge = "free (LM in the free gauge; mapping back needed a scale <= 0)"
    return summary


def _stages(problem: BAProblem, options: BAOptions, param, t0: float) -> BASummary:
    if options.staged and isinstance(param, Staged):
        # Stage 1: theta only (half the iteration budget); stage 2: theta and phi jointly.
        param.set_stage(theta_only=True)
        first = _lm(problem, dataclasses.replace(options, max_iterations=max(
            1, options.max_iterations // 2)), param, t0)
        param.set_stage(theta_only=False)
        second = _lm(problem, dataclasses.replace(
            options, max_iterations=max(0, options.max_iterations - first.iterations)),
            param, t0, pts0=first.points_state)
        for rec in second.trace:
            rec.iteration += first.iterations
        second.trace = first.trace + second.trace
        second.initial_cost, second.initial_pixel_cost = first.initial_cost, first.initial_pixel_cost
        second.initial_rms_px = first.initial_rms_px
        second.iterations += first.iterations
        second.accepted_iterations += first.accepted_iterations
        second.rejected_iterations += first.rejected_iterations
        second.first_stage_termination = first.termination
        second.wall_s = time.perf_counter() - t0
        second.setup_s = first.setup_s
        second.behind_camera["initial"] = first.behind_camera["initial"]
        if second.point_bounds:
            second.point_bounds["clipped_steps"] += first.point_bounds["clipped_steps"]
        return second
    return _lm(problem, options, param, t0)


class _StageClock:
    """Seconds per solver stage over the whole solve (``BASummary.time_in``)."""

    def __init__(self) -> None:
        self.seconds = dict.fromkeys(("evaluate", "normal_equations", "schur", "solve", "structure", "update"), 0.0)

    def add(self, stage: str, tic: float) -> None:
        self.seconds[stage] += time.perf_counter() - tic


def _lm(problem: BAProblem, options: BAOptions, param, t0: float,
        pts0: np.ndarray | None = None) -> BASummary:
    times = _StageClock()
    tic = time.perf_counter()
    cam_var = problem.cam_mask.any(1)
    # anchors' Jacobians factored (anchor_terms.py): numpy path, and the kernels' fused
    # three-slot build; the kernels' generic slot path (sparse S) takes them dense
    anchored = isinstance(param, AnchoredJacobians) and param.anchor_cams is not None
    reduced, dense_max = _reduced_solver(options, int(cam_var.sum()))
    st = SchurStructure(param.slot_cams, param.slot_cols, problem.obs_pt, cam_var,
                        problem.num_points, dense_max,
                        fast=use_kernels(options.kernels), anchored=anchored)
    st.reduced_solver = reduced
    st.pcg_settings = (options.pcg_rtol, options.pcg_max_iterations)
    builder = st
    if anchored and not st.fast:
        from polarref.ba.anchor_terms import AnchorTerms
        builder = AnchorTerms(st, problem.obs_pt, *param.anchor_cams)
    mask_v = problem.cam_mask[st.var_cams].astype(np.float64)  # (Nv, 6)
    pt_free = (~problem.pt_fixed).astype(np.float64)[:, None]
    any_pt_fixed = bool(problem.pt_fixed.any())
    bounds = param.point_bounds() if isinstance(param, BoundedPoints) else None
    if bounds is not None:
        bcols = np.flatnonzero(np.isfinite(bounds[0]) | np.isfinite(bounds[1]))
        lo_b, hi_b = bounds[0][bcols], bounds[1][bcols]
    clipped_steps = 0
    times.add("structure", tic)
    R, C = problem.R.copy(), problem.C.copy()
    pts = param.init_points() if pts0 is None else pts0.copy()
    # pose priors and control points: their blocks enter at the marked "priors" places below
    prior = None if problem.priors is None else PriorTerms(problem.priors, problem.cameras,
                                                           problem.priors.image_sigma_px)
    Xg = None if prior is None else (np.zeros((0, 3)) if problem.control_X is None
                                     else problem.control_X.copy())
    ps = None
    loss, scale = options.loss, options.loss_scale

    tic = time.perf_counter()
    factored = anchored and (not st.fast or st.fused)
    # large three-slot problems: residuals only at trial points, normal equations in chunks
    # (chunked.py; their Jacobians' time then counts in time_in["normal_equations"])
    lazy = chunked.applies(st, param, problem.num_observations)
    # three-slot forms: points eliminated in the variable y = dq + B dc (xspace.py), where
    # the maps B carry the anchors' Jacobians; else (per build) the reference cross terms
    xs = None
    if (options.anchor_schur == "xspace" and anchored and st.fused and not any_pt_fixed
            and (not lazy or hasattr(param, "anchor_maps_for_rows"))):
        xs = AnchorElimination(st, *param.anchor_cams)
    builds_x = builds_ref = 0
    use_x = False
    r, Jp, Jc = param.evaluate(R, C, pts, jac=not lazy, factored=factored)
    times.add("evaluate", tic)
    if not np.isfinite(r).all():
        from polarref.core.errors import PolarrefError
        raise PolarrefError(f"bundle adjustment ({options.param}): non-finite residuals at the "
                            "initial estimate (degenerate geometry?)")
    cost, w = _robust(r, param.groups, loss, scale)
    if prior is not None:
        cost += prior.cost(R, C, Xg)
    initial_cost = cost
    init_px_cost, init_rms = pixel_cost(_pixel_residuals(param, R, C, pts, r), loss, scale)
    behind0 = behind_camera_xyz(problem.R, problem.C, problem.X, problem.obs_cam, problem.obs_pt,
                                st.fast)
    setup_s = time.perf_counter() - t0
    damping = resolve_damping(options)
    gn = options.solver == "gn"
    identity_damping = gn or damping == "nielsen"
    radius, decrease_factor = options.initial_trust_radius, 2.0
    mu_n, nu = None, 2.0  # Nielsen: absolute damping (set from the first normal matrix), growth

    def rec_radius() -> float:  # the trace's trust radius: Ceres' only (Nielsen / GN: 0)
        return radius if not identity_damping else 0.0
    def damp_more() -> str:
        """After a failed or rejected step: more damping; a termination reason once exhausted."""
        nonlocal mu_n, nu, radius, decrease_factor
        if damping == "nielsen":
            mu_n, nu = mu_n * nu, nu * 2.0
            return "max_damping" if mu_n > _MAX_NIELSEN_MU else ""
        radius /= decrease_factor
        decrease_factor *= 2.0
        return "min_trust_radius" if radius < options.min_trust_radius else ""

    trace: list[IterationRecord] = []
    termination = "max_iterations"
    accepted_n = 0
    it = 0
    need_build = True
    while it < options.max_iterations:
        if need_build:
            tic = time.perf_counter()
            if lazy:
                use_x = xs is not None
                V, g_p, blocks = chunked.build(st, param, R, C, pts, w,
                                               pt_free if any_pt_fixed else None, xs, mask_v)
            else:
                G = getattr(Jc[1], "row_map", None) if len(Jc) == 2 else None
                if G is not None:  # polar: two whitened rows carry all three (row_map.py)
                    r_w = row_map.whiten(r, w, G, Jp, Jc[0], Jc[1].Ad)
                    Jp_w, Jc_w = Jp, Jc
                elif w is not None:
                    # weighted in place: evaluate's arrays are this build's alone (dropped
                    # below); fresh copies were a tenth of a mapper's local BA. The factored
                    # anchors are weighted below, only for a build that reads their Ad.
                    wm = w[:, :, None]
                    r_w, Jp_w = np.multiply(r, w, out=r), np.multiply(Jp, wm, out=Jp)
                    Jc_w = [np.multiply(J, wm, out=J) if isinstance(J, np.ndarray) else J
                            for J in Jc]
                else:
                    r_w, Jp_w, Jc_w = r, Jp, Jc
                if any_pt_fixed:
                    Jp_w = Jp_w * pt_free[problem.obs_pt][:, :, None]
                V, g_p = st.point_terms(Jp_w, r_w)
            active = None
            if bounds is not None:
                # at a bound with the descent direction pointing out of the box: held (only
                # the bounded columns can be: parallax forms, omega; the others stay False)
                pb, gb = pts[:, bcols], g_p[:, bcols]
                act_b = ((pb <= lo_b) & (gb > 0)) | ((pb >= hi_b) & (gb < 0))
                if act_b.any():
                    active = np.zeros(pts.shape, bool)
                    active[:, bcols] = act_b
                    # a held component's Jacobian column is zero: its row/column of V and its
                    # column of W vanish (zeroed in place on the held points only, exactly)
                    ai, ac = np.nonzero(active)
                    V[ai, ac, :] *= 0.0
                    V[ai, :, ac] *= 0.0
                    g_p[ai, ac] = 0.0
            if lazy and use_x and not xs.carries_maps(active):
                # an omega held at its bound with B != 0: this build by cross terms (xspace.py)
                use_x = False
                V, g_p, blocks = chunked.build(st, param, R, C, pts, w, None)
                if active is not None:
                    ai, ac = np.nonzero(active)
                    V[ai, ac, :] *= 0.0
                    V[ai, :, ac] *= 0.0
                    g_p[ai, ac] = 0.0
            if lazy:
                builds_x += use_x
                builds_ref += xs is not None and not use_x
            # gauge-fixed columns and fixed cameras are masked on the assembled blocks
            if not lazy:
                use_x = xs is not None and xs.carries(Jc_w[1], active)
                if w is not None and not use_x and G is None:  # the reference build reads Ad
                    # weighted (whitened rows already are)
                    Jc_w = [J if isinstance(J, np.ndarray) else J.scaled(w) for J in Jc_w]
                blocks = (xs.build(Jc_w[0], Jc_w[1], Jp_w, r_w, V, g_p, mask_v) if use_x
                          else builder.build(Jc_w, Jp_w, r_w))
                builds_x += use_x
                builds_ref += xs is not None and not use_x
            # the Jacobians are dead once the normal equations exist (a rejected step reuses
            # those; an accepted one rebuilds from its own): not held through the next trial
            r = Jp = Jc = r_w = Jp_w = Jc_w = None
            (g_c, W, U), blocks = blocks, None
            if prior is not None:  # priors: camera gradient and diagonal blocks
                ps = prior.build(R, C, Xg, problem.num_cameras)
                ps.add_to_cameras(st, st.var_cams, g_c, U)
            if active is not None:  # W's column of a held component: its point's entries
                e0 = np.searchsorted(st.entry_pt, ai, "left")
                ne = np.searchsorted(st.entry_pt, ai, "right") - e0
                ee = np.repeat(e0 - np.cumsum(ne) + ne, ne) + np.arange(ne.sum())
                W[ee, :, np.repeat(ac, ne)] *= 0.0
            g_c, W, U = st.apply_mask(mask_v, g_c, W, U)
            diag_u = np.zeros((st.Nv, 6))
            diag_u[st.u_ca[st.u_ca == st.u_cb]] = np.diagonal(
                U[st.u_ca == st.u_cb], axis1=1, axis2=2)
            g_sys = g_c  # the reduced system's gradient; g_c the forms' own (tests, model)
            if use_x:
                g_c, diag_f = xs.forms_terms(g_sys)
                diag_u += diag_f
            if identity_damping:  # ParallaxBA / Nielsen: (H + mu I)
                if mu_n is None and not gn:
                    mu_n = initial_nielsen_mu(options.nielsen_tau, diag_u, mask_v, V,
                                              problem.pt_fixed)
                D_c, D_p = np.ones_like(diag_u), np.ones((len(V), 3))
            else:
                D_c = np.clip(diag_u, _MIN_DIAG, _MAX_DIAG)
                D_p = np.clip(np.diagonal(V, axis1=1, axis2=2), _MIN_DIAG, _MAX_DIAG)
            gmax = max(float(np.abs(g_c).max(initial=0.0)), float(np.abs(g_p).max(initial=0.0)))
            if ps is not None:  # priors: control point damping and gradient
                ps.damping_diag(_MIN_DIAG, _MAX_DIAG, identity_damping)
                gmax = max(gmax, float(np.abs(ps.g_x).max(initial=0.0)))
            times.add("normal_equations", tic)
            need_build = False
            if gmax <= options.gradient_tolerance:
                termination = "gradient_tolerance"
                break
        it += 1
        mu = 0.0 if gn else (mu_n if damping == "nielsen" else 1.0 / radius)
        tic = time.perf_counter()
        Vd = V.copy()
        Vd[:, [0, 1, 2], [0, 1, 2]] += mu * D_p
        Vd[problem.pt_fixed] = np.eye(3)
        if active is not None:  # rows/columns of held components are zero apart from damping
            ai, ac = np.nonzero(active)
            Vd[ai, ac, :] = 0.0
            Vd[ai, :, ac] = 0.0
            Vd[ai, ac, ac] = 1.0
        diag_c = np.where(mask_v > 0, mu * D_c, 1.0)
        if use_x:
            system = xs.reduced_system(U, W, Vd, g_sys, g_p, diag_c, mu * D_p)
        else:
            system = st.reduced_system(U, W, Vd, g_c, g_p, diag_c)
        if system is not None and ps is not None:  # priors: control points eliminated
            S_g = ps.schur_into(system[0], system[1], mu, st.var_index, mask_v)
            system = None if S_g is None else (S_g, system[1], system[2])
        times.add("schur", tic)
        tic = time.perf_counter()
        x = None
        if system is not None:
            S, b, Li = system
            x = st.solve(S, b)
            system = S = b = None  # factored and solved: not held through the trial evaluation
        times.add("solve", tic)
        if x is None:
            trace.append(IterationRecord(it, cost, False, rec_radius(), 0.0, gmax,
                                         time.perf_counter() - t0, mu))
            if gn:
                termination = "linear_solver_failure"
                break
            stop = damp_more()
            if stop:
                termination = stop
                break
            continue
        tic = time.perf_counter()
        dc = x.reshape(st.Nv, 6) * mask_v
        dp = (xs.back_substitute(W, Li, g_p, dc) if use_x
              else st.back_substitute(W, Li, g_p, dc)) * pt_free
        # Predicted decrease of the linear model: 1/2 (-g^T dx + mu dx^T D dx).
        a_lin = -(g_c * dc).sum() - (g_p * dp).sum()
        q_damp = mu * ((D_c * dc**2 * mask_v).sum() + (D_p * dp**2).sum())
        dXg = None
        if ps is not None:  # priors: control point step and its share of the model
            dXg = ps.step(dc)
            a_lin -= (ps.g_x * dXg).sum()
            q_damp += mu * (ps.D_x * dXg**2).sum()
        model = 0.5 * (a_lin + q_damp)
        delta = None
        if bounds is not None:
            # additive retraction (parallax forms): clip the step onto the box
            # (unbounded columns: clip(x) - x = 0; only the bounded ones are computed)
            xb = pts[:, bcols] + dp[:, bcols]
            d_b = np.clip(xb, lo_b, hi_b) - xb
            if d_b.any():
                delta = np.zeros(pts.shape)
                delta[:, bcols] = d_b
                model = _clipped_model(a_lin, q_damp, g_p, dp, delta, D_p, V, mu)
                dp = dp + delta
        step_norm = float(np.sqrt((dc**2).sum() + (dp**2).sum()
                                  + (0.0 if dXg is None else (dXg**2).sum())))
        x_norm = float(np.sqrt((C**2).sum() + (pts**2).sum()))
        if step_norm <= options.parameter_tolerance * (x_norm + options.parameter_tolerance):
            termination = "parameter_tolerance"
            trace.append(IterationRecord(it, cost, False, rec_radius(), step_norm, gmax,
                                         time.perf_counter() - t0, mu))
            break
        R_new = R.copy()
        C_new = C.copy()
        vc = st.var_cams
        R_new[vc] = so3_exp(dc[:, :3]) @ R[vc]
        C_new[vc] = C[vc] + dc[:, 3:]
        pts_new = param.retract_points(pts, dp)
        if delta is not None:  # exactly on the bound, not a rounding error outside it
            pts_new = np.clip(pts_new, bounds[0], bounds[1])
        times.add("update", tic)
        tic = time.perf_counter()
        # the last iteration's Jacobians would never be read (the loop ends whether its step is
        # accepted or not): residuals only there. The mapper's local BAs all end at their
        # iteration limit, so this was one Jacobian evaluation in seven of each
        last = it >= options.max_iterations
        r_new, Jp_new, Jc_new = param.evaluate(R_new, C_new, pts_new, jac=not (lazy or last),
                                               factored=factored)
        times.add("evaluate", tic)
        new_cost, w_new = _robust(r_new, param.groups, loss, scale)
        Xg_new = None
        if prior is not None:
            Xg_new = Xg + dXg
            new_cost += prior.cost(R_new, C_new, Xg_new)
        gain = (cost - new_cost) / model if model > 0 else -1.0
        if gn:  # Gauss-Newton takes every finite step (ParallaxBA's GN mode)
            accepted = bool(np.isfinite(new_cost))
        else:  # Ceres rejects gains <= 1e-3, Nielsen / ParallaxBA only gains <= 0
            accepted = bool(np.isfinite(new_cost) and gain > (
                0.0 if damping == "nielsen" else _MIN_RELATIVE_DECREASE))
        trace.append(IterationRecord(it, new_cost if accepted else cost, accepted, rec_radius(),
                                     step_norm, gmax, time.perf_counter() - t0, mu, gain))
        if gn and not accepted:
            termination = "non_finite_cost"
            break
        if accepted:
            accepted_n += 1
            clipped_steps += delta is not None
            rel = abs(cost - new_cost) / cost if cost > 0 else 0.0
            R, C, pts, Xg = R_new, C_new, pts_new, Xg_new
            r, Jp, Jc, w, cost = r_new, Jp_new, Jc_new, w_new, new_cost
            r_new = Jp_new = Jc_new = None
            V = Vd = W = U = None  # the rebuild allocates its own
            radius = min(options.max_trust_radius,
                         radius / max(1.0 / options.max_radius_growth,
                                      1.0 - (2.0 * gain - 1.0) ** 3))
            decrease_factor = 2.0
            if damping == "nielsen" and not gn:
                mu_n *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
                nu = 2.0
            need_build = True
            if rel < options.function_tolerance:
                termination = "function_tolerance"
                break
        else:
            stop = damp_more()
            if stop:
                termination = stop
                break
    problem.R, problem.C = R, C
    if Xg is not None:
        problem.control_X = Xg
    param.store(R, C, pts)
    final_px_cost, final_rms = pixel_cost(_pixel_residuals(param, R, C, pts, r), loss, scale)
    summary = BASummary(
        param=options.param, loss=loss, initial_cost=initial_cost, final_cost=cost,
        initial_pixel_cost=init_px_cost, final_pixel_cost=final_px_cost,
        initial_rms_px=init_rms, final_rms_px=final_rms, iterations=it,
        accepted_iterations=accepted_n, rejected_iterations=it - accepted_n,
        solver=options.solver, damping="none" if gn else damping, wall_s=time.perf_counter() - t0,
        termination=termination, num_cameras=problem.num_cameras,
        num_points=problem.num_points, num_observations=problem.num_observations,
        num_variable_cameras=st.Nv, gauge=problem.gauge,
        exclusions={k: v for k, v in problem.exclusions.items() if v},
        linear_solver=st.linear_solver_name() + xspace_note(builds_x, builds_ref),
        trace=trace, time_in=times.seconds, setup_s=setup_s,
        behind_camera={"initial": behind0, "final": behind_camera_xyz(
            problem.R, problem.C, problem.X, problem.obs_cam, problem.obs_pt, st.fast)})
    summary.points_state = pts
    if bounds is not None:
        summary.point_bounds = {
            "at_lower": int((pts <= bounds[0]).any(1).sum()),
            "at_upper": int((pts >= bounds[1]).any(1).sum()),
            "clipped_steps": clipped_steps}
    log.debug("BA %s: cost %.6g -> %.6g in %d iterations (%s)", options.param, initial_cost,
              cost, it, termination)
    return summary
