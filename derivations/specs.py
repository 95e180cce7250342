"""Which functions are generated into ``polarref/_generated/`` and from which expressions."""

from __future__ import annotations

import sympy as sp

from derivations import model as m
from derivations.codegen import Arg, FunctionSpec

_THETA_SINGULAR = (
    "Singular set: theta = 0 or pi (ray on the principal axis), where theta is not differentiable "
    "(a cone point, like |x| at 0). There the Jacobian row is set to 0 (a valid subgradient, keeps "
    "solvers finite); the value itself is exact. NaN inputs give NaN value and Jacobian."
)
_PHI_SINGULAR = (
    "Singular set: theta = 0 or pi (ray on the principal axis), where phi is undefined: the value "
    "is reported as 0 (as polarref.camera does at the principal point) and the Jacobian row is NaN. Near it the "
    "Jacobian grows like 1/sin(theta). NaN inputs give NaN value and Jacobian."
)


def _scalar(sym: sp.Symbol, doc: str) -> Arg:
    return Arg(sym.name, (sym,), (), doc)


def _vec(name: str, v: sp.Matrix, doc: str) -> Arg:
    return Arg(name, tuple(v), (3,), doc)


_ALPHA = _scalar(m.alpha, "(...) landmark azimuth [rad] (from world +x toward +y).")
_BETA = _scalar(m.beta, "(...) landmark elevation [rad] (toward world +z).")
_EY = _scalar(m.e_y, "(...) first rotation [rad] (passive, about x).")
_EX = _scalar(m.e_x, "(...) second rotation [rad] (passive, about the new y).")
_EZ = _scalar(m.e_z, "(...) third rotation [rad] (passive, about the principal axis).")
_R = Arg("R_cam_from_world", tuple(m.R_sym), (3, 3),
         "(..., 3, 3) COLMAP rotation; increments are left-multiplied: R <- exp(delta) R.")
_C = _vec("C", m.C_sym, "(..., 3) camera centre in world coordinates.")
_X = _vec("X", m.X_sym, "(..., 3) world point.")
_CM = _vec("C_m", m.Cm_sym, "(..., 3) main anchor centre (the landmark's direction origin).")
_CA = _vec("C_a", m.Ca_sym, "(..., 3) associate anchor centre.")
_OMEGA = _scalar(m.omega, "(...) parallax angle at the landmark [rad], in (0, pi).")

_DELTA_AT = tuple((s, 0) for s in m.delta)


def _sq_xy(r: sp.Matrix) -> sp.Expr:
    return r[0] ** 2 + r[1] ** 2


def angle_specs() -> list[FunctionSpec]:
    q = m.ray_before_ez()
    r = m.ray_in_camera()
    return [
        FunctionSpec(
            name="view_angle_with_jacobian",
            summary="View angle theta of landmark direction (alpha, beta) seen by a camera rotated "
                    "(e_y, e_x, .) and d theta / d(alpha, beta, e_y, e_x).",
            args=(_ALPHA, _BETA, _EY, _EX),
            value=m.view_angle_of_ray(q),
            wrt=(m.alpha, m.beta, m.e_y, m.e_x),
            columns_doc="(alpha, beta, e_y, e_x)",
            singular=_sq_xy(q),
            singular_fill="0.0",
            singular_doc=_THETA_SINGULAR,
            notes="Stable form theta = atan2(|q_xy|, q_z) with q = Ry(e_x) Rx(e_y) d(alpha, beta); "
                  "equal to the corrected paper Eq. 3 (acos instead of asin) but accurate near 0 and pi. "
                  "theta does not depend on e_z (paper's claim 7).",
        ),
        FunctionSpec(
            name="polar_angle_with_jacobian",
            summary="Polar angle phi (image +x toward +y, in (-pi, pi]) of landmark direction (alpha, "
                    "beta) seen by a camera rotated (e_y, e_x, e_z), and its Jacobian.",
            args=(_ALPHA, _BETA, _EY, _EX, _EZ),
            value=m.polar_angle_of_ray(r),
            wrt=(m.alpha, m.beta, m.e_y, m.e_x, m.e_z),
            columns_doc="(alpha, beta, e_y, e_x, e_z); the e_z column equals 1",
            singular=_sq_xy(r),
            singular_fill="numpy.nan", singular_value="0.0",
            singular_doc=_PHI_SINGULAR,
            wrap_pi=True,
            notes="phi = atan2(r_y, r_x), r = Rz(e_z) Ry(e_x) Rx(e_y) d(alpha, beta) in the COLMAP camera "
                  "frame; equivalently phi = atan2(q_y, q_x) + e_z wrapped to (-pi, pi].",
        ),
    ]


