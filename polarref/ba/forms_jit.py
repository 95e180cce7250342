"""The numba-compiled evaluation of the forms (residuals and Jacobians), reached through
:mod:`polarref.ba.kernels` like kernels_jit.py's normal-equation kernels.

Each row type (pixel, view angle, angular with its axis chart) and each chain rule (Euclidean,
parallax landmarks) is written once, per observation in scalars (inlined), and used by the
kernels that mirror the numpy reference stage by stage (``parallax_rays``, ``pixel_rows``,
``parallax_jacobians``, ...; the tests compare them against numpy). The angular form's rays,
rows and chain rule also run fused in one pass (``angular_obs``): 1-2 % less time per LM
iteration than its three passes. Fusing the pixel rows the same way was measured 1-2 %
slower for the parallax form and no faster for polar or Euclidean (interleaved solves, three
problems; reports/bench-ba/notes.md, seventh pass), so those keep their passes.
"""

from __future__ import annotations

import numba
import numpy as np

# angular rows per observation (``mode``): theta only (phi gated off), whitened (theta, phi),
# whitened axis chart (angular.py)
THETA_ONLY, THETA_PHI, CHART = 0, 1, 2


def _njit(fn):
    # numpy semantics for x / 0 (inf or nan, as the reference path), not ZeroDivisionError
    return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)


def _inline(fn):
    return numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")(fn)


# ---- rows: one observation's residuals and res_D_Xc, in scalars ----

@_inline
def _pixel(K, m, X, Y, Z, obs_uv, jac):
    """Pixel residual of camera-frame point (X, Y, Z) (projection.project's operations in its
    order) and, with jac, ``uv_D_Xc``: (r0, r1, j00, j01, j02, j10, j11, j12)."""
    fx, fy, cx, cy, k1, k2 = K[m, 0], K[m, 1], K[m, 2], K[m, 3], K[m, 4], K[m, 5]
    iz = 1.0 / Z
    x, y = X * iz, Y * iz
    r2 = x * x + y * y
    dist = 1.0 + r2 * (k1 + k2 * r2)
    r0 = (fx * x * dist + cx) - obs_uv[m, 0]
    r1 = (fy * y * dist + cy) - obs_uv[m, 1]
    if not jac:
        return r0, r1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    a = 2.0 * (k1 + 2.0 * k2 * r2)
    dxx, dxy, dyy = dist + a * x * x, a * x * y, dist + a * y * y
    j00, j01 = fx * dxx * iz, fx * dxy * iz
    j10, j11 = fy * dxy * iz, fy * dyy * iz
    return r0, r1, j00, j01, -(j00 * x + j01 * y), j10, j11, -(j10 * x + j11 * y)


# atan(t) = t (1 + t^2 A(t^2)) for |t| <= SERIES_MAX: the odd Taylor series to t^17; the first
# term left out, t^19 / 19, is below 3e-18 |t| there. Where t^2 < MID_T2 (|t| < 0.0316: a
# mapper's residuals are ~1e-3 rad) the series stops at t^9: the first term left out, t^11 / 11,
# is below 9.1e-17 |t|, under half an ulp of t. One tier for nearly every residual keeps the
# branch predictable: a cut at |t| = 1e-3 (a 1 px residual at f = 1000 px) split a mapper's
# residuals about evenly, and the mispredictions cost a fifth of polar's fused evaluation.
SERIES_MAX = 0.125
MID_T2 = 1e-3
_ATAN = (-1.0 / 3, 1.0 / 5, -1.0 / 7, 1.0 / 9, -1.0 / 11, 1.0 / 13, -1.0 / 15, 1.0 / 17)
_A0, _A1, _A2, _A3, _A4, _A5, _A6, _A7 = _ATAN


@_inline
def _atan_ratio(num, den):
    """(True, atan(num / den)) by the series above where ``den > 0`` and ``|num| <= SERIES_MAX
    den``, else (False, 0.0): the caller then takes its arctan. An angle's offset from an
    observed one is such a ratio (angle subtraction: no arctan call per residual, which was
    30 % of polar's evaluation and a third of angular's)."""
    if den > 0.0 and abs(num) <= SERIES_MAX * den:
        t = num / den
        u = t * t
        if u < MID_T2:
            a = _A0 + u * (_A1 + u * (_A2 + u * _A3))
        else:
            a = _A0 + u * (_A1 + u * (_A2 + u * (_A3 + u * (_A4 + u * (_A5 + u * (_A6 + u * _A7))))))
        return True, t + t * (u * a)
    return False, 0.0


