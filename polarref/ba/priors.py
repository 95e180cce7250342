"""Pose priors and ground control points as residual blocks of the bundle adjustment.

Every form (euclidean, parallax, polar, angular) gets the same extra blocks, because they touch
only the camera blocks ``(dtheta, dC)`` and the control points' own XYZ, never a form's landmark
parameters:

* **centre prior** of camera i: ``r = s W_i (C_i - c_i)`` (3,), ``W_i`` the whitening of the
  prior covariance (``W^T W = Sigma^-1``); ``r_D_dC = s W_i``;
* **attitude prior**: ``r = (s / sigma_i) log(R_i R0_i^T)`` (3,) with ``R`` cam_from_world; for
  ``R <- exp(dtheta) R``, ``r_D_dtheta = (s / sigma_i) J_l^-1(phi)``, ``phi = log(R R0^T)``;
* **control point** g (XYZ ``X_g``, a parameter block of its own): its 3D prior
  ``r = s W_g (X_g - x_g)`` and its pixel observations ``r = (s / sigma_mark) (uv(R_i (X_g -
  C_i)) - uv_obs)``, the Euclidean residual (a control point is a marked target, its position
  is what the prior constrains).

``s`` is the forms' pixel sigma (``BAPriors.image_sigma_px``): every form's residuals are in
px-equivalent units with unit weight, i.e. whitened by ``sigma_px``, so the blocks above are
whitened residuals times ``sigma_px``: the objective is a consistent weighted least squares.
No robust loss acts on them (priors and marked targets carry no outliers).

The solver (solver.py) adds the camera parts to the diagonal camera blocks and the gradient
(:meth:`PriorTerms.camera_terms`), and eliminates the control points into the reduced camera
system by their own Schur complement (:meth:`PriorTerms.schur_into`, :meth:`PriorTerms.step`):
the extra blocks enter at one place, beside the forms' point elimination.

Datum: with >= 3 non-collinear anchors (prior centres of cameras plus control points) the
priors fix all 7 similarity DoF and ``prepare`` fixes no gauge (:func:`fixes_datum`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse

from polarref.ba.projection import Projector
from polarref.core.geometry import skew, so3_log

MIN_DATUM_ANCHORS = 3  # a similarity is fixed by 3 non-collinear points


@dataclass(frozen=True)
class CentrePriors:
    """Centre priors: ``cam`` (K,) problem camera index, ``centre`` (K, 3) world metres,
    ``sqrt_info`` (K, 3, 3) whitening ``W`` with ``W^T W`` the inverse prior covariance."""

    cam: np.ndarray
    centre: np.ndarray
    sqrt_info: np.ndarray


@dataclass(frozen=True)
class AttitudePriors:
    """Attitude priors: ``cam`` (A,), ``R`` (A, 3, 3) prior cam_from_world, ``sigma_rad`` (A,)."""

    cam: np.ndarray
    R: np.ndarray
    sigma_rad: np.ndarray


@dataclass(frozen=True)
class ControlPoints:
    """Control points: ``X0`` (G, 3) prior XYZ, ``sqrt_info`` (G, 3, 3) their whitening,
    observations ``obs_gcp`` (Mg,) control index, ``obs_cam`` (Mg,) problem camera index,
    ``uv`` (Mg, 2) pixels (COLMAP convention), ``mark_sigma_px`` marking noise, ``ids`` (G,)."""

    X0: np.ndarray
    sqrt_info: np.ndarray
    obs_gcp: np.ndarray
    obs_cam: np.ndarray
    uv: np.ndarray
    mark_sigma_px: float = 1.0
    ids: tuple = ()


@dataclass(frozen=True)
class BAPriors:
    """The extra observations of one BA problem (each part optional)."""

    centres: CentrePriors | None = None
    attitudes: AttitudePriors | None = None
    control: ControlPoints | None = None
    image_sigma_px: float = 1.0  # the forms' pixel residuals' sigma: the weight scale ``s``

    def anchors(self) -> np.ndarray:
        """(K + G, 3) prior centres and control points: what can fix the datum."""
        parts = [np.zeros((0, 3))]
        if self.centres is not None:
            parts.append(self.centres.centre)
        if self.control is not None:
            parts.append(self.control.X0)
        return np.concatenate(parts)


def fixes_datum(priors: BAPriors | None) -> bool:
    """True when the priors fix translation, rotation and scale: >= 3 anchors, not collinear."""
    if priors is None:
        return False
    A = priors.anchors()
    if len(A) < MIN_DATUM_ANCHORS:
        return False
    sv = np.linalg.svd(A - A.mean(0), compute_uv=False)
    return bool(sv[1] > 1e-9 * max(sv[0], 1e-300))


def so3_left_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """``J_l^-1(phi)`` (..., 3, 3): ``log(exp(d) exp(phi)) = phi + J_l^-1(phi) d + O(d^2)``."""
    phi = np.asarray(phi, np.float64)
    t = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = skew(phi)
    small = t < 1e-5
    ts = np.where(small, 1.0, t)
    # 1/t^2 - (1 + cos t) / (2 t sin t), its series 1/12 + t^2/720 near 0
    c = np.where(small, 1.0 / 12.0 + t**2 / 720.0,
                 1.0 / ts**2 - (1.0 + np.cos(ts)) / (2.0 * ts * np.sin(ts)))
    return np.eye(3) - 0.5 * K + c * (K @ K)


def restrict(priors: BAPriors, image_index: np.ndarray) -> BAPriors:
    """Priors re-indexed to a subset of cameras: ``image_index`` (N,) maps problem camera ->
    the priors' camera numbering; priors and observations of cameras not in it are dropped."""
    lut = {int(c): k for k, c in enumerate(image_index)}

    def keep(cams):
        sel = np.array([int(c) in lut for c in cams], bool)
        return sel, np.array([lut[int(c)] for c in cams[sel]], np.int64)

    out = BAPriors(image_sigma_px=priors.image_sigma_px)
    if priors.centres is not None:
        s, cam = keep(priors.centres.cam)
        if s.any():
            c = priors.centres
            out = replace(out, centres=CentrePriors(cam, c.centre[s], c.sqrt_info[s]))
    if priors.attitudes is not None:
        s, cam = keep(priors.attitudes.cam)
        if s.any():
            a = priors.attitudes
            out = replace(out, attitudes=AttitudePriors(cam, a.R[s], a.sigma_rad[s]))
    if priors.control is not None:
        s, cam = keep(priors.control.obs_cam)
        g = priors.control
        out = replace(out, control=replace(g, obs_gcp=g.obs_gcp[s], obs_cam=cam, uv=g.uv[s]))
    return out


