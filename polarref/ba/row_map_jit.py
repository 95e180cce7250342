"""numba kernels of the polar form's mapped view-angle row (row_map.py); reached through
:mod:`polarref.ba.kernels` like forms_jit.py's."""

from __future__ import annotations

import numba
import numpy as np

from polarref.ba.forms_jit import _atan_ratio, _parallax_chain, _parallax_ray, _pixel, _put2


def _njit(fn):
    return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _normalized(x, y, z):
    """(n_x, n_y, |n|^2) of the ray: forms_jit._pixel's operations, so that the compiler
    shares them with the pixel rows."""
    iz = 1.0 / z
    nx, ny = x * iz, y * iz
    return nx, ny, nx * nx + ny * ny


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _view_angle_offset(rn, theta_obs, c, s):
    """``theta - theta_obs`` with ``theta = atan(rn)`` the view angle of a ray whose normalized
    image radius is rn (>= 0; the projective ray's, as angular_obs.theta_rows: n is the same
    for Xc and -Xc). With ``(c, s) = (cos, sin)(theta_obs)`` the offset is ``atan(t)``, ``t =
    (rn c - s) / (c + rn s)``, by forms_jit._atan_ratio's series where it applies (no arctan
    call: it was 30 % of the evaluation's time), else by arctan."""
    ok, v = _atan_ratio(rn * c - s, c + rn * s)
    if ok:
        return v
    return np.arctan(rn) - theta_obs


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _mapped_row(K, m, x, y, z, obs_uv, theta_obs, cs_obs, w_theta, res, J, mj, G):
    """Observation m's three residuals into res[m], its pixel rows' ``res_D_Xc`` into J[mj]
    and its row map into G[m] (see :func:`polar_rows_mapped`).

    The map in closed form: with normalized ``n = (x, y) / z``, ``P = diag(f) D N`` where
    ``D = dist I + a n n^T`` (the radial distortion's Jacobian, forms_jit._pixel's ``dist``
    and ``a``) and ``t = theta_D_n N`` with ``theta_D_n = n / (|n| (1 + |n|^2))``. ``g^T P =
    w t`` then reads ``diag(f) D g = w theta_D_n``, and as ``theta_D_n`` is parallel to n,
    ``D n = (dist + a |n|^2) n``: ``g = w (n_x / f_x, n_y / f_y) / (|n| (1 + |n|^2)
    (dist + a |n|^2))``, one division instead of a 2 x 2 solve."""
    _put2(res, m, J, mj, True, _pixel(K, m, x, y, z, obs_uv, True))
    nx, ny, r2 = _normalized(x, y, z)
    rn = np.sqrt(r2)
    w = w_theta[m]
    res[m, 2] = _view_angle_offset(rn, theta_obs[m], cs_obs[m, 0], cs_obs[m, 1]) * w
    fx, fy, k1, k2 = K[m, 0], K[m, 1], K[m, 4], K[m, 5]
    dist = 1.0 + r2 * (k1 + k2 * r2)
    a = 2.0 * (k1 + 2.0 * k2 * r2)
    # on the axis theta is a cone: n = 0 gives g = 0 (any subgradient will do)
    q = w / (max(rn, 1e-300) * (1.0 + r2) * (dist + a * r2) * fx * fy)
    G[m, 0] = q * nx * fy
    G[m, 1] = q * ny * fx


@_njit
def polar_rows_mapped(Xc, K, obs_uv, theta_obs, cs_obs, w_theta):
    """Polar's residuals (M, 3) (pixel rows, bitwise forms_jit.pixel_rows, then the weighted
    view-angle row, forms_jit.theta_row_into's to rounding: :func:`_view_angle_offset`), the
    pixel rows' ``res_D_Xc`` (M, 2, 3) and the row map G (M, 2): the view-angle row's
    ``res_D_Xc`` is ``G[m] @ J[m]``. Xc (M, 3), K (M, 6), cs_obs (M, 2) cos, sin of theta_obs.
    The solver reads these through :func:`polar_obs_mapped`; the tests check that fused pass
    against this stage and against the explicit rows."""
    M = len(Xc)
    res = np.empty((M, 3))
    J = np.empty((M, 2, 3))
    G = np.empty((M, 2))
    for m in range(M):
        _mapped_row(K, m, Xc[m, 0], Xc[m, 1], Xc[m, 2], obs_uv, theta_obs, cs_obs, w_theta, res,
                    J, m, G)
    return res, J, G


@_njit
def polar_residuals_mapped(Xc, K, obs_uv, theta_obs, cs_obs, w_theta):
    """The residuals (M, 3) of :func:`polar_rows_mapped` alone, bitwise (a trial step's cost)."""
    M = len(Xc)
    res = np.empty((M, 3))
    J = np.empty((0, 2, 3))
    for m in range(M):
        x, y, z = Xc[m, 0], Xc[m, 1], Xc[m, 2]
        _put2(res, m, J, 0, False, _pixel(K, m, x, y, z, obs_uv, False))
        r2 = _normalized(x, y, z)[2]
        res[m, 2] = _view_angle_offset(np.sqrt(r2), theta_obs[m], cs_obs[m, 0],
                                       cs_obs[m, 1]) * w_theta[m]
    return res


