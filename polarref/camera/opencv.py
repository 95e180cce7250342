"""COLMAP's OPENCV model (fx, fy, cx, cy, k1, k2, p1, p2): radial plus tangential distortion.

In normalized undistorted coordinates ``(x, y) = (X, Y) / Z``, with ``r2 = x^2 + y^2``::

    xd = x (1 + k1 r2 + k2 r2^2) + 2 p1 x y + p2 (r2 + 2 x^2)
    yd = y (1 + k1 r2 + k2 r2^2) + p1 (r2 + 2 y^2) + 2 p2 x y

and ``(u, v) = (fx xd + cx, fy yd + cy)``. The tangential terms break the radial symmetry of the
other models (:mod:`polarref.camera.radial`): the pixel's angle about the principal point is no
longer the ray's azimuth phi, so every angular conversion goes through the undistorted point.

Valid field of view: the largest disc ``r < ru_lim`` around the axis on which the distortion
map's Jacobian determinant stays positive (so it is locally invertible there). With p1 = p2 = 0
it is the fold of the radial polynomial, exactly as for RADIAL. Rays beyond it are masked (NaN),
as polarref does for every model past its fold; COLMAP projects them anyway.

Undistortion is Newton's method like COLMAP's ``IterativeUndistortion``, but with the analytic
Jacobian, a start at the radial-only inverse, step halving, and iteration to rounding level
(COLMAP uses a numeric Jacobian and stops once the step is below 1e-5).
"""

from __future__ import annotations

import numpy as np

from polarref.camera.radial import odd_poly_inverse, odd_poly_limit

Array = np.ndarray
_ERR = dict(invalid="ignore", divide="ignore", over="ignore")


def distort(x: Array, y: Array, coeffs) -> tuple[Array, Array, Array]:
    """``(xd, yd, xd_D_x)``: the distorted normalized point and its (..., 2, 2) Jacobian."""
    k1, k2, p1, p2 = coeffs
    with np.errstate(**_ERR):
        x2, y2, xy = x * x, y * y, x * y
        r2 = x2 + y2
        radial = 1.0 + r2 * (k1 + k2 * r2)
        a = 2.0 * (k1 + 2.0 * k2 * r2)  # 2 d radial / d r2
        xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2)
        yd = y * radial + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy
        jxy = a * xy + 2.0 * p1 * x + 2.0 * p2 * y
        J = np.stack([np.stack([radial + a * x2 + 2.0 * p1 * y + 6.0 * p2 * x, jxy], -1),
                      np.stack([jxy, radial + a * y2 + 6.0 * p1 * y + 2.0 * p2 * x], -1)], -2)
    return xd, yd, J


def distort_D_coeffs(x: Array, y: Array) -> Array:
    """``(xd, yd)_D_(k1, k2, p1, p2)`` (..., 2, 4); it does not depend on the coefficients."""
    x2, y2, xy = x * x, y * y, x * y
    r2 = x2 + y2
    return np.stack([np.stack([x * r2, x * r2 * r2, 2.0 * xy, r2 + 2.0 * x2], -1),
                     np.stack([y * r2, y * r2 * r2, r2 + 2.0 * y2, 2.0 * xy], -1)], -2)


def _det(r: Array, alpha: Array, coeffs) -> Array:
    """det of :func:`distort`'s Jacobian at ``r (cos alpha, sin alpha)`` (no stacked arrays:
    this is the hot part of every OPENCV camera's construction)."""
    k1, k2, p1, p2 = coeffs
    x, y = r * np.cos(alpha), r * np.sin(alpha)
    r2 = r * r
    radial = 1.0 + r2 * (k1 + k2 * r2)
    a = 2.0 * (k1 + 2.0 * k2 * r2)
    jxy = a * x * y + 2.0 * p1 * x + 2.0 * p2 * y
    return ((radial + a * x * x + 2.0 * p1 * y + 6.0 * p2 * x)
            * (radial + a * y * y + 6.0 * p1 * y + 2.0 * p2 * x) - jxy * jxy)


def _first_fold(alpha: Array, coeffs, grid: Array) -> Array:
    """For each azimuth (A,), the smallest radius where det <= 0 (inf if none on the grid)."""
    with np.errstate(**_ERR):
        ok = _det(grid[None, :], alpha[:, None], coeffs) > 0
    bad = ~ok
    first = np.where(bad.any(1), bad.argmax(1), -1)
    out = np.full(len(alpha), np.inf)
    sel = np.flatnonzero(first > 0)
    lo, hi = grid[first[sel] - 1], grid[first[sel]]
    a = alpha[sel]
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        with np.errstate(**_ERR):
            pos = _det(mid, a, coeffs) > 0
        lo, hi = np.where(pos, mid, lo), np.where(pos, hi, mid)
    out[sel] = lo
    return out


