"""Generated modules vs SymPy (lambdify) and central differences; bad input; singular points."""

import warnings

import numpy as np
import pytest
import sympy as sp

from derivations import codegen, specs
from derivations.numeric_checks import GENERATED, random_inputs
from polarref import _generated as gen
from polarref.core import angular
from polarref.core.geometry import so3_exp

ALL_SPECS = {s.name: s for make in (specs.angle_specs, specs.pose_specs, specs.parallax_specs) for s in make()}


def _flat_args(spec, args):
    """Component arrays in the order of the spec's symbols."""
    out = []
    for arg, value in zip(spec.args, args):
        value = np.asarray(value)
        out += [value] if not arg.trailing else [value.reshape(value.shape[0], -1)[:, k]
                                                  for k in range(len(arg.symbols))]
    return out


@pytest.mark.parametrize("name", list(GENERATED))
def test_generated_agrees_with_sympy_lambdify(name):
    spec = ALL_SPECS[name]
    value_expr, jac_exprs, _ = codegen.expressions(spec)
    symbols = [s for a in spec.args for s in a.symbols]
    f = sp.lambdify(symbols, [value_expr, *jac_exprs], modules="numpy", cse=True)
    args = random_inputs(name, np.random.default_rng(1), 2000)
    value, jac = GENERATED[name](*args)
    ref = f(*_flat_args(spec, args))
    ref_value = np.angle(np.exp(1j * (ref[0] - value))) + value if "polar" in name else ref[0]
    np.testing.assert_allclose(value, ref_value, rtol=1e-12, atol=1e-12)
    ref_jac = np.stack([np.broadcast_to(r, value.shape) for r in ref[1:]], axis=-1)
    ok = np.all(np.isfinite(ref_jac), axis=-1)
    assert ok.mean() > 0.99
    scale = np.maximum(1.0, np.abs(ref_jac[ok]))
    assert np.max(np.abs(jac[ok] - ref_jac[ok]) / scale) < 1e-12


def _shift(args, i, k, h):
    out = list(args)
    a = np.asarray(args[i])
    if a.ndim == 3:
        step = np.zeros(3)
        step[k] = h
        out[i] = so3_exp(step) @ a
    elif a.ndim == 2:
        out[i] = a.copy()
        out[i][:, k] += h
    else:
        out[i] = a + h
    return out


@pytest.mark.parametrize("name", list(GENERATED))
def test_generated_jacobian_vs_central_differences(name):
    fn = GENERATED[name]
    args = random_inputs(name, np.random.default_rng(2), 20_000)
    value, jac = fn(*args)
    h = 1e-6
    cols = []
    for i, a in enumerate(args):
        for k in ([None] if np.asarray(a).ndim == 1 else range(3)):
            d = fn(*_shift(args, i, k, h))[0] - fn(*_shift(args, i, k, -h))[0]
            cols.append(np.angle(np.exp(1j * d)) / (2 * h))
    fd = np.stack(cols, axis=-1)
    assert fd.shape == jac.shape
    keep = np.all(np.isfinite(jac), axis=-1) & (np.linalg.norm(jac, axis=-1) < 1e3)
    assert keep.mean() > 0.99
    err = np.abs(jac[keep] - fd[keep]) / np.maximum(1.0, np.abs(jac[keep]))
    assert np.max(err) < 1e-6
    # a column mix-up would be caught: swapping two columns breaks the agreement
    assert np.max(np.abs(jac[keep][:, ::-1] - fd[keep])) > 1e-3


def test_point_forms_agree_with_angle_forms():
    """theta/phi of a world point equal the angle-form functions for the same geometry."""
    rng = np.random.default_rng(3)
    n = 10_000
    e_y, e_x, e_z = rng.uniform(-np.pi, np.pi, (3, n))
    alpha, beta = rng.uniform(-np.pi, np.pi, n), rng.uniform(-1.5, 1.5, n)
    R_cw = np.swapaxes(angular.rotation_from_polar_angles(e_y, e_x, e_z), -1, -2)
    C = rng.normal(size=(n, 3))
    X = C + rng.uniform(0.1, 50, (n, 1)) * angular.direction_from_azimuth_elevation(alpha, beta)
    theta, _ = gen.view_angle_point_with_jacobian(R_cw, C, X)
    phi, _ = gen.polar_angle_point_with_jacobian(R_cw, C, X)
    assert np.max(np.abs(theta - angular.view_angle(alpha, beta, e_y, e_x))) < 1e-13
    dphi = np.angle(np.exp(1j * (phi - angular.polar_angle(alpha, beta, e_y, e_x, e_z))))
    assert np.max(np.abs(dphi)) < 1e-12


