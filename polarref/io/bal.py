"""Bundle Adjustment in the Large (BAL, Agarwal et al. 2010) problems.

File layout: header ``num_cameras num_points num_observations``; one line per observation
``camera_index point_index x y``; then 9 numbers per camera (Rodrigues rotation, translation,
f, k1, k2) and 3 per point, whitespace separated (one per line in the published files).

BAL's camera looks down -z with y up, and its image coordinates have their origin at the image
centre with y up. Projection (:func:`bal_residuals`):
``P = R X + t;  p = -P[:2] / P[2];  r = 1 + k1 |p|^2 + k2 |p|^4;  pixel = f r p``.

Mapping to polarref's COLMAP conventions (:func:`bal_to_reconstruction`), exact:
``F = diag(1, -1, -1)`` turns BAL's camera frame into COLMAP's (x right, y down, z forward), so
``cam_from_world = (F R, F t)``; the normalized image point becomes ``(p_x, -p_y)`` and the
camera is ``RADIAL(f, cx, cy, k1, k2)`` with pixels ``u = cx + x_bal``, ``v = cy - y_bal``. BAL
has no image size; a common (cx, cy) at the centre of a box holding every observation is used.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.camera import Camera
from polarref.core.geometry import Rigid3, so3_exp
from polarref.io.text import FormatError, parse_numbers, read_lines
from polarref.model import Observations, build_reconstruction

_F = np.diag([1.0, -1.0, -1.0])  # BAL camera frame (y up, -z forward) -> COLMAP camera frame


@dataclass(frozen=True)
class BALProblem:
    """A BAL problem (arrays are float64 unless stated).

    Attributes:
        rotvec: (N, 3) Rodrigues vectors of BAL's cam_from_world rotation.
        t: (N, 3) cam_from_world translations (BAL camera frame).
        intrinsics: (N, 3) f, k1, k2 per camera.
        points: (M, 3) world points.
        obs: observations; ``obs.image`` is the camera index and ``obs.uv`` holds the RAW BAL
            image coordinates (origin at the image centre, y up), not COLMAP pixels.
    """

    rotvec: np.ndarray
    t: np.ndarray
    intrinsics: np.ndarray
    points: np.ndarray
    obs: Observations

    @property
    def num_cameras(self) -> int:
        return len(self.rotvec)

    @property
    def num_points(self) -> int:
        return len(self.points)

    @property
    def num_observations(self) -> int:
        return len(self.obs)


def read_bal(path) -> BALProblem:
    """Read a BAL text file; FormatError names the file and line of the first problem."""
    path = Path(path)
    lines = read_lines(path)
    header_line = next((i for i, s in enumerate(lines) if s.strip()), None)
    if header_line is None:
        raise FormatError(path, 1, "empty file, expected header 'num_cameras num_points "
                          "num_observations'")
    n_cam, n_pt, n_obs = parse_numbers(path, header_line + 1, lines[header_line].split(), int, 3,
                                       "header fields (num_cameras num_points num_observations)")
    if min(n_cam, n_pt, n_obs) < 0:
        raise FormatError(path, header_line + 1, "negative count in header")
    # Size arrays by what the file can hold, not by what the header claims: an observation takes
    # >= 8 bytes ("0 0 0 0\n"), a parameter >= 2 ("0\n"), so a corrupt header claiming 10^12
    # points allocates nothing large and fails below with "file ends after k of n".
    size = path.stat().st_size
    n_par = 9 * n_cam + 3 * n_pt
    obs_idx = np.empty((min(n_obs, size // 8 + 1), 2), dtype=np.int64)
    obs_xy = np.empty((len(obs_idx), 2))
    i = header_line + 1
    k = 0
    while k < n_obs:
        if i >= len(lines):
            raise FormatError(path, i, f"file ends after {k} of {n_obs} observations")
        tokens = lines[i].split()
        i += 1
        if not tokens:
            continue
        if len(tokens) != 4:
            raise FormatError(path, i, f"observation {k}: expected 'camera point x y', "
                              f"found {lines[i - 1].strip()!r}")
        c, p = parse_numbers(path, i, tokens[:2], int, what="observation indices")
        x, y = parse_numbers(path, i, tokens[2:], float, what="observation coordinates")
        if not (0 <= c < n_cam and 0 <= p < n_pt):
            raise FormatError(path, i, f"observation {k}: camera {c} or point {p} out of range "
                              f"({n_cam} cameras, {n_pt} points)")
        obs_idx[k] = c, p
        obs_xy[k] = x, y
        k += 1
    values = np.empty(min(n_par, size // 2 + 1))
    j = 0
    while j < n_par:
        if i >= len(lines):
            raise FormatError(path, i, f"file ends after {j} of {n_par} parameter values "
                              f"(9 per camera, 3 per point)")
        tokens = lines[i].split()
        i += 1
        if j + len(tokens) > n_par:
            raise FormatError(path, i, f"more parameter values than the header allows ({n_par})")
        values[j:j + len(tokens)] = parse_numbers(path, i, tokens, float, what="parameters")
        j += len(tokens)
    for extra in range(i, len(lines)):
        if lines[extra].strip():
            raise FormatError(path, extra + 1, "unexpected data after the last point")
    if not np.isfinite(values).all() or not np.isfinite(obs_xy).all():
        raise FormatError(path, None, "non-finite value (nan/inf) in the file")
    cams = values[:9 * n_cam].reshape(n_cam, 9)
    bad_f = np.flatnonzero(~(cams[:, 6] > 0))
    if len(bad_f):
        raise FormatError(path, None, f"camera {bad_f[0]} has focal length {cams[bad_f[0], 6]:g}; "
                          "BAL focal lengths must be > 0")
    return BALProblem(rotvec=cams[:, :3].copy(), t=cams[:, 3:6].copy(),
                      intrinsics=cams[:, 6:9].copy(),
                      points=values[9 * n_cam:].reshape(n_pt, 3).copy(),
                      obs=Observations.from_arrays(obs_idx[:, 0].copy(), obs_idx[:, 1].copy(),
                                                   obs_xy))


def write_bal(problem: BALProblem, path) -> None:
    """Write a BAL text file (full float64 precision, one parameter per line)."""
    path = Path(path)
    out = [f"{problem.num_cameras} {problem.num_points} {problem.num_observations}"]
    for c, p, (x, y) in zip(problem.obs.image, problem.obs.point, problem.obs.uv):
        out.append(f"{int(c)} {int(p)}     {x:.17e} {y:.17e}")
    cams = np.hstack([problem.rotvec, problem.t, problem.intrinsics])
    out.extend(f"{v:.17e}" for v in np.concatenate([cams.ravel(), problem.points.ravel()]))
    path.write_text("\n".join(out) + "\n", encoding="utf-8")


def bal_project(problem: BALProblem) -> np.ndarray:
    """Predicted BAL image coordinates (K, 2) of every observation (BAL's own model)."""
    R = so3_exp(problem.rotvec)[problem.obs.image]
    P = np.einsum("kij,kj->ki", R, problem.points[problem.obs.point]) + problem.t[problem.obs.image]
    f, k1, k2 = problem.intrinsics[problem.obs.image].T
    with np.errstate(divide="ignore", invalid="ignore"):
        p = -P[:, :2] / P[:, 2:3]
    n2 = np.sum(p * p, axis=1)
    r = 1.0 + k1 * n2 + k2 * n2 * n2
    return (f * r)[:, None] * p


def bal_residuals(problem: BALProblem) -> np.ndarray:
    """Residuals (K, 2) = predicted - observed, in BAL image units (pixels)."""
    return bal_project(problem) - problem.obs.uv


def bal_cost(problem: BALProblem) -> float:
    """``0.5 * sum(residuals^2)``, the figure Ceres reports for BAL problems."""
    return float(0.5 * np.sum(bal_residuals(problem) ** 2))


# ---- mapping to polarref / COLMAP conventions ----------------------------------------------

def bal_principal_point(problem: BALProblem) -> tuple[int, int, float, float]:
    """(width, height, cx, cy): an image box, centred on BAL's origin, holding every observation."""
    half = np.ceil(np.max(np.abs(problem.obs.uv), axis=0)) + 1.0 if problem.num_observations \
        else np.ones(2)
    width, height = int(2 * half[0]), int(2 * half[1])
    return width, height, width / 2.0, height / 2.0


def bal_to_reconstruction(problem: BALProblem):
    """The BAL problem as a :class:`polarref.model.Reconstruction` (exact mapping).

    Image and camera ids are ``camera_index + 1``; point ids are ``point_index + 1``; each
    image's keypoints are its observations in file order, converted to COLMAP pixels
    ``(cx + x, cy - y)``. ``Reconstruction.reprojection_errors`` then equals the norms of
    :func:`bal_residuals` for every observation in front of its camera; a BAL observation
    behind its camera (P_z >= 0 in BAL's frame) or past the fold of the RADIAL polynomial
    is ``inf`` there (COLMAP's RADIAL model cannot represent it).
    """
    width, height, cx, cy = bal_principal_point(problem)
    R = so3_exp(problem.rotvec)
    cameras, poses = [], []
    for i in range(problem.num_cameras):
        f, k1, k2 = problem.intrinsics[i]
        if not f > 0:
            raise ValueError(f"BAL camera {i} has focal length {f} <= 0; cannot map it to RADIAL")
        cameras.append(Camera("RADIAL", width, height, [f, cx, cy, k1, k2]))
        poses.append(Rigid3(_F @ R[i], _F @ problem.t[i]))
    uv = np.stack([cx + problem.obs.uv[:, 0], cy - problem.obs.uv[:, 1]], axis=1)
    return build_reconstruction(cameras, np.arange(problem.num_cameras), poses,
                                [f"bal_{i:05d}" for i in range(problem.num_cameras)],
                                Observations(problem.obs.image, problem.obs.point, uv), problem.points)