def fold_radius(coeffs) -> float:
    """``ru_lim``: radius of the largest disc (undistorted normalized) with det > 0; inf if none.

    Azimuths are scanned on a 128-point grid and the worst one is refined on a 64-point grid
    around it; the fold radius is smooth in the azimuth, so this finds its minimum to ~1e-7.
    """
    k1, k2, p1, p2 = (float(c) for c in coeffs)
    if p1 == 0.0 and p2 == 0.0:  # radially symmetric: the RADIAL model's fold, bit for bit
        return odd_poly_limit((k1, k2))
    grid = np.tan(np.linspace(0.0, np.pi / 2, 2049)[:-1])
    alpha = np.linspace(-np.pi, np.pi, 128, endpoint=False)
    rho = _first_fold(alpha, coeffs, grid)
    if not np.isfinite(rho).any():
        return float("inf")
    best, step = alpha[int(np.argmin(rho))], 2 * np.pi / 128
    fine = _first_fold(np.linspace(best - step, best + step, 65), coeffs, grid)
    return float(min(rho.min(), fine.min()))


def undistort(xd: Array, yd: Array, coeffs, ru_lim: float) -> tuple[Array, Array, Array]:
    """``(x, y, xd_D_x)`` with ``distort(x, y) = (xd, yd)`` and ``x^2 + y^2 < ru_lim^2``;
    NaN where no such point is found (pixels beyond the reachable part of the image)."""
    k1, k2 = float(coeffs[0]), float(coeffs[1])
    xd, yd = np.broadcast_arrays(np.asarray(xd, np.float64), np.asarray(yd, np.float64))
    lim2 = ru_lim * ru_lim
    with np.errstate(**_ERR):
        rd = np.hypot(xd, yd)
        # start on the radial-only inverse: exact when p1 = p2 = 0, close when they are small
        ru0 = odd_poly_inverse(rd, (k1, k2), min(odd_poly_limit((k1, k2)), ru_lim))
        s = np.where(rd > 0, ru0 / np.where(rd > 0, rd, 1.0), 1.0)
        s = np.where(np.isfinite(s), s, 0.0)
        x, y = xd * s, yd * s
        scale = np.maximum(1.0, rd)

        def resid(x, y):
            ex, ey, J = distort(x, y, coeffs)
            f = np.hypot(ex - xd, ey - yd)
            return ex - xd, ey - yd, J, np.where(x * x + y * y < lim2, f, np.inf)

        fx, fy, J, f = resid(x, y)
        for _ in range(100):
            det = J[..., 0, 0] * J[..., 1, 1] - J[..., 0, 1] * J[..., 1, 0]
            sx = (J[..., 1, 1] * fx - J[..., 0, 1] * fy) / det
            sy = (J[..., 0, 0] * fy - J[..., 1, 0] * fx) / det
            sx, sy = np.nan_to_num(sx), np.nan_to_num(sy)
            t = np.ones_like(x)
            nx, ny = x - sx, y - sy
            gx, gy, gJ, g = resid(nx, ny)
            for _ in range(40):  # halve the step where it does not reduce the residual
                worse = ~(g < f) & (g > 0)
                if not worse.any():
                    break
                t = np.where(worse, 0.5 * t, t)
                nx, ny = np.where(worse, x - t * sx, nx), np.where(worse, y - t * sy, ny)
                hx, hy, hJ, h = resid(nx, ny)
                gx, gy = np.where(worse, hx, gx), np.where(worse, hy, gy)
                gJ, g = np.where(worse[..., None, None], hJ, gJ), np.where(worse, h, g)
            take = g <= f
            small = np.hypot(t * sx, t * sy) <= 1e-16 * np.maximum(np.hypot(x, y), 1e-300)
            x, y = np.where(take, nx, x), np.where(take, ny, y)
            fx, fy = np.where(take, gx, fx), np.where(take, gy, fy)
            J, f = np.where(take[..., None, None], gJ, J), np.where(take, g, f)
            if np.all(small | ~take | (f == 0)):
                break
        valid = (f <= 1e-11 * scale) & (x * x + y * y < lim2)
    nan = np.full_like(x, np.nan)
    return (np.where(valid, x, nan), np.where(valid, y, nan),
            np.where(valid[..., None, None], J, np.nan))


# ---- the Camera methods for this model (called from polarref.camera.core) -------------------
# Each returns (value, jacobian, valid) like core's private helpers; core masks and raises.

