"""ParallaxBA landmarks (Zhao et al. 2015): main/associate anchors, azimuth, elevation, parallax.

Binding definition: ``d = F_p direction_from_azimuth_elevation(alpha, beta)`` is the world
direction from the main anchor centre ``C_m`` to the point, with ``F_p`` a fixed per-point
rotation whose first column is the initial direction (``direction_frames``): every point starts
at (alpha, beta) = (0, 0), 90 degrees from the poles of the azimuth/elevation chart. With world
azimuth/elevation (pole along world z) the ParallaxBA fake pile, a camera moving and looking
along +z, started half its points above 50 degrees elevation, where ``d d / d alpha`` shrinks
with cos(beta): LM needed 74 iterations (Gauss-Newton 21), with these frames 23 (GN 7).
ParallaxBA puts its pole along world y, across the viewing direction of its datasets.
``e = C_a - C_m``; ``phi_a = angle(d, e)``; the unnormalized ray from camera centre ``C_i`` is
``v_i = sin(w) (C_m - C_i) + |e| sin(w + phi_a) d``. We write
``|e| sin(w + phi_a) = sin(w) (d.e) + cos(w) |d x e|``, which has no inverse trigonometry,
so ``v_i = sin(w) (P - C_i)`` for a finite point and ``|d x e| d`` at infinity (w = 0).

Bounds: w is kept in ``[0, pi - OMEGA_MARGIN]`` (ParallaxBA's omega in (0, pi), with the point
at infinity along +d, w = 0, included). Pixel residuals cannot see the sign of ``sin(w)``: for
w < 0 the point passes through infinity and comes back behind the anchors (``v_i`` flips with
it, so it projects to the same pixel); on a forward rig at baseline/depth 3e-4 LM drove 73 of
150 points there and 49 % of the written-back observations were behind their camera. The
solver enforces the box by an active set and a projected step (see solver.py).
The point's 3 parameters also couple to the anchors' centres: an observation has 3 camera
slots (observing, main, associate) whose Jacobians go into those cameras' blocks.
"""

from __future__ import annotations

import copy
from types import SimpleNamespace

import numpy as np

from polarref.core.angular import (azimuth_elevation_from_direction, direction_from_azimuth_elevation,
                              direction_jacobian)
from polarref.ba.anchor_terms import AnchorJacobian
from polarref.ba.euclidean import rot_columns
from polarref.ba.kernels import use_kernels
from polarref.ba.problem import BAProblem
from polarref.ba.projection import Projector
from polarref.core.errors import PolarrefError

FAR = 1e8  # points at infinity are written back this many baselines from the main anchor
# w = pi is the point at infinity along -d (behind the main anchor): stop just short of it
OMEGA_MARGIN = 1e-6