def test_parallax_form_matches_explicit_point():
    rng = np.random.default_rng(4)
    n = 10_000
    R = so3_exp(rng.normal(size=(n, 3)))
    C, C_m = rng.normal(size=(2, n, 3))
    C_a = C_m + rng.normal(size=(n, 3))
    alpha, beta = rng.uniform(-np.pi, np.pi, n), rng.uniform(-1.5, 1.5, n)
    omega = rng.uniform(0.01, 1.0, n)
    d = angular.direction_from_azimuth_elevation(alpha, beta)
    b = C_a - C_m
    phi_a = np.arccos(np.clip(np.sum(d * b, -1) / np.linalg.norm(b, axis=-1), -1, 1))
    ok = (phi_a + omega < np.pi - 1e-3) & (phi_a > 1e-3)  # a triangle exists
    depth = np.linalg.norm(b, axis=-1) * np.sin(omega + phi_a) / np.sin(omega)
    X = C_m + depth[:, None] * d
    # the parallax angle at X between the two anchors really is omega
    u, w = C_m - X, C_a - X
    got = np.arccos(np.sum(u * w, -1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(w, axis=-1))
    assert np.max(np.abs(got - omega)[ok]) < 1e-8
    for par, pt in ((gen.view_angle_parallax_with_jacobian, gen.view_angle_point_with_jacobian),
                    (gen.polar_angle_parallax_with_jacobian, gen.polar_angle_point_with_jacobian)):
        a = par(R, C, C_m, C_a, alpha, beta, omega)[0]
        p = pt(R, C, X)[0]
        assert np.max(np.abs(np.angle(np.exp(1j * (a - p))))[ok]) < 1e-9


def test_parallax_point_at_infinity_is_bounded():
    """omega -> 0: the ray tends to d and the Jacobian stays finite."""
    rng = np.random.default_rng(5)
    R = so3_exp(rng.normal(size=3))
    C, C_m, C_a = rng.normal(size=(3, 3))
    theta, J = gen.view_angle_parallax_with_jacobian(R, C, C_m, C_a, 0.4, 0.2, np.array([1e-12, 0.0]))
    d = angular.direction_from_azimuth_elevation(0.4, 0.2)
    expect = angular.ray_angles(R @ d)[0]
    np.testing.assert_allclose(theta, expect, atol=1e-10)
    assert np.all(np.isfinite(J))


def test_singular_rows_documented():
    R, C = np.eye(3), np.zeros(3)
    X = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, -2.0], [0.1, 0.0, 2.0]])
    theta, Jt = gen.view_angle_point_with_jacobian(R, C, X)
    phi, Jp = gen.polar_angle_point_with_jacobian(R, C, X)
    np.testing.assert_array_equal(theta[:2], [0.0, np.pi])
    np.testing.assert_array_equal(Jt[:2], 0.0)  # subgradient on the cone point
    np.testing.assert_array_equal(phi[:2], 0.0)
    assert np.isnan(Jp[:2]).all() and np.isfinite(Jp[2]).all()
    assert np.isfinite(Jt[2]).all() and np.abs(Jt[2]).max() > 0


def test_nan_in_nan_out_and_bad_shapes():
    rng = np.random.default_rng(6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name, fn in GENERATED.items():
            args = list(random_inputs(name, rng, 100))
            args[-1] = np.array(args[-1], dtype=float)
            args[-1][:10] = np.nan
            value, jac = fn(*args)
            assert np.isnan(value[:10]).all() and np.isnan(jac[:10]).all(), name
            assert np.isfinite(value[10:]).all(), name
    with pytest.raises(ValueError, match=r"\(\.\.\., 3, 3\)"):
        gen.view_angle_point_with_jacobian(np.eye(3)[:2], np.zeros(3), np.ones(3))
    with pytest.raises(ValueError):
        gen.view_angle_point_with_jacobian(np.eye(3), np.zeros((4, 3)), np.ones((5, 3)))
    value, jac = gen.view_angle_point_with_jacobian(np.eye(3), np.zeros((4, 1, 3)), np.ones((5, 3)))
    assert value.shape == (4, 5) and jac.shape == (4, 5, 9)