def _normalized(cam, X: Array) -> tuple[Array, Array, Array, Array]:
    """1/Z, the normalized coordinates x, y, and the mask: in front and inside the valid disc."""
    Z = X[..., 2]
    valid = Z > 0
    iz = 1.0 / np.where(valid, Z, 1.0)
    x, y = X[..., 0] * iz, X[..., 1] * iz
    return iz, x, y, valid & (x * x + y * y < cam._ru_lim ** 2)


def project(cam, X: Array):
    """Pixels, ``uv_D_Xcam`` (..., 2, 3) and the valid mask."""
    with np.errstate(**_ERR):
        iz, x, y, valid = _normalized(cam, X)
        xd, yd, Jd = distort(x, y, cam.distortion)
        zero = np.zeros_like(x)
        dxy = np.stack([np.stack([iz, zero, -x * iz], -1),
                        np.stack([zero, iz, -y * iz], -1)], -2)
        J = np.diag([cam.fx, cam.fy]) @ Jd @ dxy
    return cam._pixel(xd, yd), J, valid


def params_jacobian(cam, X: Array) -> tuple[Array, Array]:
    """``uv_D_params`` (..., 2, 8) and the valid mask."""
    with np.errstate(**_ERR):
        iz, x, y, valid = _normalized(cam, X)
        xd, yd, _ = distort(x, y, cam.distortion)
        J = np.zeros(X.shape[:-1] + (2, 8))
        J[..., 0, 0], J[..., 1, 1] = xd, yd
        J[..., 0, 2] = J[..., 1, 3] = 1.0
        J[..., 4:] = distort_D_coeffs(x, y) * np.array([cam.fx, cam.fy])[:, None]
    return J, valid


def _undistorted(cam, uv: Array):
    x, y = cam._normalized(uv)
    return undistort(x, y, cam.distortion, cam._ru_lim)


def _inv2(J: Array) -> Array:
    det = J[..., 0, 0] * J[..., 1, 1] - J[..., 0, 1] * J[..., 1, 0]
    return np.stack([np.stack([J[..., 1, 1], -J[..., 0, 1]], -1),
                     np.stack([-J[..., 1, 0], J[..., 0, 0]], -1)], -2) / det[..., None, None]


def to_angular(cam, uv: Array):
    """``(theta, phi)`` (..., 2), ``angular_D_uv`` (..., 2, 2), valid mask."""
    x, y, Jd = _undistorted(cam, uv)
    with np.errstate(**_ERR):
        rho2 = x * x + y * y
        rho = np.sqrt(rho2)
        ang = np.stack([np.arctan(rho), np.arctan2(y + 0.0, x)], -1)
        a = 1.0 / (rho * (1.0 + rho2))
        Ja = np.stack([np.stack([x * a, y * a], -1), np.stack([-y / rho2, x / rho2], -1)], -2)
        J = Ja @ _inv2(Jd) / np.array([cam.fx, cam.fy])
        J = np.where((rho > 0)[..., None, None], J, np.nan)
    return ang, J, np.isfinite(x)


def from_angular(cam, theta: Array, phi: Array):
    """Pixels (..., 2), ``uv_D_angular`` (..., 2, 2), valid mask."""
    with np.errstate(**_ERR):
        valid = (theta >= 0) & (theta < cam.theta_max) & np.isfinite(phi)
        rho = np.tan(np.where(valid, theta, 0.0))
        c, s = np.cos(phi), np.sin(phi)
        xd, yd, Jd = distort(rho * c, rho * s, cam.distortion)
        sec2 = 1.0 + rho * rho
        dxy = np.stack([np.stack([sec2 * c, -rho * s], -1), np.stack([sec2 * s, rho * c], -1)], -2)
        J = np.diag([cam.fx, cam.fy]) @ Jd @ dxy
    return cam._pixel(xd, yd), J, valid


def unproject(cam, uv: Array):
    """Unit rays (..., 3), ``ray_D_uv`` (..., 3, 2), valid mask."""
    x, y, Jd = _undistorted(cam, uv)
    with np.errstate(**_ERR):
        n = np.sqrt(1.0 + x * x + y * y)
        ray = np.stack([x, y, np.ones_like(x)], -1) / n[..., None]
        # d ray / d(x, y) = (I - ray ray^T) [e1 e2] / n
        P = (np.eye(3)[..., :2] - ray[..., :, None] * ray[..., None, :2]) / n[..., None, None]
        J = P @ _inv2(Jd) / np.array([cam.fx, cam.fy])
    return ray, J, np.isfinite(x)
