"""ParallaxBA's text problem format (Zhao et al. 2015; OpenSLAM ParallaxBA demo files).

Files in one folder, named as in the fake-pile demo or as in the datasets distributed with
ParallaxBA (``README.txt``: ``ParallaxBA -cam Cam90.txt -fea Feature90.txt -calib cal90.txt``):

* ``intrinsic_matrix.txt`` / ``cal<N>.txt``: the 3x3 K (shared by all cameras, no distortion),
  three rows, or its nine numbers row by row on one line (ParallaxBA reads them with one scanf).
* ``Cam.txt`` / ``Cam<N>.txt``: one camera per line, ``alpha beta gamma Cx Cy Cz`` (Euler angles
  in radians, then the camera centre in world coordinates).
* ``Feature.pmba`` / ``Feature<N>.txt``: one point per line, ``n cam_1 u_1 v_1 ... cam_n u_n
  v_n`` (0-based camera indices); the first camera listed is the point's main anchor.
* optional ``XYZ.txt`` (or ``XYZ<N>.txt``): initial points, ``X Y Z`` per line in feature order
  (ParallaxBA's ``-xyz``).

Verified convention (on the fakepile demo, see tests/io/test_io_parallaxba.py):
``cam_from_world = (Rz(alpha) Ry(beta) Rx(gamma))^T = Rx(-gamma) Ry(-beta) Rz(-alpha)`` with the
usual right-handed elementary rotations ``Rx(a) = [[1,0,0],[0,c,-s],[0,s,c]]`` etc., and
``u ~ K cam_from_world (X - C)``. In words: ``world_from_cam`` is the z-y-x (yaw-pitch-roll)
product of the three angles. The data README's ``R = Rx(gamma) Ry(beta) Rz(alpha)`` is the same
thing only when its elementary matrices are read as *frame* (passive) rotations; with the usual
active matrices it is wrong (median DLT reprojection error 31 px instead of 0.63 px).

Pixel origin: the files do not say; coordinates are returned as stored (a constant half-pixel
shift would be absorbed by cx, cy).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import re

import numpy as np

from polarref.camera import Camera
from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3, axis_rotation
from polarref.io.text import FormatError, parse_numbers, read_lines, read_tracks
from polarref.model import Observations, build_reconstruction


def cam_from_world_rotation(euler) -> np.ndarray:
    """ParallaxBA Euler angles (..., 3) = (alpha, beta, gamma) -> cam_from_world R (..., 3, 3)."""
    euler = np.asarray(euler, dtype=np.float64)
    a, b, g = euler[..., 0], euler[..., 1], euler[..., 2]
    world_from_cam = axis_rotation(2, a) @ axis_rotation(1, b) @ axis_rotation(0, g)
    return np.swapaxes(world_from_cam, -1, -2)


def euler_from_cam_from_world(R) -> np.ndarray:
    """Inverse of :func:`cam_from_world_rotation` (beta in [-pi/2, pi/2]); (..., 3, 3) -> (..., 3)."""
    W = np.swapaxes(np.asarray(R, dtype=np.float64), -1, -2)  # world_from_cam = Rz Ry Rx
    beta = np.arcsin(np.clip(-W[..., 2, 0], -1.0, 1.0))
    alpha = np.arctan2(W[..., 1, 0], W[..., 0, 0])
    gamma = np.arctan2(W[..., 2, 1], W[..., 2, 2])
    return np.stack([alpha, beta, gamma], axis=-1)


@dataclass(frozen=True)
class ParallaxBAProblem:
    """A ParallaxBA problem.

    Attributes:
        K: (3, 3) intrinsic matrix shared by all cameras.
        euler: (N, 3) the stored angles (alpha, beta, gamma) [rad].
        centers: (N, 3) camera centres in world coordinates.
        R: (N, 3, 3) cam_from_world rotations (verified convention, module docstring).
        obs: observations (camera index, point index in file order, pixels as stored).
        track_start: (M + 1,) int64; observations of point j are ``track_start[j]:track_start[j+1]``
            and the first of them is the main anchor.
    """

    K: np.ndarray
    euler: np.ndarray
    centers: np.ndarray
    R: np.ndarray
    obs: Observations
    track_start: np.ndarray
    points: np.ndarray | None = None  # (M, 3) initial points from XYZ.txt, if the folder has one

    @property
    def num_cameras(self) -> int:
        return len(self.centers)

    @property
    def num_points(self) -> int:
        return len(self.track_start) - 1

    @property
    def t(self) -> np.ndarray:
        """(N, 3) cam_from_world translations ``-R C``."""
        return -np.einsum("nij,nj->ni", self.R, self.centers)

    @property
    def main_anchor(self) -> np.ndarray:
        """(M,) camera index of each point's main anchor (first observation)."""
        return self.obs.image[self.track_start[:-1]]

    def cam_from_world(self, i: int) -> Rigid3:
        return Rigid3(self.R[i], -self.R[i] @ self.centers[i])

    def camera(self, width: int | None = None, height: int | None = None):
        """The shared intrinsics as a PINHOLE :class:`polarref.camera.Camera`.

        The files carry no image size; by default it is the smallest box holding the principal
        point at its centre-or-beyond and every observation.
        """
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        if width is None:
            width = int(np.ceil(max(2 * cx, self.obs.uv[:, 0].max(initial=0.0))))
        if height is None:
            height = int(np.ceil(max(2 * cy, self.obs.uv[:, 1].max(initial=0.0))))
        return Camera("PINHOLE", width, height, [fx, fy, cx, cy])