@_njit
def polar_obs_mapped(R, C, obs_cam, obs_pt, Cm, d, sw, cw, hd, dh_dw, dv_dab, K, obs_uv,
                     theta_obs, cs_obs, w_theta):
    """Polar's factored, mapped evaluation in one pass (forms_jit.parallax_rays,
    :func:`polar_rows_mapped` and forms_jit.parallax_jacobians with two rows fused): residuals
    (M, 3), ``res_D_point`` (M, 2, 3), ``res_D_obs`` (M, 2, 6), ``A d`` (M, 2) and the row map
    (M, 2). Per-point terms from forms_jit.parallax_points."""
    M = len(obs_cam)
    res, G = np.empty((M, 3)), np.empty((M, 2))
    Jp, Jo, Ad = np.empty((M, 2, 3)), np.empty((M, 2, 6)), np.empty((M, 2))
    jx = np.empty((1, 2, 3))  # the pixel rows' res_D_Xc of the current observation
    for m in range(M):
        i, p = obs_cam[m], obs_pt[m]
        x, y, z = _parallax_ray(R, C, i, p, Cm, sw, hd)
        _mapped_row(K, m, x, y, z, obs_uv, theta_obs, cs_obs, w_theta, res, jx, 0, G)
        _parallax_chain(jx, 0, 2, x, y, z, R, C, i, p, Cm, d, sw, cw, dh_dw, dv_dab, Jp, Jo,
                        Ad, m)
    return res, Jp, Jo, Ad, G


@_njit
def whiten_mapped(r, w, G, Jp, Jo, Ad, out):
    """The two whitened rows ``L^-1 c`` into out (M, 2) and ``L^T J`` in place on Jp (M, 2, 3),
    Jo (M, 2, 6), Ad (M, 2), with ``L L^T = w0^2 I + w2^2 g g^T`` and ``c = w0^2 r_uv + w2^2
    r_theta g`` (row_map.py). r (M, 3) unweighted; w (M, 3) robust row weights, or 0 rows
    for none; G (M, 2)."""
    weighted = len(w) > 0
    for m in range(len(r)):
        a1, a2 = 1.0, 1.0
        if weighted:
            a1, a2 = w[m, 0] * w[m, 0], w[m, 2] * w[m, 2]
        g0, g1 = G[m, 0], G[m, 1]
        m00 = a1 + a2 * g0 * g0
        m01 = a2 * g0 * g1
        m11 = a1 + a2 * g1 * g1
        c0 = a1 * r[m, 0] + a2 * g0 * r[m, 2]
        c1 = a1 * r[m, 1] + a2 * g1 * r[m, 2]
        l00 = np.sqrt(m00)
        l10 = m01 / l00 if l00 > 0.0 else 0.0
        l11 = np.sqrt(max(m11 - l10 * l10, 0.0))
        y0 = c0 / l00 if l00 > 0.0 else 0.0
        out[m, 0] = y0
        out[m, 1] = (c1 - l10 * y0) / l11 if l11 > 0.0 else 0.0
        for j in range(3):
            u, v = Jp[m, 0, j], Jp[m, 1, j]
            Jp[m, 0, j], Jp[m, 1, j] = l00 * u + l10 * v, l11 * v
        for j in range(6):
            u, v = Jo[m, 0, j], Jo[m, 1, j]
            Jo[m, 0, j], Jo[m, 1, j] = l00 * u + l10 * v, l11 * v
        u, v = Ad[m, 0], Ad[m, 1]
        Ad[m, 0], Ad[m, 1] = l00 * u + l10 * v, l11 * v


def warm_up() -> None:
    """Compile (or load from the disk cache) these kernels on tiny inputs (kernels.warm_up)."""
    f = np.zeros
    x3 = np.array([[0.1, 0.2, 1.0]])
    K = np.array([[1.0, 1.0, 0.0, 0.0, 0.0, 0.0]])
    cs = np.array([[1.0, 0.0]])
    res, J, G = polar_rows_mapped(x3, K, f((1, 2)), f(1), cs, np.ones(1))
    polar_residuals_mapped(x3, K, f((1, 2)), f(1), cs, np.ones(1))
    one, x1, R = np.zeros(1, np.int64), np.ones(1), np.eye(3)[None].copy()
    polar_obs_mapped(R, x3, one, one, x3, x3, x1, x1, x3, x1, f((1, 3, 2)), K, f((1, 2)), f(1), cs,
                     x1)
    for w in (f((0, 3)), np.ones((1, 3))):
        whiten_mapped(res, w, G, J.copy(), f((1, 2, 6)), f((1, 2)), f((1, 2)))
