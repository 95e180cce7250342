"""Radial maps of the supported camera models (normalized to unit focal length).

Every model here is radially symmetric in normalized image coordinates
``(x, y) = ((u - cx) / fx, (v - cy) / fy)``: a ray at angle ``theta`` from the principal axis
lands at normalized radius ``rd = R(theta)``. Two kinds are distinguished because COLMAP defines
them differently and because the perspective kind has a cheaper, more accurate direct path:

* ``perspective``: ``rd = D(ru)`` with ``ru = tan(theta)`` and ``D(ru) = ru (1 + k1 ru^2 + k2 ru^4)``
  (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, PERSPECTIVE).
* ``angle``: ``rd = R(theta)`` directly (OPENCV_FISHEYE's Kannala-Brandt polynomial and the
  classical fisheye projections).

``theta_max`` is the exclusive upper end of the valid field of view: the smallest of the model's
own limit and the first angle where the radial map stops increasing (beyond it the model is not
invertible, so polarref masks those rays with NaN instead of returning an ambiguous pixel).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

Array = np.ndarray


def odd_poly(x: Array, coeffs: tuple[float, ...]) -> tuple[Array, Array]:
    """``p(x) = x (1 + c1 x^2 + c2 x^4 + ...)`` and ``p'(x)``, vectorized."""
    x2 = x * x
    val = np.ones_like(x)
    der = np.ones_like(x)
    power = np.ones_like(x)
    for i, c in enumerate(coeffs, start=1):
        power = power * x2
        val = val + c * power
        der = der + (2 * i + 1) * c * power
    return x * val, der


def odd_poly_limit(coeffs: tuple[float, ...], upper: float = float("inf")) -> float:
    """Smallest x in (0, upper) where ``p'(x)`` turns negative (end of the increasing branch),
    or inf when p increases on the whole range.

    A sign scan on a fine grid followed by bisection: polynomial root finders lose real roots
    when the coefficients span many orders of magnitude (e.g. k4 ~ 1e-38 beside k1 ~ 0.06).
    ``upper = inf`` scans x = tan(t) for t in [0, pi/2).
    """
    if not any(coeffs):
        return float("inf")
    n = 8192
    if np.isfinite(upper):
        grid = np.linspace(0.0, upper, n + 1)
        to_x = lambda g: g  # noqa: E731
    else:
        grid = np.linspace(0.0, np.pi / 2, n + 1)[:-1]
        to_x = np.tan
    with np.errstate(over="ignore", invalid="ignore"):
        der = odd_poly(to_x(grid), coeffs)[1]
    neg = np.flatnonzero(~(der > 0))
    if neg.size == 0:
        return float("inf")
    lo, hi = grid[neg[0] - 1], grid[neg[0]]
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if odd_poly(to_x(np.array(mid)), coeffs)[1] > 0:
            lo = mid
        else:
            hi = mid
    return float(to_x(np.array(lo)))


def odd_poly_inverse(y: Array, coeffs: tuple[float, ...], x_lim: float) -> Array:
    """Solve ``p(x) = y`` for x in ``[0, x_lim)`` by bracketed Newton; NaN where no solution.

    ``y`` must be >= 0. Outside the reachable range ``[0, p(x_lim))`` the result is NaN.
    """
    y = np.asarray(y, dtype=np.float64)
    if not any(coeffs):
        return np.where(y < x_lim, y, np.nan)
    with np.errstate(invalid="ignore", over="ignore"):
        y_lim = odd_poly(np.array(x_lim), coeffs)[0] if np.isfinite(x_lim) else np.inf
        ok = np.isfinite(y) & (y >= 0) & (y < y_lim)
        yy = np.where(ok, y, 0.0)
        lo = np.zeros_like(yy)
        if np.isfinite(x_lim):
            hi = np.full_like(yy, x_lim)
        else:  # p increases without bound: grow the bracket until it holds the target
            hi = np.maximum(yy, 1.0)
            for _ in range(200):
                short = odd_poly(hi, coeffs)[0] < yy
                if not short.any():
                    break
                hi = np.where(short, 2.0 * hi, hi)
        x = np.clip(yy, lo, hi)
        x = np.where(x >= hi, 0.5 * (lo + hi), x)
        # rtsafe's guard: a Newton step longer than half the one before it bisects instead;
        # without it, near an inflection Newton ping-pongs between the bracket's ends forever
        dx_old = hi - lo
        for _ in range(100):
            val, der = odd_poly(x, coeffs)
            f = val - yy
            hi = np.where(f > 0, x, hi)
            lo = np.where(f <= 0, x, lo)
            step = f / np.where(der > 0, der, np.inf)
            x_new = x - step
            bad = ~((x_new >= lo) & (x_new <= hi)) | (der <= 0) | (np.abs(step) > 0.5 * dx_old)
            x_new = np.where(bad, 0.5 * (lo + hi), x_new)
            dx_old = np.abs(x_new - x)
            done = np.abs(x_new - x) <= 4e-16 * np.maximum(np.abs(x), 1e-300)
            x = x_new
            if done.all():
                break
    return np.where(ok, x, np.nan)


