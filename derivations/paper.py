"""The paper's printed Eq. 3-10 and claim 7, checked against the Euclidean truth.

Symbolic checks use SymPy on :mod:`derivations.model`; numeric checks evaluate the printed
formulas in float64 exactly as printed (plus the stated corrections) on seeded random samples
and on the edge cases listed in issue 3, against the angle between the landmark direction and
the principal axis of :func:`polarref.core.angular.rotation_from_polar_angles` (float64 atan2 form,
itself certified against 50-digit mpmath on a subset).
"""

from __future__ import annotations

import dataclasses
import itertools
from typing import Callable

import mpmath
import numpy as np
import sympy as sp

from derivations import model as m
from polarref.core import angular
from polarref._generated.angles import view_angle_with_jacobian
from polarref.core.geometry import axis_rotation

N_SAMPLES = 100_000  # per case
N_MPMATH = 200  # per case, for certifying the float64 truth
NEAR_POLE = 1e-6  # samples with theta within this of 0 or pi are excluded from theta errors
SEED = 20240403


# --- printed formulas, evaluated literally ------------------------------------------------


def sigma2_eq7(e_y: np.ndarray, e_x: np.ndarray) -> np.ndarray:
    """Eq. 7: -e_y/|e_y| if e_x = 0, else -e_x/|e_x| (0/0 -> NaN at e_x = e_y = 0)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(e_x == 0.0, -e_y / np.abs(e_y), -e_x / np.abs(e_x))


def printed_e(e_y, e_x):
    """Eq. 4 as printed."""
    return np.arccos(np.cos(e_y) * np.cos(e_x))


def printed_v(e_y, e_x):
    """Eq. 5 as printed."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.arcsin(np.tan(e_y) / np.tan(printed_e(e_y, e_x)))


def printed_eq3_argument(alpha, beta, e_y, e_x, sigma1: Callable | None = None):
    """The bracket of Eq. 3 with e, v, sigma_2 as printed and sigma_1 = -sigma_2 (default)."""
    e, v = printed_e(e_y, e_x), printed_v(e_y, e_x)
    s2 = sigma2_eq7(e_y, e_x)
    s1 = -s2 if sigma1 is None else sigma1(e_y, e_x, s2)
    with np.errstate(invalid="ignore"):
        return np.cos(e) * np.sin(beta) + s2 * np.sin(e) * np.cos(beta) * np.cos(s1 * v + alpha)


def printed_eq3(alpha, beta, e_y, e_x):
    """Eq. 3 as printed: theta = asin[...]."""
    with np.errstate(invalid="ignore"):
        return np.arcsin(printed_eq3_argument(alpha, beta, e_y, e_x))


def corrected_eq3(alpha, beta, e_y, e_x, sigma1: Callable | None = None):
    """Eq. 3 with acos instead of asin (clipped so rounding just past +-1 is not NaN)."""
    arg = printed_eq3_argument(alpha, beta, e_y, e_x, sigma1)
    with np.errstate(invalid="ignore"):
        return np.arccos(np.clip(arg, -1.0, 1.0))


def truth_theta(alpha, beta, e_y, e_x, e_z):
    """Angle between d(alpha, beta) and the third column of rotation_from_polar_angles."""
    a = angular.rotation_from_polar_angles(e_y, e_x, e_z)[..., :, 2]
    d = angular.direction_from_azimuth_elevation(alpha, beta)
    return np.arctan2(np.linalg.norm(np.cross(a, d), axis=-1), np.sum(a * d, axis=-1))


def mpmath_theta(alpha: float, beta: float, e_y: float, e_x: float) -> float:
    """50-digit reference for the view angle (principal axis from the closed form)."""
    with mpmath.workdps(50):
        al, be, ey, ex = (mpmath.mpf(float(x)) for x in (alpha, beta, e_y, e_x))
        a = [-mpmath.sin(ex), mpmath.sin(ey) * mpmath.cos(ex), mpmath.cos(ey) * mpmath.cos(ex)]
        d = [mpmath.cos(be) * mpmath.cos(al), mpmath.cos(be) * mpmath.sin(al), mpmath.sin(be)]
        cross = [a[1] * d[2] - a[2] * d[1], a[2] * d[0] - a[0] * d[2], a[0] * d[1] - a[1] * d[0]]
        dot = sum(x * y for x, y in zip(a, d))
        return float(mpmath.atan2(mpmath.sqrt(sum(c * c for c in cross)), dot))