def choose_anchors(problem: BAProblem, compiled: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Main anchor = first observation's camera; associate = the observing camera whose ray to
    the point makes the parallax angle closest to 90 degrees with the main ray (largest
    ``sin(omega)``). Returns (main (P,), assoc (P,), omega (P,)).

    ParallaxBA takes the largest parallax angle, which suits forward-moving sequences; with
    cameras around the scene that picks omega near 180 degrees, where ``sin(omega) -> 0``: the
    point sits almost on the anchors' baseline and its position becomes extremely nonlinear
    in (direction, omega). On synth-20 (omega up to 179.3 degrees) LM then needed 81/62/76
    iterations (parallax/polar/angular) instead of 4-5. Observations are sorted by point.
    ``compiled``: the same choice by forms_jit's one-pass kernel (tests compare the two).
    """
    p = problem
    starts = np.flatnonzero(np.r_[True, p.obs_pt[1:] != p.obs_pt[:-1]])
    main = p.obs_cam[starts]
    if compiled:
        from polarref.ba import kernels
        best = kernels.best_associates(p.obs_cam, p.obs_pt, p.C, p.X)
        # omega by the reference's own arithmetic on the chosen observations: the kernel's
        # last-bit differences part chaotic solves (test_ba_bounds' held components)
        omega = _parallax_angles(p, main, best)  # best (P,): one observation per point, in order
    else:
        ang = _parallax_angles(p, main[p.obs_pt], np.arange(p.num_observations))
        # arg-max per point over its sorted run of observations
        score = np.where(ang >= 0, np.sin(ang), -1.0)
        best = np.lexsort((-score, p.obs_pt))[starts]
        omega = ang[best]
    _check_associates(omega)
    assoc = p.obs_cam[best]
    assert len(assoc) == len(p.X)
    return main, assoc, omega


def _parallax_angles(p: BAProblem, main_cam: np.ndarray, obs: np.ndarray) -> np.ndarray:
    """Angle between the main anchor's ray and observation ``obs``'s ray to its point (n,);
    -1 where the two centres coincide (unusable). main_cam, obs (n,)."""
    Xo = p.X[p.obs_pt[obs]]
    rm = Xo - p.C[main_cam]
    ri = Xo - p.C[p.obs_cam[obs]]
    cosang = np.einsum("mi,mi->m", rm, ri) / np.maximum(
        np.linalg.norm(rm, axis=1) * np.linalg.norm(ri, axis=1), 1e-300)
    ang = np.arccos(np.clip(cosang, -1.0, 1.0))
    base = np.linalg.norm(p.C[p.obs_cam[obs]] - p.C[main_cam], axis=1)
    return np.where(base > 0, ang, -1.0)


def _check_associates(omega: np.ndarray) -> None:
    if (omega < 0).any():
        raise PolarrefError(f"parallax landmarks: {int((omega < 0).sum())} points are seen only "
                            "from one camera centre (no associate anchor)")


def direction_frames(v: np.ndarray) -> np.ndarray:
    """Per-point rotations (P, 3, 3) whose first column is ``v / |v|`` (v (P, 3)): azimuth and
    elevation are measured in this fixed frame, so every point starts at (0, 0), 90 degrees
    from the parameterization's poles (see the module docstring)."""
    e1 = v / np.linalg.norm(v, axis=1, keepdims=True)
    # the world axis least aligned with e1 gives a well-conditioned second column
    ref = np.eye(3)[np.argmin(np.abs(e1), axis=1)]
    e2 = np.cross(e1, ref)
    e2 /= np.linalg.norm(e2, axis=1, keepdims=True)
    return np.stack([e1, e2, np.cross(e1, e2)], axis=2)


class Parallax:
    """Parallax-angle landmarks with pixel residuals."""

    name = "parallax"
    k = 2
    groups = ((0, 2),)
    # per-observation attributes that residual_rows reads (sliced by rows_view); None: the
    # form cannot evaluate a run of observations on its own (chunked.py then is not used)
    row_arrays: tuple[str, ...] | None = ()

    def __init__(self, problem: BAProblem, options=None):
        self.p = problem
        # compiled rays and chain rule (kernels.py) for the solver's dense slot Jacobians
        self.fast = options is not None and use_kernels(options.kernels)
        # the anchors' maps for the X-space elimination (xspace.py), with the factored kernels
        self.want_maps = options is None or options.anchor_schur == "xspace"
        self.proj = Projector(problem.cameras, problem.obs_cam, compiled=self.fast)
        self.main, self.assoc, omega0 = choose_anchors(problem, compiled=self.fast)
        self.omega0 = omega0
        op = problem.obs_pt
        self.slot_cams = np.stack([problem.obs_cam, self.main[op], self.assoc[op]])
        # observing camera: rotation and centre; anchors: centre only (columns 3:6)
        self.slot_cols = ((0, 6), (3, 6), (3, 6))
        self.anchor_cams = (self.main, self.assoc)  # Jc = [J_obs, AnchorJacobian]
        self.frame = direction_frames(problem.X - problem.C[self.main])

    def init_points(self) -> np.ndarray:
        p = self.p
        a, b = azimuth_elevation_from_direction(
            np.einsum("pji,pj->pi", self.frame, p.X - p.C[self.main]))
        lo, hi = self.point_bounds()
        return np.stack([a, b, np.clip(self.omega0, lo[2], hi[2])], axis=1)

    def point_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Box (lower (3,), upper (3,)) on (alpha, beta, w): w in [0, pi - OMEGA_MARGIN]."""
        return (np.array([-np.inf, -np.inf, 0.0]),
                np.array([np.inf, np.inf, np.pi - OMEGA_MARGIN]))

    def landmark_terms(self, C, pts):
        """Per-point terms of the landmark (see the module docstring), each (P, ...):
        main centre ``C_m`` (P, 3), direction ``d`` (P, 3), baseline ``e`` (P, 3), ``c = d.e``,
        ``s = |d x e|``, ``sin(w)``, ``cos(w)`` and ``h = |e| sin(w + phi_a)`` (P,)."""
        Cm = C[self.main]
        d = np.einsum("pij,pj->pi", self.frame,
                      direction_from_azimuth_elevation(pts[:, 0], pts[:, 1]))
        e = C[self.assoc] - Cm
        c = np.einsum("pi,pi->p", d, e)
        s = np.linalg.norm(np.cross(d, e), axis=1)
        sw, cw = np.sin(pts[:, 2]), np.cos(pts[:, 2])
        return Cm, d, e, c, s, sw, cw, sw * c + cw * s

    def point_derivatives(self, pts, d, e, c, s, sw, cw, h):
        """Per point (see :meth:`landmark_terms`): ``dh/de`` (P, 3), ``dv/d(alpha, beta)``
        without the observation-dependent part (P, 3, 2) and ``dh/dw`` (P,)."""
        Dd = self.frame @ direction_jacobian(pts[:, 0], pts[:, 1])  # (P, 3, 2)
        inv_s = 1.0 / s
        e2 = np.einsum("pi,pi->p", e, e)
        dh_dd = sw[:, None] * e + (cw * inv_s)[:, None] * (e2[:, None] * d - c[:, None] * e)
        dh_de = sw[:, None] * d + (cw * inv_s)[:, None] * (e - c[:, None] * d)
        dv_dab = d[:, :, None] * np.einsum("pi,pij->pj", dh_dd, Dd)[:, None, :] + h[:, None, None] * Dd
        return dh_de, dv_dab, cw * c - sw * s

    def rays(self, R, C, pts, jac: bool):
        """Camera-frame rays Xc (M, 3) = R_i v_i and, with jac, the pieces of their Jacobians."""
        p = self.p
        if self.fast and not jac:
            from polarref.ba import kernels
            Cm, _, sw, _, hd, *_ = kernels.parallax_points(self.frame, pts, C, self.main,
                                                           self.assoc, False)
            return kernels.parallax_rays(R, C, p.obs_cam, p.obs_pt, Cm, sw, hd), None
        Cm, d, e, c, s, sw, cw, h = self.landmark_terms(C, pts)
        op, oc = p.obs_pt, p.obs_cam
        sw_o = sw[op]
        base = Cm[op] - C[oc]
        v = sw_o[:, None] * base + (h[:, None] * d)[op]
        Ri = R[oc]
        Xc = np.einsum("mij,mj->mi", Ri, v)
        if not jac:
            return Xc, None
        dh_de, dv_dab, dh_dw = self.point_derivatives(pts, d, e, c, s, sw, cw, h)
        dv_dw = (dh_dw[:, None] * d)[op] + cw[op][:, None] * base  # (M, 3)
        return Xc, (Ri, sw_o, d, dh_de, dv_dab, dv_dw)

    def residual_rows(self, Xc: np.ndarray, jac: bool):
        """Residuals (M, k) and ``res_D_Xc`` (M, k, 3); pixel residuals here."""
        return self.proj.residuals(Xc, self.p.obs_uv, 2, jac)

    def evaluate(self, R, C, pts, jac: bool = True, factored: bool = False):
        """Residuals (M, k); with jac also ``res_D_point`` (M, k, 3) and the per-slot camera
        Jacobians ``[res_D_obs (M, k, 6), res_D_main_centre (M, k, 3), res_D_assoc_centre
        (M, k, 3)]`` (see ``slot_cams``/``slot_cols``), or with ``factored`` ``[res_D_obs,
        AnchorJacobian]`` (the solver's form, see anchor_terms.py)."""
        if jac and self.fast:
            return self._evaluate_kernels(R, C, pts, factored)
        Xc, parts = self.rays(R, C, pts, jac)
        res, Jx = self.residual_rows(Xc, jac)
        if not jac:
            return res, None, None
        Ri, sw_o, d, dh_de, dv_dab, dv_dw = parts
        k = res.shape[1]
        A = Jx @ Ri  # res_D_v (M, k, 3)
        M = len(Xc)
        op = self.p.obs_pt
        Jp = np.empty((M, k, 3))
        Jp[:, :, :2] = A @ dv_dab[op]
        Jp[:, :, 2] = np.einsum("mki,mi->mk", A, dv_dw)
        J_obs = np.empty((M, k, 6))
        J_obs[:, :, :3] = rot_columns(Xc, Jx)
        J_obs[:, :, 3:] = -sw_o[:, None, None] * A
        # anchors (factored, see anchor_terms.py): d v / d C_a = d dh_de^T, so
        # res_D_C_a = (A d) dh_de^T and res_D_C_m = sin(w) A - res_D_C_a
        Ad = np.einsum("mki,mi->mk", A, d[op])  # (M, k)
        anchors = AnchorJacobian(Ad, dh_de)
        if factored:
            return res, Jp, [J_obs, anchors]
        return res, Jp, [J_obs, *anchors.dense(J_obs, op)]

    def _evaluate_kernels(self, R, C, pts, factored: bool):
        """:meth:`evaluate` through the compiled kernels; factored, with the anchors' maps
        (xspace.py)."""
        terms = self.point_terms_for_rows(R, C, pts)
        res, Jp, Jc = self._evaluate_obs_kernels(R, C, terms, factored)
        if factored and self.want_maps:
            from polarref.ba import xspace_jit
            _, d, sw, _, _, _, dh_de, dv_dab = terms
            Jc[1].maps = xspace_jit.anchor_maps(d, sw, dh_de, dv_dab, C, self.main, self.assoc)
        return res, Jp, Jc

    def _evaluate_obs_kernels(self, R, C, terms, factored: bool):
        """The per-observation part of :meth:`_evaluate_kernels` (all of ``self.p``'s
        observations; a :meth:`rows_view` has a run of them) from the per-point terms."""
        from polarref.ba import kernels
        p = self.p
        Cm, d, sw, cw, hd, dh_dw, dh_de, dv_dab = terms
        fused = self.fused_obs(R, C, terms) if factored else None
        if fused is not None:  # ray, rows and chain rule in one pass (forms_jit.py)
            res, Jp, J_obs, Ad, G = fused
            return res, Jp, [J_obs, AnchorJacobian(Ad, dh_de, row_map=G)]
        Xc = kernels.parallax_rays(R, C, p.obs_cam, p.obs_pt, Cm, sw, hd)
        res, Jx = self.residual_rows(Xc, True)
        Jp, J_obs, J_m, J_a, Ad = kernels.parallax_jacobians(
            np.ascontiguousarray(Jx), Xc, R, C, p.obs_cam, p.obs_pt, Cm, d, sw, cw,
            dh_dw, dh_de, dv_dab, not factored)
        if factored:
            return res, Jp, [J_obs, AnchorJacobian(Ad, dh_de)]
        return res, Jp, [J_obs, J_m, J_a]

    def fused_obs(self, R, C, terms):
        """(res, res_D_point, res_D_obs, A d, row map or None) of the factored evaluation in
        one compiled pass, or None: the form evaluates its stages one by one (forms_jit.py says
        why; the row map: polar's mapped rows, row_map.py)."""
        return None

    def supports_rows(self) -> bool:
        """Whether :meth:`evaluate_rows` is available (compiled kernels, fast projector)."""
        return self.row_arrays is not None and self.fast and self.proj.fast

    def point_terms_for_rows(self, R, C, pts):
        """Per-point terms (kernels.parallax_points) shared by every :meth:`evaluate_rows`."""
        from polarref.ba import kernels
        return kernels.parallax_points(self.frame, pts, C, self.main, self.assoc, True)

    def rows_view(self, m0: int, m1: int) -> "Parallax":
        """A shallow copy that sees only observations m0:m1 (their indices, pixels,
        intrinsics and ``row_arrays``; the per-point arrays stay whole)."""
        v = copy.copy(self)
        p = self.p
        v.p = SimpleNamespace(obs_cam=p.obs_cam[m0:m1], obs_pt=p.obs_pt[m0:m1],
                              obs_uv=p.obs_uv[m0:m1])
        v.proj = self.proj.rows(m0, m1)
        for name in self.row_arrays:
            setattr(v, name, getattr(self, name)[m0:m1])
        return v

    def anchor_maps_for_rows(self, R, C, terms):
        """The anchors' maps (Bm (P, 3, 3), b (P, 3), xspace.py) from the per-point ``terms``
        of :meth:`point_terms_for_rows`, as :meth:`evaluate` (kernels, factored) attaches them."""
        from polarref.ba import xspace_jit
        _, d, sw, _, _, _, dh_de, dv_dab = terms
        return xspace_jit.anchor_maps(d, sw, dh_de, dv_dab, C, self.main, self.assoc)

    def evaluate_rows(self, R, C, terms, m0: int, m1: int):
        """:meth:`evaluate` (kernels, factored) of observations m0:m1 with the per-point
        ``terms`` of :meth:`point_terms_for_rows`: (res, res_D_point, [res_D_obs,
        AnchorJacobian]) with m1 - m0 rows (AnchorJacobian.h still per point, all P)."""
        return self.rows_view(m0, m1)._evaluate_obs_kernels(R, C, terms, True)

    def num_behind_camera(self, R, C, pts) -> int:
        """Observations whose point has depth <= 0 in the observing camera. ``v_i`` is
        ``sin(w) (P - C_i)``, so its depth is the point's times the sign of ``sin(w)``
        (w = 0: the point at infinity along +d, whose depth sign is that of ``R_i d``)."""
        Xc, _ = self.rays(R, C, pts, False)
        sgn = np.where(np.sin(pts[:, 2]) < 0, -1.0, 1.0)[self.p.obs_pt]
        return int((sgn * Xc[:, 2] <= 0).sum())

    def pixel_residuals(self, R, C, pts) -> np.ndarray:
        Xc, _ = self.rays(R, C, pts, False)
        return self.proj.residuals(Xc, self.p.obs_uv, 2, False)[0]

    def pixel_part(self, res: np.ndarray) -> np.ndarray | None:
        """The pixel residuals inside :meth:`evaluate`'s residuals (rows 0:2; polar's third
        row is the view angle), bitwise :meth:`pixel_residuals` on the compiled path (the
        same per-point terms, rays and pixel rows with and without Jacobians); None else."""
        return res[:, :2] if self.fast and self.proj.compiled else None

    def retract_points(self, pts, dp):
        return pts + dp

    def to_xyz(self, R, C, pts) -> np.ndarray:
        """XYZ of the landmarks; points at infinity (w ~ 0) go FAR baselines out along d."""
        if self.fast:  # the solve's write-back: compiled (kernels.py), equal to rounding
            from polarref.ba import kernels
            X, self.num_at_infinity = kernels.parallax_xyz(self.frame, pts, C, self.main,
                                                           self.assoc, FAR)
            return X
        Cm, d, e, _, _, sw, _, h = self.landmark_terms(C, pts)
        base = np.linalg.norm(e, axis=1)
        far = np.abs(sw) * FAR < 1.0
        dist = np.where(far, FAR * base, h / np.where(far, 1.0, sw))
        self.num_at_infinity = int(far.sum())
        return Cm + dist[:, None] * d

    def store(self, R, C, pts) -> None:
        self.p.X = self.to_xyz(R, C, pts)
        self.p.exclusions["points_at_infinity_written_far"] = self.num_at_infinity