@dataclass(frozen=True)
class Residuals:
    """Whitened residuals (times sigma_px) of every block kind, for costs and reports."""

    centre: np.ndarray     # (K, 3)
    attitude: np.ndarray   # (A, 3)
    gcp_prior: np.ndarray  # (G, 3)
    gcp_pixel: np.ndarray  # (Mg, 2)

    def cost(self) -> float:
        return 0.5 * float(sum((r**2).sum() for r in
                               (self.centre, self.attitude, self.gcp_prior, self.gcp_pixel)))


@dataclass(frozen=True)
class Jacobians:
    """Analytic Jacobians: ``centre_D_dC`` (K, 3, 3), ``attitude_D_dtheta`` (A, 3, 3),
    ``gcp_prior_D_X`` (G, 3, 3), ``pixel_D_cam`` (Mg, 2, 6) in (dtheta, dC), ``pixel_D_X``
    (Mg, 2, 3)."""

    centre_D_dC: np.ndarray
    attitude_D_dtheta: np.ndarray
    gcp_prior_D_X: np.ndarray
    pixel_D_cam: np.ndarray
    pixel_D_X: np.ndarray


class PriorTerms:
    """The priors' residual blocks on one prepared problem (cameras indexed as the problem's)."""

    def __init__(self, priors: BAPriors, cameras: list, sigma_px: float):
        self.pr = priors
        self.s = float(sigma_px)
        g = priors.control
        self.G = 0 if g is None else len(g.X0)
        self.proj = None
        if g is not None and len(g.obs_cam):
            self.proj = Projector(cameras, g.obs_cam)
        self.gcp_w = 0.0 if g is None else self.s / g.mark_sigma_px

    # -- residuals and Jacobians ------------------------------------------------------------
    def _centre(self, C):
        c = self.pr.centres
        if c is None:
            return np.zeros((0, 3)), np.zeros((0, 3, 3))
        J = self.s * c.sqrt_info
        return np.einsum("kij,kj->ki", J, C[c.cam] - c.centre), J

    def _attitude(self, R, jac):
        a = self.pr.attitudes
        if a is None:
            return np.zeros((0, 3)), np.zeros((0, 3, 3))
        phi = so3_log(R[a.cam] @ a.R.transpose(0, 2, 1))
        w = (self.s / a.sigma_rad)[:, None]
        J = w[:, :, None] * so3_left_jacobian_inv(phi) if jac else None
        return w * phi, J

    def _gcp(self, R, C, Xg, jac):
        g = self.pr.control
        if g is None:
            z = np.zeros((0, 3))
            return z, np.zeros((0, 3, 3)), np.zeros((0, 2)), np.zeros((0, 2, 6)), np.zeros((0, 2, 3))
        Jpr = self.s * g.sqrt_info
        r_pr = np.einsum("gij,gj->gi", Jpr, Xg - g.X0)
        if self.proj is None:
            return r_pr, Jpr, np.zeros((0, 2)), np.zeros((0, 2, 6)), np.zeros((0, 2, 3))
        Ri = R[g.obs_cam]
        Xc = np.einsum("mij,mj->mi", Ri, Xg[g.obs_gcp] - C[g.obs_cam])
        if not jac:
            uv = self.proj(Xc, jac=False)
            return r_pr, Jpr, self.gcp_w * (uv - g.uv), None, None
        uv, Juv = self.proj(Xc)
        Juv = self.gcp_w * Juv
        Jx = Juv @ Ri
        Jc = np.empty((len(Xc), 2, 6))
        # dXc = dtheta x Xc - R dC: rows a^T (-[Xc]x) = (Xc x a)^T, and -a^T R
        Jc[:, :, :3] = np.cross(Xc[:, None, :], Juv)
        Jc[:, :, 3:] = -Jx
        return r_pr, Jpr, self.gcp_w * (uv - g.uv), Jc, Jx

    def residuals(self, R, C, Xg) -> Residuals:
        """Residuals at cameras R (N, 3, 3), C (N, 3) and control points Xg (G, 3)."""
        rc, _ = self._centre(C)
        ra, _ = self._attitude(R, False)
        rg, _, rp, _, _ = self._gcp(R, C, Xg, False)
        return Residuals(rc, ra, rg, rp)

    def jacobians(self, R, C, Xg) -> Jacobians:
        _, Jc = self._centre(C)
        _, Ja = self._attitude(R, True)
        _, Jg, _, Jpc, Jpx = self._gcp(R, C, Xg, True)
        return Jacobians(Jc, Ja, Jg, Jpc, Jpx)

    def cost(self, R, C, Xg) -> float:
        return self.residuals(R, C, Xg).cost()

    # -- normal equations ---------------------------------------------------------------------
    def build(self, R, C, Xg, N: int) -> "PriorSystem":
        """Gradient and Gauss-Newton blocks of every prior block at the current estimate."""
        g_cam = np.zeros((N, 6))
        H_cam = np.zeros((N, 6, 6))
        rc, Jc = self._centre(C)
        if len(rc):
            np.add.at(g_cam[:, 3:], self.pr.centres.cam, np.einsum("kji,kj->ki", Jc, rc))
            np.add.at(H_cam[:, 3:, 3:], self.pr.centres.cam, np.einsum("kji,kjl->kil", Jc, Jc))
        ra, Ja = self._attitude(R, True)
        if len(ra):
            np.add.at(g_cam[:, :3], self.pr.attitudes.cam, np.einsum("kji,kj->ki", Ja, ra))
            np.add.at(H_cam[:, :3, :3], self.pr.attitudes.cam, np.einsum("kji,kjl->kil", Ja, Ja))
        G = self.G
        V = np.zeros((G, 3, 3))
        g_x = np.zeros((G, 3))
        W = np.zeros((0, 6, 3))
        e_cam = e_gcp = np.zeros(0, np.int64)
        if G:
            rg, Jg, rp, Jpc, Jpx = self._gcp(R, C, Xg, True)
            V += np.einsum("gji,gjl->gil", Jg, Jg)
            g_x += np.einsum("gji,gj->gi", Jg, rg)
            if len(rp):
                ctl = self.pr.control
                np.add.at(g_cam, ctl.obs_cam, np.einsum("mji,mj->mi", Jpc, rp))
                np.add.at(H_cam, ctl.obs_cam, np.einsum("mji,mjl->mil", Jpc, Jpc))
                np.add.at(V, ctl.obs_gcp, np.einsum("mji,mjl->mil", Jpx, Jpx))
                np.add.at(g_x, ctl.obs_gcp, np.einsum("mji,mj->mi", Jpx, rp))
                # one W block per distinct (camera, control point)
                key = ctl.obs_cam * G + ctl.obs_gcp
                uk, inv = np.unique(key, return_inverse=True)
                W = np.zeros((len(uk), 6, 3))
                np.add.at(W, inv, np.einsum("mji,mjl->mil", Jpc, Jpx))
                e_cam, e_gcp = uk // G, uk % G
        return PriorSystem(g_cam, H_cam, V, g_x, W, e_cam, e_gcp)