@dataclass(frozen=True)
class RadialMap:
    """The radial part of a camera model, unit focal length.

    Attributes:
        kind: ``"perspective"`` (``rd = D(tan theta)``) or ``"angle"`` (``rd = R(theta)``).
        family: for the angle kind, the closed form: ``"poly"`` (Kannala-Brandt, incl.
            equidistant with no coefficients), ``"stereographic"``, ``"equisolid"``,
            ``"orthographic"``. Unused for the perspective kind.
        coeffs: odd-polynomial coefficients (k1, k2, ...) of D (perspective) or of the
            Kannala-Brandt polynomial (angle/poly).
    """

    kind: str
    family: str
    coeffs: tuple[float, ...]
    limit: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # end of the increasing branch of the polynomial (ru for perspective, theta for poly)
        upper = np.inf if self.kind == "perspective" else np.pi
        lim = odd_poly_limit(self.coeffs, upper) if self.kind == "perspective" or \
            self.family == "poly" else np.inf
        object.__setattr__(self, "limit", lim)

    # ---- field of view -----------------------------------------------------------------
    @property
    def theta_max(self) -> float:
        """Exclusive upper bound of the valid theta [rad]."""
        if self.kind == "perspective":
            return float(np.arctan(self.limit))
        if self.family == "orthographic":
            return float(np.pi / 2)
        if self.family == "poly":
            return float(min(np.pi, self.limit))
        return float(np.pi)

    @property
    def rd_max(self) -> float:
        """Exclusive upper bound of the normalized image radius (``R(theta_max)``, maybe inf)."""
        if self.kind == "perspective":
            ru_lim = self.limit
            if not np.isfinite(ru_lim):
                return float("inf")
            return float(odd_poly(np.array(ru_lim), self.coeffs)[0])
        if self.family == "stereographic":
            return float("inf")
        return float(self.radius(np.array(self.theta_max))[0])

    # ---- theta -> rd -----------------------------------------------------------------
    def radius(self, theta: Array) -> tuple[Array, Array]:
        """``(rd, drd/dtheta)`` for theta (...) in radians; no range check."""
        theta = np.asarray(theta, dtype=np.float64)
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            if self.kind == "perspective":
                ru = np.tan(theta)
                d, dd = odd_poly(ru, self.coeffs)
                return d, dd * (1.0 + ru * ru)
            if self.family == "poly":
                return odd_poly(theta, self.coeffs)
            if self.family == "stereographic":
                return 2.0 * np.tan(theta / 2), 1.0 / np.cos(theta / 2) ** 2
            if self.family == "equisolid":
                return 2.0 * np.sin(theta / 2), np.cos(theta / 2)
            if self.family == "orthographic":
                return np.sin(theta), np.cos(theta)
        raise AssertionError(self.family)

    # ---- rd -> theta -----------------------------------------------------------------
    def theta(self, rd: Array) -> tuple[Array, Array]:
        """``(theta, dtheta/drd)`` for rd (...) >= 0; NaN outside ``[0, rd_max)``."""
        rd = np.asarray(rd, dtype=np.float64)
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            if self.kind == "perspective":
                ru = odd_poly_inverse(rd, self.coeffs, self.limit)
                dd = odd_poly(ru, self.coeffs)[1]
                return np.arctan(ru), 1.0 / ((1.0 + ru * ru) * dd)
            if self.family == "poly":
                th = odd_poly_inverse(rd, self.coeffs, self.theta_max)
            elif self.family == "stereographic":
                th = np.where(rd >= 0, 2.0 * np.arctan(rd / 2), np.nan)
            elif self.family == "equisolid":
                th = np.where((rd >= 0) & (rd < 2.0), 2.0 * np.arcsin(np.clip(rd / 2, 0, 1)), np.nan)
            elif self.family == "orthographic":
                th = np.where((rd >= 0) & (rd < 1.0), np.arcsin(np.clip(rd, 0, 1)), np.nan)
            else:
                raise AssertionError(self.family)
            th = np.where(th < self.theta_max, th, np.nan)
            return th, 1.0 / self.radius(th)[1]