def pose_specs() -> list[FunctionSpec]:
    r = m.ray_point()
    wrt = (*m.delta, *m.C_sym, *m.X_sym)
    cols = "(delta (3), C (3), X (3)) with delta the left rotation increment"
    return [
        FunctionSpec(
            name="view_angle_point_with_jacobian",
            summary="View angle of world point X seen by camera (R_cam_from_world, C) and its Jacobian.",
            args=(_R, _C, _X), value=m.view_angle_of_ray(r), wrt=wrt, at=_DELTA_AT,
            columns_doc=cols, singular=_sq_xy(r), singular_fill="0.0", singular_doc=_THETA_SINGULAR,
            notes="r = R (X - C) in the COLMAP camera frame; theta = atan2(|r_xy|, r_z).",
        ),
        FunctionSpec(
            name="polar_angle_point_with_jacobian",
            summary="Polar angle of world point X seen by camera (R_cam_from_world, C) and its Jacobian.",
            args=(_R, _C, _X), value=m.polar_angle_of_ray(r), wrt=wrt, at=_DELTA_AT,
            columns_doc=cols, singular=_sq_xy(r), singular_fill="numpy.nan", singular_value="0.0", singular_doc=_PHI_SINGULAR,
            wrap_pi=True, notes="r = R (X - C); phi = atan2(r_y, r_x) in (-pi, pi].",
        ),
    ]


_PARALLAX_NOTES = (
    "World ray from C toward the landmark: sin(omega) (C_m - C) + |C_a - C_m| sin(omega + phi_a) d, "
    "d = d(alpha, beta), phi_a = angle between d and C_a - C_m (atan2 form). Bounded as omega -> 0 "
    "(point at infinity along d). Where d is parallel to C_a - C_m the phi_a term is not "
    "differentiable and the C_m, C_a, alpha, beta columns may be NaN."
)


def parallax_specs() -> list[FunctionSpec]:
    r = m.ray_parallax()
    wrt = (*m.delta, *m.C_sym, *m.Cm_sym, *m.Ca_sym, m.alpha, m.beta, m.omega)
    cols = "(delta (3), C (3), C_m (3), C_a (3), alpha, beta, omega)"
    args = (_R, _C, _CM, _CA, _ALPHA, _BETA, _OMEGA)
    return [
        FunctionSpec(
            name="view_angle_parallax_with_jacobian",
            summary="View angle of a parallax-angle landmark seen by camera (R_cam_from_world, C) "
                    "and its Jacobian.",
            args=args, value=m.view_angle_of_ray(r), wrt=wrt, at=_DELTA_AT, columns_doc=cols,
            singular=_sq_xy(r), singular_fill="0.0", singular_doc=_THETA_SINGULAR,
            notes=_PARALLAX_NOTES,
        ),
        FunctionSpec(
            name="polar_angle_parallax_with_jacobian",
            summary="Polar angle of a parallax-angle landmark seen by camera (R_cam_from_world, C) "
                    "and its Jacobian.",
            args=args, value=m.polar_angle_of_ray(r), wrt=wrt, at=_DELTA_AT, columns_doc=cols,
            singular=_sq_xy(r), singular_fill="numpy.nan", singular_value="0.0", singular_doc=_PHI_SINGULAR,
            wrap_pi=True, notes=_PARALLAX_NOTES,
        ),
    ]


MODULES = {
    "angles.py": ("Angular observations as functions of the polar rotation angles (e_y, e_x, e_z).",
                  angle_specs),
    "pose.py": ("Angular observations of a world point by a camera pose (R_cam_from_world, C).",
                pose_specs),
    "parallax.py": ("Angular observations of a parallax-angle landmark by a camera pose.",
                    parallax_specs),
}
