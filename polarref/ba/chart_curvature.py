"""Second derivatives of a camera's projection in the azimuthal-equidistant chart (issue 32).

The angular form whitens its residuals with ``W = d uv / d chart`` at the observed pixel
(intrinsics.py). When the intrinsics ``k`` are refined, ``W`` moves with ``k``, and the Jacobian
of ``W (c_pred - c_obs)`` needs ``dW/dk``: the projection's second derivatives. Here they are
written once, for every camera model, in the chart ``e = theta (cos phi, sin phi)``:

    uv(e) = c + f o D(rho(u) e),    u = |e|^2

with ``f o`` the per-axis focal product, ``rho(u) = R(theta) / theta`` the model's radial map
divided by the angle, and ``D`` OPENCV's distortion of the undistorted normalized point
(``x L(|x|^2) + t(x)``, with ``L = 1 + k1 s + k2 s^2`` and ``t`` the quadratic tangential term;
identity for the angle-kind models). Both ``rho(u) e`` and ``x L(|x|^2)`` are ``y = g(|x|^2) x``
maps, whose derivatives are ``y_x a = g a + 2 g' (x.a) x`` and ``y_xx[a, b] = 2 g' ((x.b) a +
(a.b) x + (x.a) b) + 4 g'' (x.a)(x.b) x``: smooth through the axis (u = 0), where the (theta,
phi) angles are not. ``rho`` is an even analytic function of theta, hence of u: tan(t)/t and
sin(t)/t with closed forms away from the axis and Taylor series near it.

Parameters are reported in the model's order (one-focal models sum the fx and fy columns).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import factorial

import numpy as np

from polarref.camera import Camera
from polarref.camera.models import MODELS

Array = np.ndarray

# Taylor coefficients in u = t^2 of tan(t)/t and sin(t)/t; below SERIES_U the closed forms'
# derivatives cancel (their numerators are O(t^5) sums of O(t) terms). With eight terms the
# truncation of the second derivative is below 1e-13 there.
_TAN = (1.0, 1 / 3, 2 / 15, 17 / 315, 62 / 2835, 1382 / 155925, 21844 / 6081075,
        929569 / 638512875)
_SIN = tuple((-1) ** n / factorial(2 * n + 1) for n in range(8))
SERIES_U = 1e-2


def _series(coeffs, u: Array) -> tuple[Array, Array, Array]:
    """A power series in u and its first two derivatives."""
    val, d1, d2 = np.zeros_like(u), np.zeros_like(u), np.zeros_like(u)
    for n in range(len(coeffs) - 1, -1, -1):  # Horner, three at once
        d2 = d2 * u + 2.0 * d1
        d1 = d1 * u + val
        val = val * u + coeffs[n]
    return val, d1, d2


def _tan_over(u: Array) -> tuple[Array, Array, Array]:
    """``tan(t)/t`` as a function of ``u = t^2``, with d/du and d2/du2."""
    t = np.sqrt(np.where(u >= SERIES_U, u, 1.0))
    tn, s2 = np.tan(t), 1.0 / np.cos(t) ** 2
    closed = (tn / t, (t * s2 - tn) / (2 * t ** 3),
              (2 * t * t * s2 * tn - 3 * t * s2 + 3 * tn) / (4 * t ** 5))
    series = _series(_TAN, np.where(u < SERIES_U, u, 0.0))
    return tuple(np.where(u >= SERIES_U, c, s) for c, s in zip(closed, series))


def _sin_over(u: Array) -> tuple[Array, Array, Array]:
    """``sin(t)/t`` as a function of ``u = t^2``, with d/du and d2/du2."""
    t = np.sqrt(np.where(u >= SERIES_U, u, 1.0))
    sn, cs = np.sin(t), np.cos(t)
    closed = (sn / t, (t * cs - sn) / (2 * t ** 3), ((3 - t * t) * sn - 3 * t * cs) / (4 * t ** 5))
    series = _series(_SIN, np.where(u < SERIES_U, u, 0.0))
    return tuple(np.where(u >= SERIES_U, c, s) for c, s in zip(closed, series))


def _dot(a: Array, b: Array) -> Array:
    return (a * b).sum(-1, keepdims=True)


def _scaled_first(g, g1, x, a):
    """``y_x a`` of ``y = g(|x|^2) x`` (g, g1 with a trailing axis of 1)."""
    return g * a + 2.0 * g1 * _dot(x, a) * x


def _scaled_second(g1, g2, x, a, b):
    """``y_xx[a, b]`` of ``y = g(|x|^2) x``."""
    xa, xb = _dot(x, a), _dot(x, b)
    return 2.0 * g1 * (xb * a + _dot(a, b) * x + xa * b) + 4.0 * g2 * xa * xb * x


def _tangential(p1, p2, a, b):
    """The symmetric bilinear form Q with OPENCV's tangential term ``t(x) = Q(x, x)``."""
    cross = a[..., :1] * b[..., 1:] + a[..., 1:] * b[..., :1]
    ab = _dot(a, b)
    xx, yy = a[..., :1] * b[..., :1], a[..., 1:] * b[..., 1:]
    return np.concatenate([p1 * cross + p2 * (ab + 2 * xx), p1 * (ab + 2 * yy) + p2 * cross], -1)