@dataclass
class PriorSystem:
    """One build of the priors' normal equations (problem camera indexing).

    g_cam (N, 6), H_cam (N, 6, 6): camera gradient and diagonal camera blocks; V (G, 3, 3),
    g_x (G, 3): control point blocks; W (E, 6, 3) camera-control cross blocks of entries
    (e_cam (E,), e_gcp (E,)). After :meth:`schur_into`: ``Vinv`` (G, 3, 3) of the damped V."""

    g_cam: np.ndarray
    H_cam: np.ndarray
    V: np.ndarray
    g_x: np.ndarray
    W: np.ndarray
    e_cam: np.ndarray
    e_gcp: np.ndarray
    Vinv: np.ndarray | None = None
    D_x: np.ndarray | None = None

    def add_to_cameras(self, st, var_cams: np.ndarray, g_c: np.ndarray, U: np.ndarray) -> None:
        """Add the camera gradient and diagonal blocks into the forms' g_c (Nv, 6) and U blocks
        (in place; before the gauge mask, which then masks them too)."""
        diag = np.flatnonzero(st.u_ca == st.u_cb)
        if len(diag) != len(var_cams):
            raise AssertionError("priors: a variable camera without its diagonal U block")
        g_c += self.g_cam[var_cams]
        U[diag[np.argsort(st.u_ca[diag])]] += self.H_cam[var_cams]

    def damping_diag(self, lo: float, hi: float, identity: bool) -> np.ndarray:
        """(G, 3) damping diagonal of the control points (Jacobi, clipped as the forms')."""
        self.D_x = (np.ones((len(self.V), 3)) if identity
                    else np.clip(np.diagonal(self.V, axis1=1, axis2=2), lo, hi))
        return self.D_x

    def schur_into(self, S, b: np.ndarray, mu: float, var_index: np.ndarray, mask_v: np.ndarray):
        """Eliminate the control points: ``S -= W V^-1 W^T``, ``b += W V^-1 g_x`` (damped V).

        S: dense (6Nv, 6Nv) ndarray (updated in place) or scipy sparse; b (6Nv,) in place.
        Returns S, or None when a damped control block is singular."""
        Vd = self.V + mu * self.D_x[:, :, None] * np.eye(3)
        if len(Vd) and np.linalg.cond(Vd).max() > 1e14:
            return None
        self.Vinv = np.linalg.inv(Vd) if len(Vd) else np.zeros((0, 3, 3))
        self.vc = var_index[self.e_cam]
        ok = self.vc >= 0
        self.Wm = self.W * mask_v[np.maximum(self.vc, 0)][:, :, None] * ok[:, None, None]
        if not ok.any():
            return S
        Z = self.Wm @ self.Vinv[self.e_gcp]  # (E, 6, 3)
        np.add.at(b.reshape(-1, 6), self.vc[ok],
                  np.einsum("eij,ej->ei", Z, self.g_x[self.e_gcp])[ok])
        ea, eb = np.nonzero((self.e_gcp[:, None] == self.e_gcp[None, :]) & ok[:, None] & ok[None, :])
        blocks = -Z[ea] @ self.Wm[eb].transpose(0, 2, 1)  # (pairs, 6, 6)
        ii = (6 * self.vc[ea][:, None, None] + np.arange(6)[None, :, None]).repeat(6, 2)
        jj = (6 * self.vc[eb][:, None, None] + np.arange(6)[None, None, :]).repeat(6, 1)
        if isinstance(S, np.ndarray):
            np.add.at(S, (ii.ravel(), jj.ravel()), blocks.ravel())
            return S
        return S + scipy.sparse.coo_matrix((blocks.ravel(), (ii.ravel(), jj.ravel())),
                                           shape=S.shape).tocsc()

    def step(self, dc: np.ndarray) -> np.ndarray:
        """Control point steps ``dX = -V^-1 (g_x + W^T dc)`` (G, 3) from the camera step dc (Nv, 6)."""
        rhs = -self.g_x.copy()
        ok = self.vc >= 0
        if ok.any():
            np.add.at(rhs, self.e_gcp[ok],
                      -np.einsum("eji,ej->ei", self.Wm[ok], dc[self.vc[ok]]))
        return np.einsum("gij,gj->gi", self.Vinv, rhs)