def parallaxba_to_reconstruction(problem: ParallaxBAProblem, points: np.ndarray | None = None):
    """The problem as a :class:`polarref.model.Reconstruction` (one shared PINHOLE
    camera, id 1; image ids camera index + 1; point ids point index + 1). ``points`` (M, 3)
    default to :func:`triangulate_dlt`. Pixels are used as stored (see module docstring)."""
    points = triangulate_dlt(problem) if points is None else np.asarray(points, dtype=np.float64)
    poses = [problem.cam_from_world(i) for i in range(problem.num_cameras)]
    return build_reconstruction([problem.camera()], np.zeros(problem.num_cameras, np.int64), poses,
                                [f"cam_{i:03d}" for i in range(problem.num_cameras)],
                                problem.obs, points)


@dataclass(frozen=True)
class ParallaxBAFiles:
    """The files of one ParallaxBA problem (``xyz`` None when there is no start file)."""

    cam: Path
    feature: Path
    intrinsics: Path
    xyz: Path | None


_NUMBERED = re.compile(r"Cam(\d+)\.txt")


def find_parallaxba_files(folder) -> ParallaxBAFiles | None:
    """The ParallaxBA files in ``folder`` in either naming (module docstring); None if it has
    neither ``Cam.txt`` + ``Feature.pmba`` nor ``Cam<N>.txt`` + ``Feature<N>.txt``. PolarrefError
    if several numbered problems share the folder or one lacks its ``cal<N>.txt``."""
    folder = Path(folder)
    if not folder.is_dir():
        return None
    if (folder / "Cam.txt").is_file() and (folder / "Feature.pmba").is_file():
        xyz = folder / "XYZ.txt"
        return ParallaxBAFiles(folder / "Cam.txt", folder / "Feature.pmba",
                               folder / "intrinsic_matrix.txt", xyz if xyz.is_file() else None)
    nums = sorted(m.group(1) for f in folder.iterdir() if (m := _NUMBERED.fullmatch(f.name))
                  and (folder / f"Feature{m.group(1)}.txt").is_file())
    if not nums:
        return None
    if len(nums) > 1:
        names = ", ".join(f"Cam{n}.txt" for n in nums)
        raise PolarrefError(f"{folder}: several ParallaxBA problems ({names}); put each in its "
                            "own folder")
    n = nums[0]
    cal = folder / f"cal{n}.txt"
    if not cal.is_file():
        raise PolarrefError(f"{folder}: Cam{n}.txt and Feature{n}.txt but no cal{n}.txt "
                            "(the 3x3 K)")
    xyz = [folder / name for name in (f"XYZ{n}.txt", "XYZ.txt") if (folder / name).is_file()]
    return ParallaxBAFiles(folder / f"Cam{n}.txt", folder / f"Feature{n}.txt", cal,
                           xyz[0] if xyz else None)


def _read_K(kpath: Path) -> np.ndarray:
    rows = [(i + 1, s.split()) for i, s in enumerate(read_lines(kpath)) if s.strip()]
    if len(rows) == 1 and len(rows[0][1]) == 9:  # ParallaxBA scans nine numbers, any layout
        n, tok = rows[0]
        rows = [(n, tok[0:3]), (n, tok[3:6]), (n, tok[6:9])]
    if len(rows) != 3:
        raise FormatError(kpath, None, f"expected 3 non-empty rows of K, found {len(rows)}")
    K = np.array([parse_numbers(kpath, n, tok, float, 3, "K entries") for n, tok in rows])
    if not (K[0, 0] > 0 and K[1, 1] > 0) or np.any(K[2] != [0, 0, 1]) or K[1, 0] != 0:
        raise FormatError(kpath, None, f"not an upper-triangular K with positive focal lengths: "
                          f"{K.tolist()}")
    if K[0, 1] != 0:
        raise FormatError(kpath, 1, f"skew K[0,1] = {K[0, 1]} is not supported")
    return K


def read_xyz(path, num_points: int) -> np.ndarray:
    """ParallaxBA's start points (``-xyz``): ``X Y Z`` per non-empty line, (num_points, 3)."""
    path = Path(path)
    pts = [parse_numbers(path, i + 1, s.split(), float, 3, "coordinates (X Y Z)")
           for i, s in enumerate(read_lines(path)) if s.strip()]
    if len(pts) != num_points:
        raise FormatError(path, None, f"{len(pts)} points for {num_points} features")
    pts = np.array(pts, dtype=np.float64).reshape(-1, 3)
    if not np.isfinite(pts).all():
        raise FormatError(path, None, "non-finite coordinates")
    return pts


