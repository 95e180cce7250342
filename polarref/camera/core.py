"""The ``Camera`` type: projection, unprojection and angular (theta, phi) pixel coordinates.

Conventions (binding for polarref):

* Pixels follow COLMAP: origin at the top-left corner of the first pixel (its centre is
  (0.5, 0.5)), u to the right, v down. Camera frame: +x right, +y down, +z = principal axis.
* ``theta`` is the angle between the ray and +z, in ``[0, theta_max)``.
* ``phi`` is the ray's azimuth about the principal axis, measured from image +x (right) toward
  image +y (down), in ``(-pi, pi]``: ``phi = atan2((v - cy) / fy, (u - cx) / fx)``, which is the
  plain pixel angle ``atan2(v - cy, u - cx)`` when fx == fy. So a camera-frame ray is
  ``(sin theta cos phi, sin theta sin phi, cos theta)`` for every model, and (theta, phi) do not
  depend on the intrinsics. phi is always the *ray's* azimuth: for OPENCV, whose tangential
  distortion is not radially symmetric, it differs from the pixel angle formula above. At the principal point phi is undefined; it is reported as 0 and its
  Jacobian row as NaN.
* Invalid input (a ray at or beyond the model's ``theta_max``, a zero vector, a pixel beyond
  the image radius the model can reach) gives NaN in the value and its Jacobian; pass
  ``strict=True`` to raise ValueError instead.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from polarref.core.angular import last_axis as _last
from polarref.core.angular import ray_angles
from polarref.camera import opencv
from polarref.camera.models import MODELS, ModelSpec, radial_map
from polarref.camera.radial import RadialMap

Array = np.ndarray
_ERR = dict(invalid="ignore", divide="ignore", over="ignore")


def _masked(out: Array, valid: Array, strict: bool, what: str) -> Array:
    """Put NaN into rows where ``valid`` is False (or raise when strict)."""
    if strict and not np.all(valid):
        bad = np.argwhere(~np.asarray(valid))
        raise ValueError(f"{what}: {len(bad)} input(s) outside the model's valid range, "
                         f"first at index {tuple(int(i) for i in bad[0])}")
    extra = out.ndim - np.ndim(valid)
    return np.where(np.reshape(valid, np.shape(valid) + (1,) * extra), out, np.nan)


@dataclass(frozen=True, eq=False)
class Camera:
    """An intrinsic camera model (see :mod:`polarref.camera.models` for the model table).

    Attributes:
        model: model name, e.g. ``"PINHOLE"``, ``"OPENCV_FISHEYE"``, ``"STEREOGRAPHIC"``.
        width: image width in pixels (> 0).
        height: image height in pixels (> 0).
        params: (P,) float64 parameters in the model's order; stored as a read-only copy.

    Raises:
        ValueError: unknown model, wrong parameter count, non-finite parameters, focal <= 0,
            width or height <= 0.
    """

    model: str
    width: int
    height: int
    params: np.ndarray
    _spec: ModelSpec = field(init=False, repr=False, compare=False)
    _radial: RadialMap = field(init=False, repr=False, compare=False)
    _theta_max: float = field(init=False, repr=False, compare=False)
    _ru_lim: float = field(init=False, repr=False, compare=False)  # OPENCV's valid disc

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"unknown camera model {self.model!r}; known: {', '.join(MODELS)}")
        spec = MODELS[self.model]
        for name in ("width", "height"):
            val = getattr(self, name)
            if int(val) != val or int(val) <= 0:
                raise ValueError(f"camera {name} must be a positive integer, got {val!r}")
            object.__setattr__(self, name, int(val))
        params = np.array(self.params, dtype=np.float64).reshape(-1)
        if params.size != len(spec.names):
            raise ValueError(f"{self.model} takes {len(spec.names)} params "
                             f"({', '.join(spec.names)}), got {params.size}")
        if not np.all(np.isfinite(params)):
            raise ValueError(f"{self.model} params must be finite, got {params.tolist()}")
        if params[spec.fx] <= 0 or params[spec.fy] <= 0:
            raise ValueError(f"{self.model} focal length must be > 0, got {params.tolist()}")
        params.setflags(write=False)
        object.__setattr__(self, "params", params)
        object.__setattr__(self, "_spec", spec)
        radial = radial_map(spec, params)
        object.__setattr__(self, "_radial", radial)
        object.__setattr__(self, "_theta_max", radial.theta_max)
        if spec.kind == "opencv":
            ru_lim = opencv.fold_radius(params[list(spec.extra)])
            object.__setattr__(self, "_ru_lim", ru_lim)
            object.__setattr__(self, "_theta_max", float(np.arctan(ru_lim)))

    # ---- identity ------------------------------------------------------------------------
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        return (self.model, self.width, self.height) == (other.model, other.width, other.height) \
            and np.array_equal(self.params, other.params)

    def __hash__(self) -> int:
        return hash((self.model, self.width, self.height, tuple(self.params.tolist())))

    def __repr__(self) -> str:
        vals = ", ".join(f"{n}={v:.6g}" for n, v in zip(self._spec.names, self.params))
        return f"Camera({self.model}, {self.width}x{self.height}, {vals})"

    # ---- parameters ------------------------------------------------------------------------
    @property
    def param_names(self) -> tuple[str, ...]:
        return self._spec.names

    @property
    def fx(self) -> float:
        return float(self.params[self._spec.fx])

    @property
    def fy(self) -> float:
        return float(self.params[self._spec.fy])

    @property
    def principal_point(self) -> Array:
        """(2,) (cx, cy) in pixels."""
        return np.array([self.params[self._spec.cx], self.params[self._spec.cy]])

    @property
    def distortion(self) -> tuple[float, ...]:
        """The model's distortion coefficients (empty for distortion-free models)."""
        if self._spec.kind == "opencv":
            return tuple(float(self.params[i]) for i in self._spec.extra)
        return self._radial.coeffs

    @property
    def theta_max(self) -> float:
        """Exclusive upper bound of the valid ray angle from the principal axis [rad]."""
        return self._theta_max

    @property
    def is_perspective(self) -> bool:
        """True for models whose rays are mapped through ``tan(theta)`` (z must be > 0)."""
        return self._spec.kind in ("perspective", "opencv")

    def calibration_matrix(self) -> Array:
        """(3, 3) ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.

        For distortion-free perspective models K maps camera points to pixels; for the other
        models it maps normalized *distorted* coordinates ``R(theta) (cos phi, sin phi)`` to pixels.
        """
        cx, cy = self.principal_point
        return np.array([[self.fx, 0.0, cx], [0.0, self.fy, cy], [0.0, 0.0, 1.0]])

    def rescaled(self, scale: float) -> "Camera":
        """The same camera for an image resized by ``scale`` (exact in COLMAP's pixel convention)."""
        if not scale > 0:
            raise ValueError(f"scale must be > 0, got {scale}")
        params = self.params.copy()
        for i in (self._spec.fx, self._spec.fy, self._spec.cx, self._spec.cy):
            params[i] = self.params[i] * scale
        return Camera(self.model, max(1, round(self.width * scale)),
                      max(1, round(self.height * scale)), params)

    # ---- projection ------------------------------------------------------------------------
    def project(self, X_cam, *, strict: bool = False) -> Array:
        """Camera-frame points (..., 3) -> pixels (..., 2); NaN outside the valid field of view."""
        return self.project_with_jacobian(X_cam, strict=strict)[0]

    def project_jacobian(self, X_cam, *, strict: bool = False) -> Array:
        """``uv_D_Xcam`` (..., 2, 3) of :meth:`project`."""
        return self.project_with_jacobian(X_cam, strict=strict)[1]

    def project_with_jacobian(self, X_cam, *, strict: bool = False) -> tuple[Array, Array]:
        """Pixels (..., 2) and ``uv_D_Xcam`` (..., 2, 3) in one pass (the bundle adjuster's path)."""
        X = _last(X_cam, 3, "X_cam")
        if self._spec.kind == "opencv":
            uv, J, valid = opencv.project(self, X)
        elif self._spec.kind == "perspective":
            uv, J, valid = self._project_perspective(X)
        else:
            uv, J, valid = self._project_angle(X)
        return (_masked(uv, valid, strict, "Camera.project"),
                _masked(J, valid, strict, "Camera.project"))

    def project_params_jacobian(self, X_cam, *, strict: bool = False) -> Array:
        """``uv_D_params`` (..., 2, P) of :meth:`project` w.r.t. the model's parameters (in order).

        For refining intrinsics in a bundle adjuster; NaN outside the valid field of view.
        """
        X = _last(X_cam, 3, "X_cam")
        spec, coeffs = self._spec, self._radial.coeffs
        if spec.kind == "opencv":
            J, valid = opencv.params_jacobian(self, X)
            return _masked(J, valid, strict, "Camera.project")
        with np.errstate(**_ERR):
            if spec.kind == "perspective":
                Z = X[..., 2]
                iz = 1.0 / np.where(Z > 0, Z, 1.0)
                ex, ey = X[..., 0] * iz, X[..., 1] * iz  # undistorted normalized point
                r2 = ex * ex + ey * ey
                basis = [r2 ** (i + 1) for i in range(len(coeffs))]  # d radial / d k_i
                radial = 1.0 + sum(c * b for c, b in zip(coeffs, basis))
                xd, yd = ex * radial, ey * radial
            else:
                r = np.hypot(X[..., 0], X[..., 1])
                theta = np.arctan2(r, X[..., 2])
                R = self._radial.radius(theta)[0]
                on_axis = r == 0
                ex = np.where(on_axis, 0.0, X[..., 0] / np.where(on_axis, 1.0, r))  # unit azimuth
                ey = np.where(on_axis, 0.0, X[..., 1] / np.where(on_axis, 1.0, r))
                basis = [theta ** (2 * i + 3) for i in range(len(coeffs))]  # d R / d k_i
                xd, yd = R * ex, R * ey
            J = np.zeros(X.shape[:-1] + (2, len(spec.names)))
            J[..., 0, spec.fx] += xd
            J[..., 1, spec.fy] += yd
            J[..., 0, spec.cx] = 1.0
            J[..., 1, spec.cy] = 1.0
            for idx, b in zip(spec.extra, basis):
                J[..., 0, idx] = self.fx * ex * b
                J[..., 1, idx] = self.fy * ey * b
        valid = np.isfinite(self.project(X)[..., 0])
        return _masked(J, valid, strict, "Camera.project")

    def _pixel(self, xd: Array, yd: Array) -> Array:
        cx, cy = self.principal_point
        return np.stack([self.fx * xd + cx, self.fy * yd + cy], axis=-1)

    def _project_perspective(self, X: Array):
        coeffs = self._radial.coeffs
        ru_lim = self._radial.limit
        with np.errstate(**_ERR):
            Z = X[..., 2]
            valid = Z > 0
            iz = 1.0 / np.where(valid, Z, 1.0)
            x, y = X[..., 0] * iz, X[..., 1] * iz
            r2 = x * x + y * y
            valid &= r2 < ru_lim * ru_lim
            radial = np.ones_like(r2)
            dradial = np.zeros_like(r2)  # d radial / d r2
            power = np.ones_like(r2)
            for i, c in enumerate(coeffs, start=1):
                dradial = dradial + i * c * power
                power = power * r2
                radial = radial + c * power
            uv = self._pixel(x * radial, y * radial)
            # d(xd, yd)/d(x, y) = radial I + 2 dradial (x, y)^T (x, y)
            a = 2.0 * dradial
            dxd = np.stack([np.stack([radial + a * x * x, a * x * y], -1),
                            np.stack([a * x * y, radial + a * y * y], -1)], -2)
            zero = np.zeros_like(x)
            dxy = np.stack([np.stack([iz, zero, -x * iz], -1),
                            np.stack([zero, iz, -y * iz], -1)], -2)
            J = np.diag([self.fx, self.fy]) @ dxd @ dxy
        return uv, J, valid

    def _project_angle(self, X: Array):
        rm = self._radial
        with np.errstate(**_ERR):
            Xx, Xy, Z = X[..., 0], X[..., 1], X[..., 2]
            r = np.hypot(Xx, Xy)
            n = np.hypot(r, Z)
            theta = np.arctan2(r, Z)
            valid = (n > 0) & (theta < self._theta_max)
            R, dR = rm.radius(theta)
            s = np.sin(theta)
            on_axis = r == 0
            # k = R / r scales (X, Y) to the normalized image; on the axis its limit is R'(0)/n.
            k = np.where(on_axis, dR / n, R / np.where(on_axis, 1.0, r))
            # dk/dX = X w, dk/dY = Y w, dk/dZ = -R'/n^2, w = (R' sin cos - R) / (n^3 sin^3).
            # The numerator cancels for small theta, but w only enters multiplied by X^2 ~ n^2
            # sin^2 theta, so the absolute error stays at rounding level; exactly on the axis
            # the term vanishes.
            w = np.where(on_axis, 0.0,
                         (dR * s * np.cos(theta) - R) / (n**3 * np.where(on_axis, 1.0, s) ** 3))
            dkdz = -dR / (n * n)
            uv = self._pixel(k * Xx, k * Xy)
            dxd = np.stack([np.stack([k + Xx * Xx * w, Xx * Xy * w, Xx * dkdz], -1),
                            np.stack([Xy * Xx * w, k + Xy * Xy * w, Xy * dkdz], -1)], -2)
            J = np.array([[self.fx, 0.0], [0.0, self.fy]]) @ dxd
        return uv, J, valid

    # ---- angular pixel coordinates -----------------------------------------------------
    def _normalized(self, uv: Array) -> tuple[Array, Array]:
        cx, cy = self.principal_point
        return (uv[..., 0] - cx) / self.fx, (uv[..., 1] - cy) / self.fy

    def to_angular(self, uv, *, strict: bool = False) -> tuple[Array, Array]:
        """Pixels (..., 2) -> ``(theta, phi)``, each (...); NaN beyond the reachable radius."""
        ang, _ = self.to_angular_with_jacobian(uv, strict=strict)
        return ang[..., 0], ang[..., 1]

    def to_angular_jacobian(self, uv, *, strict: bool = False) -> Array:
        """``angular_D_uv`` (..., 2, 2): rows (theta, phi), columns (u, v); NaN at the principal point."""
        return self.to_angular_with_jacobian(uv, strict=strict)[1]

    def to_angular_with_jacobian(self, uv, *, strict: bool = False) -> tuple[Array, Array]:
        """``(theta, phi)`` stacked as (..., 2) and ``angular_D_uv`` (..., 2, 2)."""
        uv = _last(uv, 2, "uv")
        if self._spec.kind == "opencv":
            ang, J, valid = opencv.to_angular(self, uv)
            return _masked(ang, valid, strict, "Camera.to_angular"), \
                _masked(J, valid, strict, "Camera.to_angular")
        x, y = self._normalized(uv)
        with np.errstate(**_ERR):
            rd = np.hypot(x, y)
            theta, dtheta = self._radial.theta(rd)
            phi = np.arctan2(y + 0.0, x)
            valid = np.isfinite(theta)
            ird = 1.0 / rd
            J = np.stack([np.stack([dtheta * x * ird / self.fx, dtheta * y * ird / self.fy], -1),
                          np.stack([-y * ird * ird / self.fx, x * ird * ird / self.fy], -1)], -2)
            J = np.where((rd > 0)[..., None, None], J, np.nan)
        ang = np.stack([theta, phi], axis=-1)
        return _masked(ang, valid, strict, "Camera.to_angular"), \
            _masked(J, valid, strict, "Camera.to_angular")

    def view_angle_with_gradient(self, uv) -> tuple[Array, Array]:
        """``theta`` (...) and ``theta_D_uv`` (..., 2): the first row of
        :meth:`to_angular_with_jacobian` with the same arithmetic, without phi (the polar BA
        form reads only these, once per local BA of a mapper); NaN where that has NaN."""
        uv = _last(uv, 2, "uv")
        if self._spec.kind == "opencv":
            ang, J = self.to_angular_with_jacobian(uv)
            return ang[..., 0], J[..., 0, :]
        x, y = self._normalized(uv)
        with np.errstate(**_ERR):
            rd = np.hypot(x, y)
            theta, dtheta = self._radial.theta(rd)
            ird = 1.0 / rd
            g = np.stack([dtheta * x * ird / self.fx, dtheta * y * ird / self.fy], -1)
        valid = np.isfinite(theta)
        return (np.where(valid, theta, np.nan),
                np.where((valid & (rd > 0))[..., None], g, np.nan))

    def from_angular(self, theta, phi, *, strict: bool = False) -> Array:
        """``(theta, phi)`` (...) -> pixels (..., 2); NaN for theta outside ``[0, theta_max)``."""
        return self.from_angular_with_jacobian(theta, phi, strict=strict)[0]

    def from_angular_jacobian(self, theta, phi, *, strict: bool = False) -> Array:
        """``uv_D_angular`` (..., 2, 2): rows (u, v), columns (theta, phi)."""
        return self.from_angular_with_jacobian(theta, phi, strict=strict)[1]

    def from_angular_with_jacobian(self, theta, phi, *, strict: bool = False):
        theta, phi = np.broadcast_arrays(np.asarray(theta, dtype=np.float64),
                                         np.asarray(phi, dtype=np.float64))
        if self._spec.kind == "opencv":
            uv, J, valid = opencv.from_angular(self, theta, phi)
            return _masked(uv, valid, strict, "Camera.from_angular"), \
                _masked(J, valid, strict, "Camera.from_angular")
        with np.errstate(**_ERR):
            valid = (theta >= 0) & (theta < self._theta_max) & np.isfinite(phi)
            R, dR = self._radial.radius(np.where(valid, theta, 0.0))
            c, s = np.cos(phi), np.sin(phi)
            uv = self._pixel(R * c, R * s)
            J = np.stack([np.stack([self.fx * dR * c, -self.fx * R * s], -1),
                          np.stack([self.fy * dR * s, self.fy * R * c], -1)], -2)
        return _masked(uv, valid, strict, "Camera.from_angular"), \
            _masked(J, valid, strict, "Camera.from_angular")

    # ---- unprojection ----------------------------------------------------------------------
    def unproject(self, uv, *, strict: bool = False) -> Array:
        """Pixels (..., 2) -> unit camera-frame rays (..., 3); NaN beyond the reachable radius."""
        return self.unproject_with_jacobian(uv, strict=strict)[0]

    def unproject_jacobian(self, uv, *, strict: bool = False) -> Array:
        """``ray_D_uv`` (..., 3, 2) of :meth:`unproject`."""
        return self.unproject_with_jacobian(uv, strict=strict)[1]

    def unproject_with_jacobian(self, uv, *, strict: bool = False) -> tuple[Array, Array]:
        uv = _last(uv, 2, "uv")
        if self._spec.kind == "opencv":
            ray, J, valid = opencv.unproject(self, uv)
            return _masked(ray, valid, strict, "Camera.unproject"), \
                _masked(J, valid, strict, "Camera.unproject")
        x, y = self._normalized(uv)
        with np.errstate(**_ERR):
            rd = np.hypot(x, y)
            theta, dtheta = self._radial.theta(rd)
            valid = np.isfinite(theta)
            st, ct = np.sin(theta), np.cos(theta)
            centre = rd == 0
            safe = np.where(centre, 1.0, rd)
            sc = np.where(centre, dtheta, st / safe)  # sin(theta)/rd, limit theta'(0) at rd = 0
            # d sc/d rd / rd; cancellation error is harmless since it multiplies (x, y)(x, y)^T.
            g = np.where(centre, 0.0, (ct * dtheta * rd - st) / safe**3)
            ray = np.stack([sc * x, sc * y, ct], axis=-1)
            J = np.stack([np.stack([sc + g * x * x, g * x * y], -1),
                          np.stack([g * x * y, sc + g * y * y], -1),
                          np.stack([-sc * dtheta * x, -sc * dtheta * y], -1)], -2)
            J = J / np.array([self.fx, self.fy])
        return _masked(ray, valid, strict, "Camera.unproject"), \
            _masked(J, valid, strict, "Camera.unproject")

    # ---- pycolmap ------------------------------------------------------------------------
    @staticmethod
    def from_pycolmap(cam) -> "Camera":
        """Copy a ``pycolmap.Camera``; raises ValueError for models polarref does not implement."""
        name = cam.model.name if hasattr(cam.model, "name") else str(cam.model)
        if name not in MODELS:
            raise ValueError(f"pycolmap camera model {name} is not supported by polarref.camera")
        return Camera(name, int(cam.width), int(cam.height), np.array(cam.params, dtype=np.float64))

    def to_pycolmap(self, camera_id: int | None = None):
        """A ``pycolmap.Camera`` with the same maths (EQUIDISTANT -> SIMPLE_FISHEYE,
        PERSPECTIVE -> SIMPLE_PINHOLE); ValueError for models COLMAP lacks."""
        import pycolmap

        if self._spec.colmap is None:
            raise ValueError(f"COLMAP has no model equivalent to {self.model}")
        kwargs = dict(model=self._spec.colmap, width=self.width, height=self.height,
                      params=self.params.copy())
        if camera_id is not None:
            kwargs["camera_id"] = int(camera_id)
        return pycolmap.Camera(**kwargs)


def ray_from_angular(theta, phi) -> Array:
    """Unit camera-frame ray (..., 3) ``(sin t cos p, sin t sin p, cos t)``."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, float), np.asarray(phi, float))
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def angular_from_ray(X_cam) -> tuple[Array, Array, Array]:
    """``(theta, phi, angular_D_X)`` of camera-frame vectors (..., 3) of any length > 0.

    theta and phi are :func:`polarref.core.angular.ray_angles` (phi = 0 on the principal axis).

    The Jacobian (..., 2, 3) has rows (theta, phi); it is NaN on the principal axis (phi
    undefined) and for a zero vector.
    """
    X = _last(X_cam, 3, "X_cam")
    theta, phi = ray_angles(X)
    with np.errstate(**_ERR):
        r = np.hypot(X[..., 0], X[..., 1])
        n2 = r * r + X[..., 2] ** 2
        zero = np.zeros_like(r)
        J = np.stack([np.stack([X[..., 2] * X[..., 0] / r, X[..., 2] * X[..., 1] / r, -r], -1)
                      / n2[..., None],
                      np.stack([-X[..., 1], X[..., 0], zero], -1) / (r * r)[..., None]], -2)
        J = np.where((r > 0)[..., None, None], J, np.nan)
    return theta, phi, J