@dataclass(frozen=True)
class ChartLens:
    """One camera's chart map ``uv(e)`` at chart points ``e`` (..., 2), ready to differentiate.

    Attributes:
        cam: the camera.
        e: the chart points (..., 2).
        rho: (rho, rho', rho'') of u = |e|^2, each (..., 1).
        x: ``rho e`` (..., 2): the undistorted normalized point (tan kinds), or the distorted
            one (angle kinds, where D is the identity).
        lens: (L, L', L'') of s = |x|^2, each (..., 1); (1, 0, 0) for the angle kinds.
        tangential: (p1, p2); zero but for OPENCV.
        focal: (fx, fy) (2,).
        poly: Kannala-Brandt coefficients that multiply u, u^2, ... in rho (angle/poly kind), else ().
    """

    cam: Camera
    e: Array
    rho: tuple[Array, Array, Array]
    x: Array
    lens: tuple[Array, Array, Array]
    tangential: tuple[float, float]
    focal: Array
    poly: tuple[float, ...]

    @staticmethod
    def at(cam: Camera, e: Array) -> "ChartLens":
        spec = MODELS[cam.model]
        e = np.asarray(e, np.float64)
        u = (e * e).sum(-1, keepdims=True)
        coeffs = tuple(float(cam.params[i]) for i in spec.extra)
        poly: tuple[float, ...] = ()
        k1 = k2 = p1 = p2 = 0.0
        if spec.kind in ("perspective", "opencv"):
            rho = _tan_over(u)
            k1, k2, p1, p2 = (coeffs + (0.0,) * 4)[:4]
        elif spec.family == "poly":
            poly = coeffs
            rho = _series((1.0,) + coeffs, u)
        elif spec.family == "stereographic":  # 2 tan(t/2) / t
            rho = tuple(v / 4 ** n for n, v in enumerate(_tan_over(u / 4)))
        elif spec.family == "equisolid":  # 2 sin(t/2) / t
            rho = tuple(v / 4 ** n for n, v in enumerate(_sin_over(u / 4)))
        elif spec.family == "orthographic":
            rho = _sin_over(u)
        else:
            raise AssertionError(spec.family)
        x = rho[0] * e
        s = (x * x).sum(-1, keepdims=True)
        lens = (1.0 + s * (k1 + k2 * s), k1 + 2.0 * k2 * s, np.full_like(s, 2.0 * k2))
        return ChartLens(cam, e, rho, x, lens, (p1, p2), np.array([cam.fx, cam.fy]), poly)

    # -- the map and its derivatives ----------------------------------------------------------
    def _undistorted_first(self, a: Array) -> Array:
        return _scaled_first(self.rho[0], self.rho[1], self.e, a)

    def _distort_first(self, y: Array) -> Array:
        L, L1, _ = self.lens
        return _scaled_first(L, L1, self.x, y) + 2.0 * _tangential(*self.tangential, self.x, y)

    def pixel(self) -> Array:
        """``uv(e)`` (..., 2)."""
        L = self.lens[0]
        D = self.x * L + _tangential(*self.tangential, self.x, self.x)
        return self.focal * D + self.cam.principal_point

    def first(self, a: Array) -> Array:
        """``uv_e a`` (..., 2) for directions ``a`` (..., 2)."""
        return self.focal * self._distort_first(self._undistorted_first(a))

    def jacobian(self) -> Array:
        """``uv_D_e`` (..., 2, 2)."""
        eye = np.eye(2)
        return np.stack([self.first(np.broadcast_to(eye[j], self.e.shape)) for j in range(2)], -1)

    def second(self, a: Array, b: Array) -> Array:
        """``uv_ee[a, b]`` (..., 2); a, b (..., 2) broadcast against ``e``."""
        _, L1, L2 = self.lens
        ya, yb = self._undistorted_first(a), self._undistorted_first(b)
        yab = _scaled_second(self.rho[1], self.rho[2], self.e, a, b)
        Dxx = _scaled_second(L1, L2, self.x, ya, yb) + 2.0 * _tangential(*self.tangential, ya, yb)
        return self.focal * (Dxx + self._distort_first(yab))

    def first_D_params(self, a: Array) -> Array:
        """``d(uv_e a) / d params`` (..., 2, P), model parameters in the model's order."""
        y = self._undistorted_first(a)
        Dy = self._distort_first(y)
        zero = np.zeros_like(Dy)
        cols = [np.concatenate([Dy[..., :1], zero[..., 1:]], -1),  # fx
                np.concatenate([zero[..., :1], Dy[..., 1:]], -1),  # fy
                zero, zero]  # cx, cy
        spec = MODELS[self.cam.model]
        if spec.kind in ("perspective", "opencv"):  # L = 1 + k1 s + k2 s^2, then p1, p2
            x, s = self.x, (self.x * self.x).sum(-1, keepdims=True)
            xy = _dot(x, y)
            dist = [s * y + 2.0 * xy * x, s * s * y + 4.0 * s * xy * x,
                    2.0 * _tangential(1.0, 0.0, x, y), 2.0 * _tangential(0.0, 1.0, x, y)]
        else:  # rho = 1 + k1 u + k2 u^2 + ...
            u = (self.e * self.e).sum(-1, keepdims=True)
            ea = _dot(self.e, a)
            dist = [u ** i * a + 2.0 * i * u ** (i - 1) * ea * self.e
                    for i in range(1, len(self.poly) + 1)]
        G = np.stack(cols + [self.focal * d for d in dist], -1)
        return G @ params_fold(self.cam.model, G.shape[-1])