# --- cases --------------------------------------------------------------------------------


def _signed_log(rng, n, lo, hi):
    return rng.choice([-1.0, 1.0], n) * 10.0 ** rng.uniform(lo, hi, n)


def _near_half_pi(rng, n):
    return rng.choice([-1.0, 1.0], n) * (np.pi / 2 - 10.0 ** rng.uniform(-12, -2, n))


def _near_axis(rng, n):
    """Landmarks at view angle 10^-9..10^-3 (and 10% exactly on the axis) from random cameras."""
    e_y = rng.uniform(-np.pi, np.pi, n)
    e_x = rng.uniform(-np.pi, np.pi, n)
    a = angular.principal_axis(e_y, e_x)
    u = np.cross(a, rng.normal(size=(n, 3)))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    t = 10.0 ** rng.uniform(-9, -3, n)
    t[: n // 10] = 0.0
    alpha, beta = angular.azimuth_elevation_from_direction(np.cos(t)[:, None] * a + np.sin(t)[:, None] * u)
    return alpha, beta, e_y, e_x, rng.uniform(-np.pi, np.pi, n)


def _cases() -> dict[str, Callable[[np.random.Generator, int], tuple[np.ndarray, ...]]]:
    def angles(rng, n, e_y=None, e_x=None):
        alpha = rng.uniform(-np.pi, np.pi, n)
        beta = rng.uniform(-np.pi / 2, np.pi / 2, n)
        e_z = rng.uniform(-np.pi, np.pi, n)
        e_y = rng.uniform(-np.pi, np.pi, n) if e_y is None else e_y
        e_x = rng.uniform(-np.pi, np.pi, n) if e_x is None else e_x
        return alpha, beta, np.broadcast_to(e_y, (n,)).copy(), np.broadcast_to(e_x, (n,)).copy(), e_z

    return {
        "random": lambda r, n: angles(r, n),
        "random |e_y|,|e_x| < pi/2": lambda r, n: angles(r, n, r.uniform(-np.pi / 2, np.pi / 2, n),
                                                        r.uniform(-np.pi / 2, np.pi / 2, n)),
        "e_x = 0": lambda r, n: angles(r, n, e_x=0.0),
        "e_y = 0": lambda r, n: angles(r, n, e_y=0.0),
        "e_x = e_y = 0": lambda r, n: angles(r, n, 0.0, 0.0),
        "|e_y| -> pi/2 (pi/2 - |e_y| in 1e-12..1e-2)": lambda r, n: angles(r, n, e_y=_near_half_pi(r, n)),
        "|e_y| = pi/2 (nearest float)": lambda r, n: angles(r, n, e_y=r.choice([-1.0, 1.0], n) * np.pi / 2),
        "e -> 0 (|e_y|,|e_x| in 1e-12..1e-3)": lambda r, n: angles(r, n, _signed_log(r, n, -12, -3),
                                                                  _signed_log(r, n, -12, -3)),
        "negative e_y, e_x": lambda r, n: angles(r, n, r.uniform(-np.pi, 0, n), r.uniform(-np.pi, 0, n)),
        "theta -> 0 (1e-9..1e-3, 10% exactly 0)": _near_axis,
    }


@dataclasses.dataclass(frozen=True)
class CaseEvidence:
    """Max errors (rad) of each form of the view angle for one case."""

    case: str  # name of the sampled case
    samples: int  # samples drawn
    excluded_near_pole: int  # samples with theta within NEAR_POLE of 0 or pi (not in theta errors)
    printed_eq3_max_err: float  # asin form as printed, vs truth (finite results only)
    printed_eq3_nan: int  # samples where the printed form is NaN
    printed_is_complement_max_err: float  # max |asin form - (pi/2 - theta)|
    corrected_eq3_max_err: float  # acos form with sigma_1 = -sigma_2, vs truth
    corrected_eq3_nan: int  # samples where the corrected form is NaN
    corrected_eq3_max_err_all: float  # same, including the near-pole samples
    stable_max_err: float  # polarref.core.angular.view_angle vs float64 truth (all samples)
    generated_max_err: float  # polarref._generated view_angle_with_jacobian value vs truth (all)
    stable_vs_mpmath_max_err: float  # view_angle vs 50-digit mpmath on N_MPMATH samples
    stable_all_vs_mpmath_max_err: float  # same, on N_MPMATH samples including near-pole ones
    truth_vs_mpmath_max_err: float  # the float64 truth itself vs mpmath
    eq4_max_err: float  # printed e (acos) vs atan2 form
    eq5_sin_max_err: float  # |sin v - sin psi| (finite v only)
    eq5_nan: int  # samples where printed v is NaN
    eq8_max_err: float  # |Eq. 8 right side - cos theta| with u = alpha - psi, tau = pi/2 - beta
    claim7_max_err: float  # max |theta(e_z) - theta(e_z')| for two random e_z


def _max(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.max(np.abs(x))) if x.size else float("nan")


def case_evidence(name: str, sampler, n: int, rng: np.random.Generator) -> CaseEvidence:
    alpha, beta, e_y, e_x, e_z = sampler(rng, n)
    theta = truth_theta(alpha, beta, e_y, e_x, e_z)
    keep = (theta > NEAR_POLE) & (theta < np.pi - NEAR_POLE)
    printed = printed_eq3(alpha, beta, e_y, e_x)
    corrected = corrected_eq3(alpha, beta, e_y, e_x)
    stable = angular.view_angle(alpha, beta, e_y, e_x)
    idx = np.flatnonzero(keep)[:N_MPMATH]
    ref = np.array([mpmath_theta(alpha[i], beta[i], e_y[i], e_x[i]) for i in idx])
    ref_all = np.array([mpmath_theta(alpha[i], beta[i], e_y[i], e_x[i]) for i in range(N_MPMATH)])
    e_stable, psi = angular.tilt_and_axis_azimuth(e_y, e_x)
    v = printed_v(e_y, e_x)
    tau = np.pi / 2 - beta
    eq8 = np.cos(e_stable) * np.cos(tau) + np.sin(e_stable) * np.sin(tau) * np.cos(alpha - psi)
    other_ez = rng.uniform(-np.pi, np.pi, n)
    return CaseEvidence(
        case=name,
        samples=n,
        excluded_near_pole=int(np.sum(~keep)),
        printed_eq3_max_err=_max((printed - theta)[keep]),
        printed_eq3_nan=int(np.sum(np.isnan(printed))),
        printed_is_complement_max_err=_max((printed - (np.pi / 2 - theta))[keep]),
        corrected_eq3_max_err=_max((corrected - theta)[keep]),
        corrected_eq3_nan=int(np.sum(np.isnan(corrected))),
        corrected_eq3_max_err_all=_max(corrected - theta),
        stable_max_err=_max(stable - theta),
        generated_max_err=_max(view_angle_with_jacobian(alpha, beta, e_y, e_x)[0] - theta),
        stable_vs_mpmath_max_err=_max(stable[idx] - ref),
        stable_all_vs_mpmath_max_err=_max(stable[:N_MPMATH] - ref_all),
        truth_vs_mpmath_max_err=_max(theta[idx] - ref),
        eq4_max_err=_max(printed_e(e_y, e_x) - e_stable),
        eq5_sin_max_err=_max(np.sin(v) - np.sin(psi)),
        eq5_nan=int(np.sum(np.isnan(v))),
        eq8_max_err=_max(eq8 - np.cos(theta)),
        claim7_max_err=_max(truth_theta(alpha, beta, e_y, e_x, other_ez) - theta),
    )


def all_case_evidence(n: int = N_SAMPLES, seed: int = SEED) -> list[CaseEvidence]:
    rng = np.random.default_rng(seed)
    return [case_evidence(name, sampler, n, rng) for name, sampler in _cases().items()]


# --- alternatives -------------------------------------------------------------------------

SIGMA1_RULES: dict[str, Callable] = {
    "+1": lambda ey, ex, s2: np.ones_like(s2),
    "-1": lambda ey, ex, s2: -np.ones_like(s2),
    "sigma_2": lambda ey, ex, s2: s2,
    "-sigma_2": lambda ey, ex, s2: -s2,
}


@dataclasses.dataclass(frozen=True)
class ConventionTrial:
    """Corrected Eq. 3 (acos) under one alternative rotation convention."""

    first_axis: str  # world axis of the e_y rotation ("x" or "y"); e_x is about the other
    order: str  # "intrinsic" (e_z about the principal axis, applied last) or "extrinsic"
    signs: str  # signs applied to (e_y, e_x) in the active matrices; "-,-" = passive
    best_sigma1: str  # sigma_1 rule with the smallest error (project azimuth)
    best_max_err: float  # its max error (rad) with the project azimuth convention
    azimuth_fix: str  # azimuth reference under which it would hold, "" if none of those tried
    claim7_max_err: float  # max |theta(e_z) - theta(e_z')|


def _active(axis: str, t: np.ndarray) -> np.ndarray:
    return axis_rotation({"x": 0, "y": 1, "z": 2}[axis], t)


def convention_trials(n: int = 20_000, seed: int = SEED + 1) -> list[ConventionTrial]:
    """Enumerate rotation conventions; the chosen one is intrinsic, (x, y), signs (-, -)."""
    rng = np.random.default_rng(seed)
    alpha = rng.uniform(-np.pi, np.pi, n)
    beta = rng.uniform(-np.pi / 2, np.pi / 2, n)
    e_y = rng.uniform(-np.pi, np.pi, n)
    e_x = rng.uniform(-np.pi, np.pi, n)
    e_z, e_z2 = rng.uniform(-np.pi, np.pi, (2, n))
    d = angular.direction_from_azimuth_elevation(alpha, beta)
    trials = []
    for first, order, sy, sx in itertools.product("xy", ("intrinsic", "extrinsic"), (1, -1), (1, -1)):
        second = "y" if first == "x" else "x"

        def axis(ez):
            A, B, Z = _active(first, sy * e_y), _active(second, sx * e_x), _active("z", ez)
            M = A @ B @ Z if order == "intrinsic" else Z @ B @ A
            return M[..., :, 2]

        a = axis(e_z)
        theta = np.arccos(np.clip(np.sum(a * d, -1), -1, 1))
        theta2 = np.arccos(np.clip(np.sum(axis(e_z2) * d, -1), -1, 1))
        errs = {k: _max(corrected_eq3(alpha, beta, e_y, e_x, f) - theta) for k, f in SIGMA1_RULES.items()}
        best = min(errs, key=errs.get)
        fix = ""
        for mirror, offset in itertools.product((1, -1), (0.0, np.pi / 2, np.pi, -np.pi / 2)):
            alpha_paper = mirror * alpha + offset
            for k, f in SIGMA1_RULES.items():
                if _max(corrected_eq3(alpha_paper, beta, e_y, e_x, f) - theta) < 1e-6:
                    sign = "" if mirror == 1 else "-"
                    fix = fix or f"alpha_paper = {sign}alpha + {offset / np.pi:g} pi, sigma_1 = {k}"
        trials.append(ConventionTrial(first, order, f"{'+' if sy > 0 else '-'},{'+' if sx > 0 else '-'}",
                                      best, errs[best], fix, _max(theta2 - theta)))
    return trials


def sigma1_trials(n: int = N_SAMPLES, seed: int = SEED + 2) -> dict[str, float]:
    """Max error of corrected Eq. 3 per sigma_1 rule under the chosen convention."""
    rng = np.random.default_rng(seed)
    alpha, beta, e_y, e_x, e_z = _cases()["random"](rng, n)
    theta = truth_theta(alpha, beta, e_y, e_x, e_z)
    return {k: _max(corrected_eq3(alpha, beta, e_y, e_x, f) - theta) for k, f in SIGMA1_RULES.items()}


# --- symbolic -----------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SymbolicCheck:
    """One identity SymPy reduced to 0 (holds) or not."""

    name: str  # what is checked
    statement: str  # LaTeX of the identity
    holds: bool  # simplify(lhs - rhs) == 0


def _zero(expr: sp.Expr) -> bool:
    return sp.simplify(sp.expand_trig(expr)) == 0


def symbolic_checks() -> list[SymbolicCheck]:
    al, be, ey, ex, ez = m.alpha, m.beta, m.e_y, m.e_x, m.e_z
    a = m.world_from_cam()[:, 2]
    d = m.direction()
    E, P, s = sp.symbols("e psi s", real=True)
    sph = sp.Matrix([sp.sin(E) * sp.cos(P), sp.sin(E) * sp.sin(P), sp.cos(E)])
    tau = sp.pi / 2 - be
    checks = [
        SymbolicCheck("principal axis", r"R_{wc}\,\mathbf e_3 = (-\sin e_x,\ \sin e_y\cos e_x,\ \cos e_y\cos e_x)",
                      _zero((a - sp.Matrix([-sp.sin(ex), sp.sin(ey) * sp.cos(ex), sp.cos(ey) * sp.cos(ex)])).norm() ** 2)),
        SymbolicCheck("claim 7", r"\partial (R_{wc}\mathbf e_3)/\partial e_z = 0",
                      all(sp.simplify(sp.diff(c, ez)) == 0 for c in a)),
        SymbolicCheck("Eq. 4/9", r"\cos e := a_z = \cos e_y \cos e_x", _zero(a[2] - sp.cos(ey) * sp.cos(ex))),
        SymbolicCheck("Eq. 8", r"\mathbf a(e,\psi)\cdot\mathbf d = \cos e\cos\tau + \sin e\sin\tau\cos(\alpha-\psi),\ \tau=\pi/2-\beta",
                      _zero(sph.dot(d) - (sp.cos(E) * sp.cos(tau) + sp.sin(E) * sp.sin(tau) * sp.cos(al - P)))),
        SymbolicCheck("Eq. 5/10", r"\frac{\tan e_y}{\tan e}\,\sin e = \tan e_y \cos e_y\cos e_x = a_y = \sin e\,\sin\psi",
                      _zero(sp.tan(ey) * sp.cos(ey) * sp.cos(ex) - a[1])),
        SymbolicCheck("sigma, e_x < 0 (v = psi)", r"\sigma_2=1,\sigma_1=-1:\ \cos(-\psi+\alpha)=\cos(\alpha-\psi)",
                      _zero(sp.cos(-P + al) - sp.cos(al - P))),
        SymbolicCheck("sigma, e_x > 0 (v = pi - psi)", r"\sigma_2=-1,\sigma_1=1:\ -\cos(\pi-\psi+\alpha)=\cos(\alpha-\psi)",
                      _zero(-sp.cos(sp.pi - P + al) - sp.cos(al - P))),
        SymbolicCheck("sigma, e_x = 0 (psi = v = s pi/2, s = sgn e_y)",
                      r"\sigma_2=-s,\sigma_1=s:\ -s\cos(s^2\pi/2+\alpha)=\cos(\alpha - s\pi/2),\ s=\pm1",
                      all(_zero((-s * sp.cos(s * s * sp.pi / 2 + al) - sp.cos(al - s * sp.pi / 2)).subs(s, k)) for k in (1, -1))),
        SymbolicCheck("asin vs acos", r"\sin^{-1}x = \pi/2 - \cos^{-1}x\ (x\in[-1,1])",
                      sp.simplify(sp.diff(sp.asin(s) + sp.acos(s), s)) == 0
                      and sp.asin(0) + sp.acos(0) == sp.pi / 2),
    ]
    return checks
