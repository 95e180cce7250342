"""Random inputs for the generated functions and their central-difference Jacobian check."""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from polarref import _generated as gen
from polarref.core.geometry import so3_exp

FD_STEP = 1e-6  # central-difference step (rad or length units); error ~ h^2 f''' + eps/h


def random_inputs(name: str, rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    """Seeded inputs for generated function ``name`` (positional, in signature order)."""
    u = lambda lo, hi: rng.uniform(lo, hi, n)  # noqa: E731
    if name in ("view_angle_with_jacobian",):
        return u(-np.pi, np.pi), u(-1.5, 1.5), u(-np.pi, np.pi), u(-np.pi, np.pi)
    if name in ("polar_angle_with_jacobian",):
        return u(-np.pi, np.pi), u(-1.5, 1.5), u(-np.pi, np.pi), u(-np.pi, np.pi), u(-np.pi, np.pi)
    R = so3_exp(rng.normal(size=(n, 3)))
    C = rng.normal(size=(n, 3))
    if name.endswith("point_with_jacobian"):
        return R, C, C + rng.normal(size=(n, 3)) * 5.0
    C_m = rng.normal(size=(n, 3))
    C_a = C_m + rng.normal(size=(n, 3))
    return R, C, C_m, C_a, u(-np.pi, np.pi), u(-1.5, 1.5), u(0.01, 1.0)


GENERATED: dict[str, Callable] = {
    "view_angle_with_jacobian": gen.view_angle_with_jacobian,
    "polar_angle_with_jacobian": gen.polar_angle_with_jacobian,
    "view_angle_point_with_jacobian": gen.view_angle_point_with_jacobian,
    "polar_angle_point_with_jacobian": gen.polar_angle_point_with_jacobian,
    "view_angle_parallax_with_jacobian": gen.view_angle_parallax_with_jacobian,
    "polar_angle_parallax_with_jacobian": gen.polar_angle_parallax_with_jacobian,
}


def _columns(args: tuple[np.ndarray, ...]) -> list[tuple[int, int | None]]:
    """(argument index, component or None) per Jacobian column; rotations first as delta."""
    cols: list[tuple[int, int | None]] = []
    for i, a in enumerate(args):
        if a.ndim == 1:
            cols.append((i, None))
        else:
            cols += [(i, k) for k in range(3)]
    return cols


def _shifted(args, col, h):
    i, k = col
    out = list(args)
    a = args[i]
    if a.ndim == 3:  # rotation: left increment exp(h e_k) R
        step = np.zeros(3)
        step[k] = h
        out[i] = so3_exp(step) @ a
    elif a.ndim == 2:
        out[i] = a.copy()
        out[i][:, k] += h
    else:
        out[i] = a + h
    return out


def central_difference(fn: Callable, args: tuple[np.ndarray, ...], h: float = FD_STEP) -> np.ndarray:
    """(N, ncols) central differences of fn's value; angle differences wrapped to (-pi, pi]."""
    cols = []
    for col in _columns(args):
        hi = fn(*_shifted(args, col, h))[0]
        lo = fn(*_shifted(args, col, -h))[0]
        cols.append(np.angle(np.exp(1j * (hi - lo))) / (2 * h))
    return np.stack(cols, axis=-1)


@dataclasses.dataclass(frozen=True)
class JacobianCheck:
    """Generated Jacobian vs central differences for one function."""

    function: str  # generated function name
    samples: int  # samples compared (those with sin(theta) > 1e-2 and finite values)
    max_abs_err: float  # max |J - FD| / max(1, |J|), over all entries


def jacobian_check(name: str, n: int = 2000, seed: int = 7) -> JacobianCheck:
    fn = GENERATED[name]
    args = random_inputs(name, np.random.default_rng(seed), n)
    value, jac = fn(*args)
    fd = central_difference(fn, args)
    # Away from the singular set (ray on the axis) and, for parallax, from d || C_a - C_m.
    keep = np.all(np.isfinite(jac), axis=-1) & (np.abs(np.linalg.norm(jac, axis=-1)) < 1e3)
    err = np.abs(jac - fd) / np.maximum(1.0, np.abs(jac))
    return JacobianCheck(name, int(keep.sum()), float(np.max(err[keep])))


def all_jacobian_checks() -> list[JacobianCheck]:
    return [jacobian_check(name) for name in GENERATED]