@_inline
def _theta(x, y, z, jac):
    """View angle of the projective ray ``sign(Z) (x, y, z)`` (angular_obs.theta_rows) and,
    with jac, ``theta_D_Xc``: (theta, t0, t1, t2)."""
    sg = -1.0 if z < 0 else 1.0
    x, y, z = x * sg, y * sg, z * sg
    rho2 = x * x + y * y
    rho = np.sqrt(rho2)
    theta = np.arctan2(rho, z)
    if not jac:
        return theta, 0.0, 0.0, 0.0
    n2 = rho2 + z * z
    f = z / (max(rho, 1e-300) * n2)
    return theta, x * f * sg, y * f * sg, -rho / n2 * sg


@_inline
def _chart(x, y, z, jac):
    """Azimuthal-equidistant chart ``theta (cos phi, sin phi)`` of the projective ray and
    ``e_D_Xc`` (angular_obs.axis_chart_rows, its near-axis series included):
    (e0, e1, j00, j01, j02, j10, j11, j12)."""
    sg = -1.0 if z < 0 else 1.0
    x, y, z = x * sg, y * sg, z * sg
    rho = np.hypot(x, y)
    theta = np.arctan2(rho, z)
    t = rho / (z if z > 0 else 1.0)
    near = z > 0 and t < 1e-3
    g = 1.0 / z if near else theta / rho
    if not jac:
        return g * x, g * y, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    n2 = rho * rho + z * z
    # (d g / d rho) / rho; its closed form cancels badly near the axis: series there
    q = (-2.0 / 3.0 + 0.8 * t * t) / z ** 3 if near else (rho * z / n2 - theta) / rho ** 3
    qxy = q * x * y * sg
    return (g * x, g * y, (g + q * x * x) * sg, qxy, -x / n2 * sg,
            qxy, (g + q * y * y) * sg, -y / n2 * sg)


@_inline
def _chart_row(x, y, z, m, a_obs, whiten, jac):
    """Angular residuals of a CHART row (angular.py): ``B^-1 (e - e_obs)`` of the axis chart
    (a_obs / whiten hold the chart's), and with jac their ``res_D_Xc``: (r0, r1, j00, j01, j02,
    j10, j11, j12)."""
    w00, w01, w10, w11 = whiten[m, 0, 0], whiten[m, 0, 1], whiten[m, 1, 0], whiten[m, 1, 1]
    e0, e1, c00, c01, c02, c10, c11, c12 = _chart(x, y, z, jac)
    d0, d1 = e0 - a_obs[m, 0], e1 - a_obs[m, 1]
    return (w00 * d0 + w01 * d1, w10 * d0 + w11 * d1,
            w00 * c00 + w01 * c10, w00 * c01 + w01 * c11, w00 * c02 + w01 * c12,
            w10 * c00 + w11 * c10, w10 * c01 + w11 * c11, w10 * c02 + w11 * c12)