def params_fold(model: str, n_generic: int) -> Array:
    """(n_generic, P) 0/1 matrix from the generic columns (fx, fy, cx, cy, d1, d2, ...) onto
    the model's parameters; a one-focal model's f takes both focal columns."""
    spec = MODELS[model]
    S = np.zeros((n_generic, len(spec.names)))
    for g, i in enumerate((spec.fx, spec.fy, spec.cx, spec.cy) + tuple(spec.extra)):
        S[g, i] = 1.0
    return S


# -- the whitening's motion with the intrinsics (intrinsics.py) ---------------------------------
# The observed pixel is fixed; its chart point c_obs(k) moves with the intrinsics k by
# c_obs' = -(uv_D_c)^-1 uv_D_k (implicit function theorem), so W(k) = uv_D_c(c_obs(k), k) moves
# by W' = uv_cc[., c_obs'] + uv_ck. ``uv_D_k`` (n, 2, q) is the projection's Jacobian at the
# observed rays w.r.t. the free (scaled) intrinsics ``free`` (indices) times ``scale``.

def chart_whitening_D_k(cam: Camera, e: Array, B: Array, uv_D_k: Array, delta: Array,
                        free: Array, scale: Array) -> Array:
    """``d(W delta)/dk`` (n, 2, q) of the chart rows: W = uv_D_e = B^-1 at the observed chart
    points e (n, 2), delta (n, 2) held."""
    e_k = -B @ uv_D_k  # (n, 2, q)
    lens = ChartLens.at(cam, e[:, None, :])
    hess = lens.second(delta[:, None, :], e_k.transpose(0, 2, 1)).transpose(0, 2, 1)
    return hess + ChartLens.at(cam, e).first_D_params(delta)[:, :, free] * scale


def _angle_chart(ang: Array) -> tuple[Array, Array, Array, Array]:
    """Chart points e (n, 2), ``e_D_ang`` (n, 2, 2), and the radial / azimuthal unit vectors."""
    th, ph = ang[:, 0], ang[:, 1]
    radial = np.stack([np.cos(ph), np.sin(ph)], 1)
    perp = np.stack([-radial[:, 1], radial[:, 0]], 1)
    return th[:, None] * radial, np.stack([radial, th[:, None] * perp], 2), radial, perp


def angle_whitening_D_k(cam: Camera, ang: Array, A: Array, uv_D_k: Array, delta: Array,
                        free: Array, scale: Array) -> Array:
    """``d(W delta)/dk`` (n, 2, q) of the (theta, phi) rows: W = uv_D_ang = A^-1 at the observed
    angles ang (n, 2), delta (n, 2) held. Through the chart: ``uv(ang) = uv(e(ang))``, so
    ``W' delta = uv_ee[e_a delta, e_a a'] + uv_ek[e_a delta] + uv_e e_aa[delta, a']``."""
    e, e_a, radial, perp = _angle_chart(ang)
    a_k = -A @ uv_D_k  # (n, 2, q): the observed angles' motion
    de = (e_a @ delta[:, :, None])[:, :, 0]
    lens1 = ChartLens.at(cam, e[:, None, :])
    hess = lens1.second(de[:, None, :], (e_a @ a_k).transpose(0, 2, 1)).transpose(0, 2, 1)
    lens = ChartLens.at(cam, e)
    # e_aa[delta, g] = (dt g_phi + dphi g_t) perp - theta dphi g_phi radial
    dt, dp = delta[:, :1], delta[:, 1:]
    gt, gp = a_k[:, 0], a_k[:, 1]
    eaa = (dt * gp + dp * gt)[:, None, :] * perp[:, :, None] \
        - (ang[:, :1] * dp * gp)[:, None, :] * radial[:, :, None]
    return hess + lens.first_D_params(de)[:, :, free] * scale + lens.jacobian() @ eaa


def theta_weight_D_k(cam: Camera, ang: Array, A: Array, uv_D_k: Array, free: Array,
                     scale: Array) -> Array:
    """``d w / dk`` (n, q) of the theta weight ``w = 1 / |theta_D_uv|`` (row 0 of A = W^-1):
    ``dw = -w^3 A0 . dA0`` with ``dA = -A dW A``, i.e. ``w^3 A0 . W'(A A0)``."""
    A0 = A[:, 0, :]
    w = 1.0 / np.linalg.norm(A0, axis=1)
    Wz = angle_whitening_D_k(cam, ang, A, uv_D_k, (A @ A0[:, :, None])[:, :, 0], free, scale)
    return w[:, None] ** 3 * np.einsum("nj,njq->nq", A0, Wz)
