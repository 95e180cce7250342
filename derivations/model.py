"""Plain Euclidean geometry of the angular observations, in SymPy.

Everything here is "truth by construction": rotation matrices, the principal axis, the
landmark direction, and the view/polar angles of the camera-frame ray. The paper's printed
equations are checked against these in :mod:`derivations.paper`.

Convention (chosen so that the paper's Eq. 3-10 can hold together with the project's fixed
direction convention ``d = (cos b cos a, cos b sin a, sin b)``; alternatives are enumerated in
:mod:`derivations.paper`):

* world: +z up; azimuth alpha from +x toward +y; elevation beta from the x-y plane toward +z.
* unrotated camera (e_y = e_x = e_z = 0): camera axes equal world axes, so the principal axis
  (camera +z) points up (+z); this is what Eq. 8 with e = 0 (cos theta = sin beta) demands.
* passive (frame) rotations, intrinsic order e_y -> e_x -> e_z::

      cam_from_world = Rz(e_z) @ Ry(e_x) @ Rx(e_y)
      world_from_cam = Rx(-e_y) @ Ry(-e_x) @ Rz(-e_z)

  with the right-handed active matrices ``Rx(t) = [[1,0,0],[0,c,-s],[0,s,c]]`` etc. The frame is
  turned first about x by e_y, then about the new y by e_x, then about the new z (the principal
  axis) by e_z. The principal axis in world coordinates is
  ``a = (-sin e_x, sin e_y cos e_x, cos e_y cos e_x)``: e_y tilts it toward +y, e_x toward -x.
* the camera frame is COLMAP's (x right, y down, z forward), so ``cam_from_world`` above is a
  COLMAP rotation. Polar angle ``phi = atan2(y_cam, x_cam)``: from image +x (right) toward
  image +y (down). View angle ``theta = atan2(hypot(x_cam, y_cam), z_cam)``.
"""

from __future__ import annotations

import sympy as sp

REAL = {"real": True}

alpha, beta = sp.symbols("alpha beta", **REAL)
e_y, e_x, e_z = sp.symbols("e_y e_x e_z", **REAL)


def Rx(t: sp.Expr) -> sp.Matrix:
    c, s = sp.cos(t), sp.sin(t)
    return sp.Matrix([[1, 0, 0], [0, c, -s], [0, s, c]])


def Ry(t: sp.Expr) -> sp.Matrix:
    c, s = sp.cos(t), sp.sin(t)
    return sp.Matrix([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def Rz(t: sp.Expr) -> sp.Matrix:
    c, s = sp.cos(t), sp.sin(t)
    return sp.Matrix([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def cam_from_world(ey: sp.Expr = e_y, ex: sp.Expr = e_x, ez: sp.Expr = e_z) -> sp.Matrix:
    """Passive intrinsic e_y (about x) -> e_x (about y) -> e_z (about z): COLMAP rotation."""
    return Rz(ez) * Ry(ex) * Rx(ey)


def world_from_cam(ey: sp.Expr = e_y, ex: sp.Expr = e_x, ez: sp.Expr = e_z) -> sp.Matrix:
    return Rx(-ey) * Ry(-ex) * Rz(-ez)


def direction(a: sp.Expr = alpha, b: sp.Expr = beta) -> sp.Matrix:
    """Project convention: azimuth from +x toward +y, elevation toward +z."""
    return sp.Matrix([sp.cos(b) * sp.cos(a), sp.cos(b) * sp.sin(a), sp.sin(b)])


def principal_axis(ey: sp.Expr = e_y, ex: sp.Expr = e_x) -> sp.Matrix:
    """Third column of world_from_cam; independent of e_z by construction."""
    return sp.simplify(world_from_cam(ey, ex, 0)[:, 2])


def view_angle_of_ray(r: sp.Matrix) -> sp.Expr:
    """Angle between a camera-frame ray and +z; the atan2 form is accurate near 0 and pi."""
    return sp.atan2(sp.sqrt(r[0] ** 2 + r[1] ** 2), r[2])


def polar_angle_of_ray(r: sp.Matrix) -> sp.Expr:
    """Angle of a camera-frame ray around +z, from +x toward +y (image right toward down)."""
    return sp.atan2(r[1], r[0])


def ray_in_camera(a: sp.Expr = alpha, b: sp.Expr = beta) -> sp.Matrix:
    """Landmark direction (alpha, beta) expressed in the camera frame."""
    return cam_from_world() * direction(a, b)


def ray_before_ez() -> sp.Matrix:
    """q = Ry(e_x) Rx(e_y) d: the camera-frame ray except for the final turn e_z about z."""
    return Ry(e_x) * Rx(e_y) * direction()


# --- Bundle-adjustment forms ---------------------------------------------------------------

R_sym = sp.Matrix(3, 3, sp.symbols("R00 R01 R02 R10 R11 R12 R20 R21 R22", **REAL))
C_sym = sp.Matrix(sp.symbols("C0 C1 C2", **REAL))
X_sym = sp.Matrix(sp.symbols("X0 X1 X2", **REAL))
delta = sp.Matrix(sp.symbols("delta0 delta1 delta2", **REAL))
Cm_sym = sp.Matrix(sp.symbols("Cm0 Cm1 Cm2", **REAL))
Ca_sym = sp.Matrix(sp.symbols("Ca0 Ca1 Ca2", **REAL))
omega = sp.Symbol("omega", **REAL)


def skew(v: sp.Matrix) -> sp.Matrix:
    return sp.Matrix([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def perturbed_rotation() -> sp.Matrix:
    """exp(delta) R to first order; derivatives are taken at delta = 0 (left perturbation)."""
    return (sp.eye(3) + skew(delta)) * R_sym


def ray_point() -> sp.Matrix:
    """Camera-frame ray toward world point X: R (X - C) with R <- exp(delta) R."""
    return perturbed_rotation() * (X_sym - C_sym)


def parallax_world_ray() -> sp.Matrix:
    """Unnormalised world ray from camera centre C toward a parallax-angle landmark.

    Landmark (C_m, C_a, alpha, beta, omega): d is the direction from the main anchor C_m toward
    the point, phi_a the angle between d and C_a - C_m, omega the parallax angle at the point.
    By the sine rule the point is C_m + |C_a - C_m| sin(omega + phi_a) / sin(omega) d; scaling
    by sin(omega) > 0 keeps the ray bounded as omega -> 0 (point at infinity along d).
    """
    d = direction()
    b = Ca_sym - Cm_sym
    cross = d.cross(b)
    phi_a = sp.atan2(sp.sqrt(cross.dot(cross)), d.dot(b))
    return sp.sin(omega) * (Cm_sym - C_sym) + sp.sqrt(b.dot(b)) * sp.sin(omega + phi_a) * d


def ray_parallax() -> sp.Matrix:
    return perturbed_rotation() * parallax_world_ray()