def read_parallaxba(folder, cam_file: str | None = None, feature_file: str | None = None,
                    intrinsics_file: str | None = None) -> ParallaxBAProblem:
    """Read a ParallaxBA problem folder (either naming, :func:`find_parallaxba_files`; file
    names given here override it); FormatError names the file and line."""
    folder = Path(folder)
    found = find_parallaxba_files(folder)
    kpath = folder / (intrinsics_file
                      or (found.intrinsics.name if found else "intrinsic_matrix.txt"))
    K = _read_K(kpath)
    cpath = folder / (cam_file or (found.cam.name if found else "Cam.txt"))
    cams = []
    for i, s in enumerate(read_lines(cpath)):
        if s.strip():
            cams.append(parse_numbers(cpath, i + 1, s.split(), float, 6,
                                      "values (alpha beta gamma Cx Cy Cz)"))
    if not cams:
        raise FormatError(cpath, 1, "no cameras")
    cams = np.array(cams)
    fpath = folder / (feature_file or (found.feature.name if found else "Feature.pmba"))
    obs, starts = read_tracks(fpath, len(cams), "camera", distinct=True)
    if len(starts) == 1:
        raise FormatError(fpath, 1, "no points")
    points = None
    if found is not None and found.xyz is not None:
        points = read_xyz(found.xyz, len(starts) - 1)
    return ParallaxBAProblem(K=K, euler=cams[:, :3].copy(), centers=cams[:, 3:].copy(),
                             R=cam_from_world_rotation(cams[:, :3]),
                             obs=obs,
                             track_start=starts, points=points)


def write_parallaxba(problem: ParallaxBAProblem, folder) -> None:
    """Write the three files (angles and centres as stored in ``problem``)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "intrinsic_matrix.txt").write_text(
        "\n".join(" ".join(f"{v:.17g}" for v in row) for row in problem.K) + "\n")
    (folder / "Cam.txt").write_text("\n".join(
        " ".join(f"{v:.17g}" for v in np.r_[e, c]) for e, c in zip(problem.euler, problem.centers))
        + "\n")
    lines = []
    for j in range(problem.num_points):
        s = slice(problem.track_start[j], problem.track_start[j + 1])
        parts = [str(s.stop - s.start)]
        for c, (u, v) in zip(problem.obs.image[s], problem.obs.uv[s]):
            parts += [str(int(c)), f"{u:.17g}", f"{v:.17g}"]
        lines.append(" ".join(parts))
    (folder / "Feature.pmba").write_text("\n".join(lines) + "\n")
    if problem.points is not None:
        (folder / "XYZ.txt").write_text("\n".join(
            " ".join(f"{v:.17g}" for v in X) for X in problem.points) + "\n")


def triangulate_dlt(problem: ParallaxBAProblem, R: np.ndarray | None = None) -> np.ndarray:
    """Linear (DLT) triangulation of every point from all its observations, (M, 3).

    Used to check the pose convention: with the right convention, reprojection errors of the
    DLT points are at the noise level. ``R`` overrides the cam_from_world rotations.
    """
    R = problem.R if R is None else R
    xn = np.c_[problem.obs.uv, np.ones(len(problem.obs.uv))] @ np.linalg.inv(problem.K).T
    P = np.concatenate([R, -(R @ problem.centers[:, :, None])], axis=2)[problem.obs.image]
    r1 = xn[:, 0:1] * P[:, 2] - P[:, 0]
    r2 = xn[:, 1:2] * P[:, 2] - P[:, 1]
    A = np.zeros((problem.num_points, 4, 4))
    np.add.at(A, problem.obs.point, r1[:, :, None] * r1[:, None, :] + r2[:, :, None] * r2[:, None, :])
    _, V = np.linalg.eigh(A)
    Xh = V[:, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        return Xh[:, :3] / Xh[:, 3:4]


def reprojection_errors(problem: ParallaxBAProblem, points: np.ndarray,
                        R: np.ndarray | None = None) -> np.ndarray:
    """Pixel reprojection error (L,) of every observation for world points (M, 3); ``inf``
    behind the camera (the rule of :meth:`polarref.model.Reconstruction.observation_errors`)."""
    R = problem.R if R is None else R
    Xc = np.einsum("lij,lj->li", R[problem.obs.image],
                   points[problem.obs.point] - problem.centers[problem.obs.image])
    uvh = Xc @ problem.K.T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = uvh[:, :2] / uvh[:, 2:3]
    return np.where(Xc[:, 2] > 0, np.linalg.norm(uv - problem.obs.uv, axis=1), np.inf)