@_inline
def _angle_rows(x, y, z, m, a_obs, cs, whiten, w_theta, mode, jac, exact):
    """Angular residuals of a THETA_PHI row, ``A^-1 (theta - theta_obs, wrap(phi - phi_obs))``, or
    of a THETA_ONLY row, ``((theta - theta_obs) w_theta, 0)`` (angular.py), with jac their
    ``res_D_Xc``, as (ok, (r0, r1, j00, ..., j12)). cs (M, 4) holds cos, sin of
    theta_obs and phi_obs: both offsets by :func:`_atan_ratio` of the rotated ray (already
    wrapped). Where that does not apply ``ok`` is False, and with ``exact`` (a literal) the
    offset is arctan2's (angular_obs.theta_rows / phi_rows' arithmetic). angular_rows' main pass
    runs without ``exact`` and redoes the rows that are not ok in a pass of their own (with the
    call in its loop it took 4.5 instead of 0.7 ms on a local BA's 70k rows); angular_obs keeps
    ``exact`` inline, where a second pass measured slower."""
    # the projective ray sign(z) (x, y, z), as _theta
    sg = -1.0 if z < 0 else 1.0
    xs, ys, zs = x * sg, y * sg, z * sg
    rho2 = xs * xs + ys * ys
    rho = np.sqrt(rho2)
    ct, st = cs[m, 0], cs[m, 1]
    ok, dt = _atan_ratio(rho * ct - zs * st, zs * ct + rho * st)
    if exact and not ok:
        dt = np.arctan2(rho, zs) - a_obs[m, 0]
    t0 = t1 = t2 = 0.0
    if jac:  # _theta's theta_D_Xc
        n2 = rho2 + zs * zs
        f = zs / (max(rho, 1e-300) * n2)
        t0, t1, t2 = xs * f * sg, ys * f * sg, -rho / n2 * sg
    if mode[m] == THETA_ONLY:
        w = w_theta[m]
        return ok, (dt * w, 0.0, t0 * w, t1 * w, t2 * w, 0.0, 0.0, 0.0)
    w00, w01, w10, w11 = whiten[m, 0, 0], whiten[m, 0, 1], whiten[m, 1, 0], whiten[m, 1, 1]
    cp, sp = cs[m, 2], cs[m, 3]
    ok_phi, df = _atan_ratio(ys * cp - xs * sp, xs * cp + ys * sp)
    if exact and not ok_phi:
        a = np.arctan2(ys, xs) - a_obs[m, 1]
        # wrap to (-pi, pi] (angular_obs.wrap); the modulo only where a is outside
        df = a if -np.pi < a <= np.pi else np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    r0, r1 = w00 * dt + w01 * df, w10 * dt + w11 * df
    if not jac:
        return ok and ok_phi, (r0, r1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    rr = max(rho2, 1e-300)
    f0, f1 = -ys / rr * sg, xs / rr * sg  # phi_D_Xc (third component 0)
    return ok and ok_phi, (r0, r1, w00 * t0 + w01 * f0, w00 * t1 + w01 * f1, w00 * t2,
                           w10 * t0 + w11 * f0, w10 * t1 + w11 * f1, w10 * t2)


@_inline
def _put2(res, mr, J, mj, jac, row):
    """Two residual rows (r0, r1, j00..j12) into res[mr, :2] and, with jac, J[mj, :2]."""
    res[mr, 0], res[mr, 1] = row[0], row[1]
    if jac:
        J[mj, 0, 0], J[mj, 0, 1], J[mj, 0, 2] = row[2], row[3], row[4]
        J[mj, 1, 0], J[mj, 1, 1], J[mj, 1, 2] = row[5], row[6], row[7]


# ---- chain rules: one observation's parameter Jacobians from its res_D_Xc ----

@_inline
def _euclidean_chain(Jx, mj, k, x, y, z, R, i, Jp, Jc, m):
    """``res_D_point = Jx R_i`` and ``res_D_cam = [Xc x Jx, -res_D_point]`` of observation m
    (rows Jx[mj, :k]) into Jp[m], Jc[m]."""
    for r in range(k):
        a0, a1, a2 = Jx[mj, r, 0], Jx[mj, r, 1], Jx[mj, r, 2]
        for j in range(3):
            v = a0 * R[i, 0, j] + a1 * R[i, 1, j] + a2 * R[i, 2, j]
            Jp[m, r, j] = v
            Jc[m, r, 3 + j] = -v
        Jc[m, r, 0] = y * a2 - z * a1
        Jc[m, r, 1] = z * a0 - x * a2
        Jc[m, r, 2] = x * a1 - y * a0


@_inline
def _parallax_chain(Jx, mj, k, x, y, z, R, C, i, p, Cm, d, sw, cw, dh_dw, dv_dab, Jp, Jo, Ad,
                    m):
    """Parallax landmarks' chain rule (parallax.py) of observation m (rows Jx[mj, :k]),
    with ``A = Jx R_i``: point ``[A dv/d(alpha, beta), A dv/dw]``, observer
    ``[Xc x Jx, -sin(w) A]`` and ``A d`` into Jp[m], Jo[m], Ad[m]."""
    d0, d1, d2 = d[p, 0], d[p, 1], d[p, 2]
    hw, cwp, swp = dh_dw[p], cw[p], sw[p]
    w0 = hw * d0 + cwp * (Cm[p, 0] - C[i, 0])  # dv/dw
    w1 = hw * d1 + cwp * (Cm[p, 1] - C[i, 1])
    w2 = hw * d2 + cwp * (Cm[p, 2] - C[i, 2])
    b00, b01 = dv_dab[p, 0, 0], dv_dab[p, 0, 1]
    b10, b11 = dv_dab[p, 1, 0], dv_dab[p, 1, 1]
    b20, b21 = dv_dab[p, 2, 0], dv_dab[p, 2, 1]
    r00, r01, r02 = R[i, 0, 0], R[i, 0, 1], R[i, 0, 2]
    r10, r11, r12 = R[i, 1, 0], R[i, 1, 1], R[i, 1, 2]
    r20, r21, r22 = R[i, 2, 0], R[i, 2, 1], R[i, 2, 2]
    for r in range(k):
        a0, a1, a2 = Jx[mj, r, 0], Jx[mj, r, 1], Jx[mj, r, 2]
        A0 = a0 * r00 + a1 * r10 + a2 * r20  # A = Jx R_i
        A1 = a0 * r01 + a1 * r11 + a2 * r21
        A2 = a0 * r02 + a1 * r12 + a2 * r22
        Jp[m, r, 0] = A0 * b00 + A1 * b10 + A2 * b20
        Jp[m, r, 1] = A0 * b01 + A1 * b11 + A2 * b21
        Jp[m, r, 2] = A0 * w0 + A1 * w1 + A2 * w2
        Jo[m, r, 0] = y * a2 - z * a1
        Jo[m, r, 1] = z * a0 - x * a2
        Jo[m, r, 2] = x * a1 - y * a0
        Jo[m, r, 3] = -swp * A0
        Jo[m, r, 4] = -swp * A1
        Jo[m, r, 5] = -swp * A2
        Ad[m, r] = A0 * d0 + A1 * d1 + A2 * d2


@_inline
def _parallax_ray(R, C, i, p, Cm, sw, hd):
    """Camera-frame ray ``R_i (sin(w) (C_m - C_i) + h d)`` of point p in camera i."""
    v0 = sw[p] * (Cm[p, 0] - C[i, 0]) + hd[p, 0]
    v1 = sw[p] * (Cm[p, 1] - C[i, 1]) + hd[p, 1]
    v2 = sw[p] * (Cm[p, 2] - C[i, 2]) + hd[p, 2]
    return (R[i, 0, 0] * v0 + R[i, 0, 1] * v1 + R[i, 0, 2] * v2,
            R[i, 1, 0] * v0 + R[i, 1, 1] * v1 + R[i, 1, 2] * v2,
            R[i, 2, 0] * v0 + R[i, 2, 1] * v1 + R[i, 2, 2] * v2)


# ---- fused kernel: angular's evaluation in one pass ----

@_njit
def angular_obs(R, C, obs_cam, obs_pt, Cm, d, sw, cw, hd, dh_dw, dv_dab, a_obs, cs, whiten,
                w_theta, mode):
    """Angular residuals (M, 2), ``res_D_point`` (M, 2, 3), ``res_D_obs`` (M, 2, 6) and ``A d``
    (M, 2) of parallax landmarks (angular.py, factored anchors) in one pass: parallax_rays,
    angular_rows and parallax_jacobians fused. Per-point terms from parallax_points; rows per
    ``mode`` (:func:`_angle_rows`, :func:`_chart_row`)."""
    M = len(obs_cam)
    res, Jp, Jo, Ad = np.empty((M, 2)), np.empty((M, 2, 3)), np.empty((M, 2, 6)), np.empty((M, 2))
    jx = np.empty((1, 2, 3))  # res_D_Xc of the current observation
    # the axis chart's rows (rare) in a pass of their own: inline beside the angle rows they
    # made this pass 1.3x as long (3.8 vs 2.9 ms on a real mapper local BA, 70k observations);
    # arctan2 stays inline here (a second pass for it, as angular_rows', measured 3.5 ms)
    for chart in (False, True):
        for m in range(M):
            if (mode[m] == CHART) != chart:
                continue
            i, p = obs_cam[m], obs_pt[m]
            x, y, z = _parallax_ray(R, C, i, p, Cm, sw, hd)
            row = (_chart_row(x, y, z, m, a_obs, whiten, True) if chart else
                   _angle_rows(x, y, z, m, a_obs, cs, whiten, w_theta, mode, True, True)[1])
            _put2(res, m, jx, 0, True, row)
            _parallax_chain(jx, 0, 2, x, y, z, R, C, i, p, Cm, d, sw, cw, dh_dw, dv_dab, Jp,
                            Jo, Ad, m)
    return res, Jp, Jo, Ad


# ---- stage kernels: the numpy reference's stages, one by one ----

@_njit
def euclidean_rays(R, C, X, obs_cam, obs_pt):
    """Camera-frame points ``Xc[m] = R_i (X_p - C_i)`` (M, 3)."""
    M = len(obs_cam)
    Xc = np.empty((M, 3))
    for m in range(M):
        i, p = obs_cam[m], obs_pt[m]
        v0, v1, v2 = X[p, 0] - C[i, 0], X[p, 1] - C[i, 1], X[p, 2] - C[i, 2]
        for r in range(3):
            Xc[m, r] = R[i, r, 0] * v0 + R[i, r, 1] * v1 + R[i, r, 2] * v2
    return Xc


@_njit
def euclidean_jacobians(Jx, Xc, R, obs_cam):
    """``res_D_point = Jx R_i`` (M, k, 3) and ``res_D_cam = [Xc x Jx, -res_D_point]`` (M, k, 6)
    from ``res_D_Xc`` (M, k, 3) (euclidean.py)."""
    M, k, _ = Jx.shape
    Jp = np.empty((M, k, 3))
    Jc = np.empty((M, k, 6))
    for m in range(M):
        _euclidean_chain(Jx, m, k, Xc[m, 0], Xc[m, 1], Xc[m, 2], R, obs_cam[m], Jp, Jc, m)
    return Jp, Jc


@_njit
def parallax_points(frame, pts, C, main, assoc, jac):
    """Per-point terms of parallax landmarks (parallax.py ``landmark_terms`` and
    ``point_derivatives``): main centre Cm (P, 3), direction d (P, 3), sin(w), cos(w) (P,),
    h d (P, 3); with ``jac`` also dh/dw (P,), dh/de (P, 3), dv/d(alpha, beta) (P, 3, 2)."""
    P = len(pts)
    Cm, d, hd = np.empty((P, 3)), np.empty((P, 3)), np.empty((P, 3))
    sw, cw, dh_dw = np.empty(P), np.empty(P), np.empty(P)
    dh_de, dv_dab = np.empty((P, 3)), np.empty((P, 3, 2))
    u, e, ua, ub, dd = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for p in range(P):
        ca, sa = np.cos(pts[p, 0]), np.sin(pts[p, 0])
        cb, sb = np.cos(pts[p, 1]), np.sin(pts[p, 1])
        u[0], u[1], u[2] = cb * ca, cb * sa, sb
        m, a = main[p], assoc[p]
        for i in range(3):
            d[p, i] = frame[p, i, 0] * u[0] + frame[p, i, 1] * u[1] + frame[p, i, 2] * u[2]
            Cm[p, i] = C[m, i]
            e[i] = C[a, i] - C[m, i]
        c = d[p, 0] * e[0] + d[p, 1] * e[1] + d[p, 2] * e[2]
        x0 = d[p, 1] * e[2] - d[p, 2] * e[1]
        x1 = d[p, 2] * e[0] - d[p, 0] * e[2]
        x2 = d[p, 0] * e[1] - d[p, 1] * e[0]
        s = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        sw[p], cw[p] = np.sin(pts[p, 2]), np.cos(pts[p, 2])
        h = sw[p] * c + cw[p] * s
        for i in range(3):
            hd[p, i] = h * d[p, i]
        if not jac:
            continue
        dh_dw[p] = cw[p] * c - sw[p] * s
        e2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
        f = cw[p] / s
        for i in range(3):
            dd[i] = sw[p] * e[i] + f * (e2 * d[p, i] - c * e[i])  # dh/dd
            dh_de[p, i] = sw[p] * d[p, i] + f * (e[i] - c * d[p, i])
        ua[0], ua[1], ua[2] = -cb * sa, cb * ca, 0.0  # d u / d alpha, d u / d beta
        ub[0], ub[1], ub[2] = -sb * ca, -sb * sa, cb
        ga = gb = 0.0
        for i in range(3):
            Da = frame[p, i, 0] * ua[0] + frame[p, i, 1] * ua[1] + frame[p, i, 2] * ua[2]
            Db = frame[p, i, 0] * ub[0] + frame[p, i, 1] * ub[1] + frame[p, i, 2] * ub[2]
            ga += dd[i] * Da
            gb += dd[i] * Db
            dv_dab[p, i, 0] = h * Da
            dv_dab[p, i, 1] = h * Db
        for i in range(3):
            dv_dab[p, i, 0] += d[p, i] * ga
            dv_dab[p, i, 1] += d[p, i] * gb
    return Cm, d, sw, cw, hd, dh_dw, dh_de, dv_dab


@_njit
def parallax_xyz(frame, pts, C, main, assoc, far):
    """XYZ (P, 3) of parallax landmarks (parallax.py ``to_xyz``: ``C_m + (h / sin(w)) d``, or
    ``far |e|`` along d where ``|sin(w)| far < 1``) and the number of such points at
    infinity; the solve's write-back, one pass instead of numpy's (P,) temporaries."""
    P = len(pts)
    X = np.empty((P, 3))
    n_far = 0
    for p in range(P):
        ca, sa = np.cos(pts[p, 0]), np.sin(pts[p, 0])
        cb, sb = np.cos(pts[p, 1]), np.sin(pts[p, 1])
        u0, u1, u2 = cb * ca, cb * sa, sb
        m, a = main[p], assoc[p]
        d0 = frame[p, 0, 0] * u0 + frame[p, 0, 1] * u1 + frame[p, 0, 2] * u2
        d1 = frame[p, 1, 0] * u0 + frame[p, 1, 1] * u1 + frame[p, 1, 2] * u2
        d2 = frame[p, 2, 0] * u0 + frame[p, 2, 1] * u1 + frame[p, 2, 2] * u2
        e0, e1, e2 = C[a, 0] - C[m, 0], C[a, 1] - C[m, 1], C[a, 2] - C[m, 2]
        sw = np.sin(pts[p, 2])
        if abs(sw) * far < 1.0:
            dist = far * np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
            n_far += 1
        else:
            c = d0 * e0 + d1 * e1 + d2 * e2
            x0, x1, x2 = d1 * e2 - d2 * e1, d2 * e0 - d0 * e2, d0 * e1 - d1 * e0
            s = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
            dist = (sw * c + np.cos(pts[p, 2]) * s) / sw
        X[p, 0], X[p, 1], X[p, 2] = C[m, 0] + dist * d0, C[m, 1] + dist * d1, C[m, 2] + dist * d2
    return X, n_far


@_njit
def parallax_rays(R, C, obs_cam, obs_pt, Cm, sw, hd):
    """Camera-frame rays ``Xc[m] = R_i (sin(w) (C_m - C_i) + h d)`` (M, 3) of parallax
    landmarks (parallax.py); Cm, hd = h d (P, 3) and sw (P,) per point."""
    M = len(obs_cam)
    Xc = np.empty((M, 3))
    for m in range(M):
        Xc[m, 0], Xc[m, 1], Xc[m, 2] = _parallax_ray(R, C, obs_cam[m], obs_pt[m], Cm, sw, hd)
    return Xc


@_njit
def parallax_jacobians(Jx, Xc, R, C, obs_cam, obs_pt, Cm, d, sw, cw, dh_dw, dh_de, dv_dab,
                       dense=True):
    """Chain rule from ``res_D_Xc`` (M, k, 3) to the parameters of parallax landmarks:
    ``res_D_point`` (M, k, 3) and the dense slot Jacobians ``res_D_obs`` (M, k, 6),
    ``res_D_main_centre`` and ``res_D_assoc_centre`` (M, k, 3) (see parallax.py, anchor_terms.py:
    with ``A = Jx R_i``: point ``[A dv/d(alpha, beta), A dv/dw]``, observer ``[Xc x Jx, -sin(w) A]``,
    associate ``(A d) dh/de^T``, main ``sin(w) A - associate``). Also ``A d`` (M, k), the
    anchors' factored form (anchor_terms.py); without ``dense`` the anchors' (M, k, 3)
    Jacobians are not formed (returned with 0 rows)."""
    M, k, _ = Jx.shape
    Jp = np.empty((M, k, 3))
    Jo = np.empty((M, k, 6))
    Md = M if dense else 0
    Jm = np.empty((Md, k, 3))
    Ja = np.empty((Md, k, 3))
    Ad = np.empty((M, k))
    for m in range(M):
        _parallax_chain(Jx, m, k, Xc[m, 0], Xc[m, 1], Xc[m, 2], R, C, obs_cam[m], obs_pt[m],
                        Cm, d, sw, cw, dh_dw, dv_dab, Jp, Jo, Ad, m)
    if dense:
        for m in range(M):
            p = obs_pt[m]
            for r in range(k):
                for j in range(3):
                    Ja[m, r, j] = Ad[m, r] * dh_de[p, j]
                    Jm[m, r, j] = -Jo[m, r, 3 + j] - Ja[m, r, j]
    return Jp, Jo, Jm, Ja, Ad


@_njit
def pixel_rows(Xc, K, obs_uv, k, jac):
    """Pixel residuals ``uv - obs_uv`` into rows 0:2 of res (M, k) and, with jac, ``uv_D_Xc``
    into J (M, k, 3) (J has 0 rows without jac): projection.project with the same operations
    in the same order (bitwise its result), in one pass and without its (M,) temporaries.
    Rows 2: of res and J are left unset for the caller (polar's view-angle row), so a
    k-row residual needs no second copy. K (M, 6) fx, fy, cx, cy, k1, k2; obs_uv (M, 2)."""
    M = len(Xc)
    res = np.empty((M, k))
    J = np.empty((M if jac else 0, k, 3))
    for m in range(M):
        _put2(res, m, J, m, jac, _pixel(K, m, Xc[m, 0], Xc[m, 1], Xc[m, 2], obs_uv, jac))
    return res, J


@_njit
def theta_row_into(Xc, theta_obs, w_theta, res, J, jac):
    """Polar's weighted view-angle row ``(theta - theta_obs) w_theta`` into row 2 of res
    (M, 3) and, with jac, its ``res_D_Xc`` into row 2 of J (M, 3, 3), in place (rows 0:2
    from :func:`pixel_rows`): the same values as polar.py's numpy view-angle row."""
    for m in range(len(Xc)):
        th, t0, t1, t2 = _theta(Xc[m, 0], Xc[m, 1], Xc[m, 2], jac)
        w = w_theta[m]
        res[m, 2] = (th - theta_obs[m]) * w
        if jac:
            J[m, 2, 0], J[m, 2, 1], J[m, 2, 2] = t0 * w, t1 * w, t2 * w


@_njit
def angular_rows(Xc, a_obs, cs, whiten, w_theta, mode, jac):
    """Angular residuals (M, 2) and with jac ``res_D_Xc`` (M, 2, 3) (angular.py), per
    ``mode`` (M,) (:func:`_angle_rows`, :func:`_chart_row`); angles of the projective ray
    (angular_obs.py)."""
    M = len(Xc)
    res = np.empty((M, 2))
    J = np.empty((M if jac else 0, 2, 3))
    # the chart's rows apart, as in angular_obs, and the rows whose offsets need arctan2 in a
    # last pass (no call in the main loop: 4.5 -> 0.7 ms on a real local BA's 70k rows)
    redo = np.empty(M, np.int64)
    n_redo = 0
    for chart in (False, True):
        for m in range(M):
            if (mode[m] == CHART) != chart:
                continue
            x, y, z = Xc[m, 0], Xc[m, 1], Xc[m, 2]
            if chart:
                row = _chart_row(x, y, z, m, a_obs, whiten, jac)
            else:
                ok, row = _angle_rows(x, y, z, m, a_obs, cs, whiten, w_theta, mode, jac, False)
                if not ok:
                    redo[n_redo] = m
                    n_redo += 1
            _put2(res, m, J, m, jac, row)
    for k in range(n_redo):
        m = redo[k]
        row = _angle_rows(Xc[m, 0], Xc[m, 1], Xc[m, 2], m, a_obs, cs, whiten, w_theta, mode,
                          False, True)[1]
        res[m, 0], res[m, 1] = row[0], row[1]
    return res, J


# ---- set-up of the parallax forms ----

@_njit
def best_associates(obs_cam, obs_pt, C, X):
    """The observation (P,) of each point whose ray makes the largest ``sin`` of the parallax
    angle with the main anchor's (the point's first observation's camera), as parallax.py's
    ``choose_anchors`` picks it, in one pass over the observations (sorted by point); a point
    seen from the main centre only gets its first observation (omega -1 there). The largest
    ``sin(arccos(c))`` is the smallest ``|c|``: no arccos and sin per observation (a quarter of
    the polar form's set-up in captured mapper BAs); the two orders differ only where sin's
    rounding makes two distinct cosines tie."""
    P = len(X)
    best = np.empty(P, np.int64)
    top = np.full(P, 3.0)
    prev, mc, nm = -1, 0, 0.0
    for m in range(len(obs_cam)):
        p, c = obs_pt[m], obs_cam[m]
        new_point = p != prev
        if new_point:
            prev, mc = p, c
        rm0, rm1, rm2 = X[p, 0] - C[mc, 0], X[p, 1] - C[mc, 1], X[p, 2] - C[mc, 2]
        if new_point:  # the main ray's length, once per point
            nm = np.sqrt(rm0 * rm0 + rm1 * rm1 + rm2 * rm2)
        ri0, ri1, ri2 = X[p, 0] - C[c, 0], X[p, 1] - C[c, 1], X[p, 2] - C[c, 2]
        den = max(nm * np.sqrt(ri0 * ri0 + ri1 * ri1 + ri2 * ri2), 1e-300)
        cosang = min(max((rm0 * ri0 + rm1 * ri1 + rm2 * ri2) / den, -1.0), 1.0)
        b0, b1, b2 = C[c, 0] - C[mc, 0], C[c, 1] - C[mc, 1], C[c, 2] - C[mc, 2]
        key = abs(cosang) if b0 * b0 + b1 * b1 + b2 * b2 > 0 else 2.0
        if key < top[p]:  # strict: the first of equal scores, as the reference's stable sort
            top[p], best[p] = key, m
    return best


@_njit
def pinhole_view_angles(K, obs_uv):
    """Normalized radius ``rd = tan theta`` (M,) of each observed pixel, the view angle's weight
    ``1 / |theta_D_uv|`` (M,) and ``(cos, sin)`` of theta (M, 2) for pinhole rows of K (M, 6)
    (k1 = k2 = 0; the caller checks): the arithmetic of ``Camera.view_angle_with_gradient`` for
    that model in one pass (numpy's was half of the polar form's set-up per mapper BA), cos
    and sin from ``tan theta`` (no trigonometry). theta itself is ``np.arctan(rd)``: numpy's
    vectorized arctan is ten times this loop's scalar one. Where numpy gives NaN (the
    principal point, non-finite pixels) the weight is NaN; the count of such rows is returned
    too."""
    M = len(K)
    rds, w = np.empty(M), np.empty(M)
    cs = np.empty((M, 2))
    bad = 0
    fx = fy = ifx = ify = np.nan
    for m in range(M):
        if K[m, 0] != fx or K[m, 1] != fy:  # rows of one camera: two divisions per camera
            fx, fy = K[m, 0], K[m, 1]
            ifx, ify = 1.0 / fx, 1.0 / fy
        x = (obs_uv[m, 0] - K[m, 2]) * ifx
        y = (obs_uv[m, 1] - K[m, 3]) * ify
        rd2 = x * x + y * y
        rd = np.sqrt(rd2)
        # |theta_D_uv| = |(x / fx, y / fy)| / (rd (1 + rd^2))
        e0, e1 = x * ifx, y * ify
        wm = (1.0 + rd2) * rd / np.sqrt(e0 * e0 + e1 * e1)
        if not (np.isfinite(wm) and wm > 0.0):  # the principal point: 0 / 0
            wm = np.nan
            bad += 1
        rds[m], w[m] = rd, wm
        c = 1.0 / np.sqrt(1.0 + rd2)
        cs[m, 0], cs[m, 1] = c, rd * c
    return rds, w, cs, bad
