"""Rigid and similarity transforms, SO(3) exp/log, and Umeyama alignment.

Poses are named by frames: ``cam_from_world`` maps world points into the camera frame,
``X_cam = R @ X_world + t``. Everything is float64 and vectorized over leading axes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_SMALL = 1e-8  # below this rotation angle (rad) the Taylor series are exact to float64


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v]_x`` with ``skew(a) @ b == cross(a, b)``; (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=np.float64)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1),
                     np.stack([-y, x, z], -1)], -2)


def axis_rotation(axis: int, angle: np.ndarray) -> np.ndarray:
    """Right-handed active rotation about coordinate ``axis`` (0 = x, 1 = y, 2 = z).

    Args:
        axis: 0, 1 or 2.
        angle: (...) angles [rad].

    Returns:
        (..., 3, 3), e.g. ``Rx(t) = [[1, 0, 0], [0, cos t, -sin t], [0, sin t, cos t]]``. The
        constant zeros and one stay exact even for NaN angles.
    """
    angle = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(angle.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def so3_exp(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation vector (..., 3) -> rotation matrix (..., 3, 3)."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    angle = np.linalg.norm(rotvec, axis=-1)[..., None, None]
    small = angle < _SMALL
    safe = np.where(small, 1.0, angle)
    a = np.where(small, 1.0 - angle**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    K = skew(rotvec)
    return np.eye(3) + a * K + b * (K @ K)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (..., 3, 3) -> rotation vector (..., 3), angle in [0, pi].

    Uses the quaternion route, which stays accurate near 0 and near pi (where the
    ``(R - R^T) / (2 sin)`` formula loses all digits).
    """
    q = quat_from_rotmat(R)
    w = q[..., 0]
    v = q[..., 1:]
    sign = np.where(w < 0, -1.0, 1.0)[..., None]  # pick the quaternion with w >= 0
    w, v = np.abs(w), v * sign
    n = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(n, w)
    scale = np.where(n < _SMALL, 2.0 / np.maximum(w, _SMALL), angle / np.where(n < _SMALL, 1.0, n))
    return v * scale[..., None]


def quat_from_rotmat(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (..., 3, 3) -> unit quaternion (..., 4) as (w, x, y, z), w >= 0."""
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    # Shepperd's method: pick the largest diagonal term to divide by, for stability.
    cands = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22,
                      1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    k = np.argmax(cands, axis=-1)
    s = np.sqrt(np.maximum(np.take_along_axis(cands, k[..., None], -1)[..., 0], 1e-300)) * 2.0
    d21, d02, d10 = R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]
    s21, s02, s10 = R[..., 2, 1] + R[..., 1, 2], R[..., 0, 2] + R[..., 2, 0], R[..., 1, 0] + R[..., 0, 1]
    q = np.stack([
        np.stack([s / 4, d21 / s, d02 / s, d10 / s], -1),
        np.stack([d21 / s, s / 4, s10 / s, s02 / s], -1),
        np.stack([d02 / s, s10 / s, s / 4, s21 / s], -1),
        np.stack([d10 / s, s02 / s, s21 / s, s / 4], -1),
    ], -2)
    q = np.take_along_axis(q, k[..., None, None], -2)[..., 0, :]
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def rotmat_from_quat(q: np.ndarray) -> np.ndarray:
    """Quaternion (..., 4) as (w, x, y, z), any norm > 0 -> rotation matrix (..., 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Angle of ``R_a R_b^T`` in degrees, (..., 3, 3) x2 -> (...)."""
    rel = np.asarray(R_a) @ np.swapaxes(np.asarray(R_b), -1, -2)
    return np.degrees(np.linalg.norm(so3_log(rel), axis=-1))


@dataclass(frozen=True)
class Rigid3:
    """Rigid transform ``b_from_a``: ``X_b = R @ X_a + t``. R (3, 3), t (3,)."""

    R: np.ndarray
    t: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "R", np.asarray(self.R, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "t", np.asarray(self.t, dtype=np.float64).reshape(3))

    @staticmethod
    def identity() -> "Rigid3":
        return Rigid3(np.eye(3), np.zeros(3))

    @staticmethod
    def from_rotvec(rotvec: np.ndarray, t: np.ndarray) -> "Rigid3":
        return Rigid3(so3_exp(rotvec), t)

    @staticmethod
    def from_quat(q_wxyz: np.ndarray, t: np.ndarray) -> "Rigid3":
        return Rigid3(rotmat_from_quat(q_wxyz), t)

    def apply(self, X: np.ndarray) -> np.ndarray:
        """Transform points (..., 3)."""
        return np.asarray(X, dtype=np.float64) @ self.R.T + self.t

    def inverse(self) -> "Rigid3":
        return Rigid3(self.R.T, -self.R.T @ self.t)

    def compose(self, other: "Rigid3") -> "Rigid3":
        """``self * other``: if self is c_from_b and other is b_from_a, the result is c_from_a."""
        return Rigid3(self.R @ other.R, self.R @ other.t + self.t)

    @property
    def center(self) -> np.ndarray:
        """For a ``cam_from_world`` pose: the camera centre in world coordinates."""
        return -self.R.T @ self.t

    @property
    def rotvec(self) -> np.ndarray:
        return so3_log(self.R)

    @property
    def quat(self) -> np.ndarray:
        """(w, x, y, z), as COLMAP's images.txt writes it."""
        return quat_from_rotmat(self.R)


@dataclass(frozen=True)
class Sim3:
    """Similarity ``b_from_a``: ``X_b = s R X_a + t``."""

    s: float
    R: np.ndarray
    t: np.ndarray

    def apply(self, X: np.ndarray) -> np.ndarray:
        return self.s * (np.asarray(X, dtype=np.float64) @ self.R.T) + self.t

    def transform_pose(self, cam_from_a: Rigid3) -> Rigid3:
        """Re-express a ``cam_from_a`` pose as ``cam_from_b`` (camera centre mapped, scale removed)."""
        R = cam_from_a.R @ self.R.T
        center_b = self.apply(cam_from_a.center)
        return Rigid3(R, -R @ center_b)


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> Sim3:
    """Least-squares similarity with ``dst ~ s R src + t`` (Umeyama 1991).

    Args:
        src: (N, 3) points, N >= 3 and not collinear.
        dst: (N, 3) points.
    Raises:
        ValueError: fewer than 3 points, non-finite input, or (near-)collinear points.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"umeyama: expected two (N, 3) arrays, got {src.shape} and {dst.shape}")
    if len(src) < 3:
        raise ValueError(f"umeyama: need >= 3 point pairs, got {len(src)}")
    if not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise ValueError("umeyama: non-finite coordinates")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, S, Vt = np.linalg.svd(cov)
    sv = np.linalg.svd(xs, compute_uv=False)
    if sv[1] <= 1e-9 * max(sv[0], 1e-300):
        raise ValueError("umeyama: source points are (nearly) collinear; alignment is ill-posed")
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    var_s = (xs**2).sum() / len(src)
    s = float(np.trace(np.diag(S) @ D) / var_s) if with_scale else 1.0
    t = mu_d - s * R @ mu_s
    return Sim3(s, R, t)
