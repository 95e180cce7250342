"""Self-calibration: intrinsics shared by the images of one camera, refined in every BA form.

Layout. The free intrinsics of one camera group (focal, principal point, distortion; chosen by
``BAOptions.refine``) are cut into chunks of three; each chunk is a *pseudo camera* appended to
the problem's cameras, whose centre ``C`` holds the three (scaled) values and whose rotation
columns are masked. The solver's additive centre update is then exactly the intrinsics update,
and every observation gets one extra camera slot per chunk (columns 3:6), so the intrinsics
join the reduced camera system through the unchanged Schur machinery (U, W, g, damping,
back-substitution). Values are scaled by the initial focal length (focal, principal point) so
the columns of S stay within a few orders of magnitude.

Residual Jacobians with respect to the intrinsics ``k`` (analytic, never finite differences):

* pixel rows: ``uv_D_k`` of the projection at the predicted camera-frame point;
* angular rows (polar, angular): the observed angles move with ``k``. They are defined by
  ``project(ray(ang), k) = uv_obs``, so ``ang_obs_D_k = -A uv_D_k(ray_obs)`` with
  ``A = ang_D_uv`` at the observed pixel (implicit function theorem), and the residual
  ``W (ang_pred - ang_obs)`` gets ``+W A uv_D_k(ray_obs)``. The same holds for the axis
  chart with ``B = e_D_uv``.
* the whitening moves too: ``W = A^-1 = uv_D_ang`` at the observed angles (``B^-1`` on the
  chart rows, ``1 / |theta_D_uv|`` on the theta rows) is re-evaluated at the current intrinsics,
  and its derivative ``dW/dk (ang_pred - ang_obs)`` joins the Jacobian (chart_curvature.py:
  the projection's second derivatives). Held at the starting intrinsics instead (as before
  issue 32), the angle-unit cost fell as the focal length grew and the solves settled on a
  focal too long by ~noise^2 (reports/collections/angular-focal-bias.md): a different
  objective, not the pixel-equivalent one. The gating (which rows use phi, which the chart) stays fixed
  for a solve so the cost stays smooth.

The 7-DoF similarity gauge is unchanged: intrinsics add no gauge freedom for a general scene.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np

from polarref.ba.angular_obs import axis_chart_rows, phi_rows, theta_rows, wrap
from polarref.ba.chart_curvature import (ChartLens, angle_whitening_D_k, chart_whitening_D_k,
                                         theta_weight_D_k)
from polarref.ba.options import IntrinsicsResult  # noqa: F401 (re-exported: its record lives with BASummary)
from polarref.ba.parameterization import BoundedPoints, Staged
from polarref.ba.parameterization import make_param
from polarref.ba.problem import BAProblem, prepare
from polarref.ba.refine import REFINE_GROUPS, parse_refine  # noqa: F401 (REFINE_GROUPS re-exported)
from polarref.ba.solver import solve
from polarref.ba.projection import Projector, radial_params
from polarref.camera import Camera, ray_from_angular
from polarref.camera.models import MODELS

log = logging.getLogger(__name__)

def free_indices(model: str, refine: tuple[str, ...]) -> np.ndarray:
    """Indices into the model's parameter vector refined for the groups ``refine``.

    ``dist`` is every distortion coefficient of the model, e.g. OPENCV's k1, k2, p1, p2.
    """
    spec = MODELS[model]
    idx = []
    if "focal" in refine:
        idx += sorted({spec.fx, spec.fy})
    if "pp" in refine:
        idx += [spec.cx, spec.cy]
    if "dist" in refine:
        idx += list(spec.extra)
    return np.array(idx, np.int64)


# map of the fast kernel's per-observation table (fx, fy, cx, cy, k1, k2) onto model params
_K6_OF = {"SIMPLE_PINHOLE": (0, 2, 3), "PERSPECTIVE": (0, 2, 3), "PINHOLE": (0, 1, 2, 3),
          "SIMPLE_RADIAL": (0, 2, 3, 4), "RADIAL": (0, 2, 3, 4, 5)}


def uv_D_params(cam: Camera, Xc: np.ndarray) -> np.ndarray:
    """``uv_D_params`` (M, 2, P) of ``cam`` at camera-frame points Xc (M, 3), params in order.

    Pinhole+radial models use the closed form of the BA's fast kernel (defined for any depth,
    like the kernel itself); other models (OPENCV_FISHEYE, OPENCV, ...)
    ``Camera.project_params_jacobian``, zero outside the model's field of view.
    """
    K = radial_params(cam)
    if K is None:
        return np.nan_to_num(cam.project_params_jacobian(Xc))
    fx, fy, _, _, k1, k2 = K
    x, y = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
    r2 = x * x + y * y
    dist = 1.0 + r2 * (k1 + k2 * r2)
    J6 = np.zeros((len(Xc), 2, 6))
    J6[:, 0, 0] = x * dist
    J6[:, 1, 1] = y * dist
    J6[:, 0, 2] = J6[:, 1, 3] = 1.0
    J6[:, 0, 4], J6[:, 1, 4] = fx * x * r2, fy * y * r2
    J6[:, 0, 5], J6[:, 1, 5] = fx * x * r2 * r2, fy * y * r2 * r2
    cols = _K6_OF[cam.model]
    J = J6[:, :, list(cols)]
    if cam.model in ("SIMPLE_PINHOLE", "PERSPECTIVE", "SIMPLE_RADIAL", "RADIAL"):
        J[:, :, 0] += J6[:, :, 1]  # one focal length drives fx and fy
    return J


def default_groups(cameras: list) -> np.ndarray:
    """(N,) group per camera: cameras with equal intrinsics share one group."""
    seen: dict = {}
    return np.array([seen.setdefault(c, len(seen)) for c in cameras], np.int64)


class IntrinsicsBlocks:
    """The pseudo-camera layout of the free intrinsics (see the module docstring)."""

    def __init__(self, cameras: list, groups: np.ndarray, refine: tuple[str, ...], force_pp: bool = False):
        self.groups = np.asarray(groups, np.int64)
        G = int(self.groups.max()) + 1
        self.cams0: list[Camera] = []
        for g in range(G):
            members = np.flatnonzero(self.groups == g)
            first = cameras[int(members[0])]
            if any(cameras[int(i)] != first for i in members[1:]):
                log.warning("intrinsics group %d: images start from different intrinsics; "
                            "using those of its first image", g)
            self.cams0.append(first)
        self.free = [free_indices(c.model, refine) for c in self.cams0]
        if "pp" in refine and not force_pp:
            self._hold_single_image_pp(refine)
        self.scale = [np.where(np.isin(f, list(MODELS[c.model].extra)), 1.0, c.fx)
                      for c, f in zip(self.cams0, self.free)]
        # chunks: (group, first free index, count) -> pseudo camera N + j
        self.chunks = [(g, a, min(3, len(f) - a)) for g, f in enumerate(self.free)
                       for a in range(0, len(f), 3)]
        self.num_slots = max((sum(1 for c in self.chunks if c[0] == g) for g in range(G)),
                             default=0)

    def _hold_single_image_pp(self, refine: tuple[str, ...]) -> None:
        # One image does not separate the principal point from its own rotation (a BAL solve
        # moved it by 80 px): groups of one image keep theirs unless the caller forces it.
        single = [g for g in range(len(self.cams0)) if int((self.groups == g).sum()) == 1]
        if not single:
            return
        held = tuple(r for r in refine if r != "pp")
        for g in single:
            self.free[g] = free_indices(self.cams0[g].model, held)
        log.warning("principal point held on %d of %d intrinsics groups that hold one image each "
                    "(it is not constrained there; force it with polarref ba --refine-pp-single)",
                    len(single), len(self.cams0))

    @property
    def num_pseudo(self) -> int:
        """Pseudo cameras: one per chunk, plus one fixed placeholder for unused slots."""
        return len(self.chunks) + 1

    def initial_values(self) -> np.ndarray:
        """(num_pseudo, 3) scaled free values (the pseudo cameras' centres)."""
        out = np.zeros((self.num_pseudo, 3))
        for j, (g, a, n) in enumerate(self.chunks):
            f = self.free[g][a:a + n]
            out[j, :n] = self.cams0[g].params[f] / self.scale[g][a:a + n]
        return out

    def masks(self) -> np.ndarray:
        """(num_pseudo, 6) free columns of the pseudo cameras (rotation columns never)."""
        m = np.zeros((self.num_pseudo, 6), bool)
        for j, (_, _, n) in enumerate(self.chunks):
            m[j, 3:3 + n] = True
        return m

    def slot_cams(self, obs_cam: np.ndarray, N: int) -> np.ndarray:
        """(num_slots, M) pseudo camera of each observation per intrinsics slot."""
        table = np.full((int(self.groups.max()) + 1, max(self.num_slots, 1)),
                        N + self.num_pseudo - 1)
        count = np.zeros(len(table), np.int64)
        for j, (g, _, _) in enumerate(self.chunks):
            table[g, count[g]] = N + j
            count[g] += 1
        return table[self.groups[obs_cam]].T[:self.num_slots]

    def cameras(self, values: np.ndarray) -> list[Camera] | None:
        """Group cameras at scaled free values (num_pseudo, 3); None if a model rejects them."""
        params = [c.params.copy() for c in self.cams0]
        for j, (g, a, n) in enumerate(self.chunks):
            params[g][self.free[g][a:a + n]] = values[j, :n] * self.scale[g][a:a + n]
        try:
            return [Camera(c.model, c.width, c.height, p) for c, p in zip(self.cams0, params)]
        except ValueError:
            return None


class SelfCalibrating:
    """Wraps a parameterization (euclidean, parallax, polar, angular) with intrinsics slots.

    Presents the solver's parameterization interface on the augmented problem (cameras
    ``0..N-1`` real, ``N..`` pseudo); the inner parameterization works on the real problem.
    """

    def __init__(self, inner, blocks: IntrinsicsBlocks, real: BAProblem, aug: BAProblem):
        self.inner, self.blocks, self.real, self.aug = inner, blocks, real, aug
        self.name, self.k, self.groups = inner.name, inner.k, inner.groups
        self.N = real.num_cameras
        self.slot_cams = np.vstack([inner.slot_cams, blocks.slot_cams(real.obs_cam, self.N)])
        self.slot_cols = tuple(inner.slot_cols) + ((3, 6),) * blocks.num_slots
        self.anchor_cams = None  # anchors go through the generic slot path (dense Jacobians)
        # the inner form's optional capabilities (parameterization.py) pass through
        if isinstance(inner, BoundedPoints):
            self.point_bounds = inner.point_bounds
        if isinstance(inner, Staged):
            self.set_stage = inner.set_stage
        og = blocks.groups[real.obs_cam]
        self.obs_of_group = [np.flatnonzero(og == g) for g in range(len(blocks.cams0))]
        self._key = None

    # -- intrinsics-dependent state of the inner parameterization -----------------------------
    def _set(self, C: np.ndarray) -> list[Camera] | None:
        values = C[self.N:]
        key = values.tobytes()
        if key == self._key:
            return self._cams
        cams = self.blocks.cameras(values)
        self._key, self._cams = key, cams
        if cams is None:
            return None
        inner, p = self.inner, self.real
        inner.proj = Projector([cams[g] for g in self.blocks.groups], p.obs_cam)
        if inner.name in ("polar", "angular"):
            M = p.num_observations
            self.ang, self.A = np.full((M, 2), np.nan), np.full((M, 2, 2), np.nan)
            for cam, idx in zip(cams, self.obs_of_group):
                self.ang[idx], self.A[idx] = cam.to_angular_with_jacobian(p.obs_uv[idx])
            self._rewhiten(cams)
        return cams

    def _rewhiten(self, cams: list[Camera]) -> None:
        """The inner form's observed angles and whitening at the current intrinsics, with its
        own formulas (polar.py, angular.py); the gating (phi_ok, chart_idx) stays as built."""
        inner, p = self.inner, self.real
        if inner.name == "polar":
            inner.theta_obs = np.ascontiguousarray(self.ang[:, 0])
            inner.w_theta = 1.0 / np.linalg.norm(self.A[:, 0, :], axis=1)
            return
        inner.obs_ang = np.stack([self.ang[:, 0], np.nan_to_num(self.ang[:, 1])], 1)
        inner.whiten = np.linalg.inv(np.where(inner.phi_ok[:, None, None], self.A, np.eye(2)))
        inner.w_theta = 1.0 / np.linalg.norm(np.nan_to_num(self.A[:, 0, :]), axis=1).clip(1e-300)
        if len(inner.chart_idx):
            # the chart point of the observed angles and W = uv_D_e there, exact (chart_curvature)
            # where angular_obs.axis_chart_rows' near-axis branch (t < 1e-3) truncates the value
            # to (x, y) / z while its Jacobian keeps the t^2 term: the two differ at O(t^2),
            # < 4e-7 relative, which is nothing for the residual but O(1) in the whitening's
            # intrinsics derivative on those rows
            ci = inner.chart_idx
            th, ph = self.ang[ci, 0], np.nan_to_num(self.ang[ci, 1])
            inner.chart_obs = th[:, None] * np.stack([np.cos(ph), np.sin(ph)], 1)
            inner.chart_whiten = np.empty((len(ci), 2, 2))
            cg = self.blocks.groups[p.obs_cam[ci]]
            for g, cam in enumerate(cams):
                sel = np.flatnonzero(cg == g)
                inner.chart_whiten[sel] = ChartLens.at(cam, inner.chart_obs[sel]).jacobian()
            self.B = np.linalg.inv(inner.chart_whiten)
        inner.refresh_kernel_rows()

    def camera_points(self, R, C, pts) -> np.ndarray:
        """(M, 3) camera-frame points/rays of the inner parameterization."""
        if self.inner.name == "euclidean":
            return self.inner.camera_frame(R, C, pts)[1]
        return self.inner.rays(R, C, pts, False)[0]

    def res_D_intrinsics(self, R, C, pts, cams) -> np.ndarray:
        """(M, k, 3 num_slots) residual Jacobian w.r.t. the scaled free intrinsics."""
        inner, b = self.inner, self.blocks
        M = self.real.num_observations
        out = np.zeros((M, self.k, 3 * max(b.num_slots, 1)))
        Xc = self.camera_points(R, C, pts)
        for g, (cam, idx) in enumerate(zip(cams, self.obs_of_group)):
            f, s = b.free[g], b.scale[g]
            q = len(f)
            if q == 0 or len(idx) == 0:
                continue
            if inner.name != "angular":  # pixel rows
                out[idx, :2, :q] = uv_D_params(cam, Xc[idx])[:, :, f] * s
            if inner.name in ("polar", "angular"):
                rows = slice(2, 3) if inner.name == "polar" else slice(0, 2)
                out[idx, rows, :q] = self._angle_rows_D_k(cam, idx, f, s, Xc[idx])
        if inner.name == "angular" and inner.use_chart:
            ci = inner.chart_idx
            cg = b.groups[self.real.obs_cam[ci]]
            e_pred = axis_chart_rows(Xc[ci], False)[0]
            for g, cam in enumerate(cams):
                sel = np.flatnonzero(cg == g)
                q = len(b.free[g])
                if q == 0 or len(sel) == 0:
                    continue
                ray = ray_from_angular(self.ang[ci[sel], 0], np.nan_to_num(self.ang[ci[sel], 1]))
                dP = uv_D_params(cam, ray)[:, :, b.free[g]] * b.scale[g]
                delta = e_pred[sel] - inner.chart_obs[sel]
                out[ci[sel], :, :q] = dP + chart_whitening_D_k(
                    cam, inner.chart_obs[sel], self.B[sel], dP, delta, b.free[g], b.scale[g])
        # free values of one group are laid out chunk after chunk: slot j = columns 3j:3j+3
        return out

    def _angle_rows_D_k(self, cam: Camera, idx, free, scale, Xc) -> np.ndarray:
        """Jacobian (n, r, q) of the angle rows of observations ``idx`` (r = 2: the angular
        form's (theta, phi) or theta-only rows; r = 1: the polar form's theta row) w.r.t. the
        free scaled intrinsics: the observed angles' motion plus the whitening's."""
        inner = self.inner
        ang = np.stack([self.ang[idx, 0], np.nan_to_num(self.ang[idx, 1])], 1)
        A = self.A[idx]
        dP = uv_D_params(cam, ray_from_angular(ang[:, 0], ang[:, 1]))[:, :, free] * scale
        dt = theta_rows(Xc, False)[0] - ang[:, 0]
        out = np.zeros((len(idx), 1 if inner.name == "polar" else 2, len(free)))
        if inner.name == "polar":
            t = np.arange(len(idx))
        else:  # theta-only rows; the chart rows' Jacobian is res_D_intrinsics'
            t = np.flatnonzero(~inner.use_phi[idx]
                               & ~(inner.use_chart & np.isin(idx, inner.chart_idx)))
        if len(t):  # w (theta_pred - theta_obs): theta_obs_D_k = -A0 dP, and w moves
            dw = theta_weight_D_k(cam, ang[t], A[t], dP[t], free, scale)
            out[t, 0] = inner.w_theta[idx[t], None] * np.einsum("ni,niq->nq", A[t, 0, :], dP[t]) \
                + dt[t, None] * np.nan_to_num(dw)
        if inner.name == "polar":
            return out
        u = np.flatnonzero(inner.use_phi[idx])
        if len(u):  # W (ang_pred - ang_obs): W ang_obs_D_k = -W A dP = -dP, and W moves
            delta = np.stack([dt[u], wrap(phi_rows(Xc[u], False)[0] - ang[u, 1])], 1)
            out[u] = dP[u] + angle_whitening_D_k(cam, ang[u], A[u], dP[u], delta, free, scale)
        return out

    # -- the solver's interface ---------------------------------------------------------------
    def init_points(self):
        return self.inner.init_points()

    def retract_points(self, pts, dp):
        return self.inner.retract_points(pts, dp)

    def evaluate(self, R, C, pts, jac: bool = True, factored: bool = False):
        cams = self._set(C)
        N, M = self.N, self.real.num_observations
        if cams is None:  # e.g. a step to focal <= 0: an infinite cost rejects it
            bad = np.full((M, self.k), np.inf)
            if not jac:
                return bad, None, None
            return bad, np.zeros((M, self.k, 3)), [np.zeros((M, self.k, c1 - c0))
                                                   for c0, c1 in self.slot_cols]
        r, Jp, Jc = self.inner.evaluate(R[:N], C[:N], pts, jac, factored=False)
        if not jac:
            return r, None, None
        Jk = self.res_D_intrinsics(R[:N], C[:N], pts, cams)
        return r, Jp, list(Jc) + [Jk[:, :, 3 * j:3 * j + 3] for j in range(self.blocks.num_slots)]

    def pixel_residuals(self, R, C, pts):
        self._set(C)
        return self.inner.pixel_residuals(R[:self.N], C[:self.N], pts)

    def store(self, R, C, pts) -> None:
        self._set(C)
        self.inner.store(R[:self.N], C[:self.N], pts)
        self.aug.X = self.real.X


def augmented_problem(problem: BAProblem, blocks: IntrinsicsBlocks) -> BAProblem:
    """The prepared ``problem`` with the pseudo cameras appended (arrays shared, not copied)."""
    n = blocks.num_pseudo
    aug = BAProblem(problem.cameras, np.concatenate([problem.R, np.tile(np.eye(3), (n, 1, 1))]),
                    np.concatenate([problem.C, blocks.initial_values()]), problem.X,
                    problem.obs,
                    np.r_[problem.cam_fixed, ~blocks.masks().any(1)], problem.pt_fixed,
                    problem.image_ids, problem.point_ids,
                    np.concatenate([problem.cam_mask, blocks.masks()]),
                    problem.gauge, problem.exclusions)
    return aug


def solve_calibrating(problem: BAProblem, options, *, prepared: bool = False):
    """LM over poses, points and the free intrinsics (``options.refine``); updates ``problem``
    in place (R, C, X and ``cameras``) and returns the BASummary with ``intrinsics`` filled."""
    if not prepared:
        prepare(problem)
    refine = parse_refine(options.refine)
    groups = (default_groups(problem.cameras) if problem.camera_group is None
              else np.asarray(problem.camera_group, np.int64))
    blocks = IntrinsicsBlocks(problem.cameras, groups, refine, force_pp=options.refine_pp_single)
    inner_options = dataclasses.replace(options, refine=())
    inner = make_param(problem, inner_options)
    aug = augmented_problem(problem, blocks)
    wrapper = SelfCalibrating(inner, blocks, problem, aug)
    summary = solve(aug, inner_options, prepared=True, param=wrapper)
    N = problem.num_cameras
    problem.R, problem.C = aug.R[:N], aug.C[:N]
    cams = blocks.cameras(aug.C[N:])
    problem.cameras = [cams[g] for g in groups]
    summary.num_cameras = N
    summary.num_variable_cameras = int(problem.cam_mask.any(1).sum())
    summary.gauge = problem.gauge + f"; intrinsics refined: {','.join(refine) or 'none'}"
    summary.intrinsics = [
        IntrinsicsResult(g, c0.model, MODELS[c0.model].names, c0.params.tolist(),
                         c1.params.tolist(), tuple(MODELS[c0.model].names[i] for i in blocks.free[g]),
                         int((groups == g).sum()))
        for g, (c0, c1) in enumerate(zip(blocks.cams0, cams))]
    return summary
