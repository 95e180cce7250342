"""PVL-BA four-file problems (cal.txt, Cam-<n>-.txt, XYZ.txt, Feature.txt) and the
ContextCapture BlocksExchange XML they are converted from.

PVL-BA (``pvl_ba_bench_sample/PVL-BA-format.md``): per camera group a 3x3 K in ``cal.txt``;
per image ``ey ex ez Xc Yc Zc group`` (group 1-based) with the world-to-camera rotation given
element by element in the spec (:func:`rotation_from_pvl_euler`), ``X_cam = R (X - C)``,
``u = fx x/z + cx``; per point ``X Y Z`` and a track ``N image u v ...`` of undistorted pixels.
In elementary rotations (right-handed, active: ``Rx(a) = [[1,0,0],[0,c,-s],[0,s,c]]``) the spec's
matrix is ``R = Rz(-ez) Rx(-ex) Ry(ey)``, i.e. ``world_from_cam = Ry(-ey) Rx(ex) Rz(ez)``: the
photogrammetric phi-omega-kappa (Y-X-Z) order with ``R_phi = [[c,0,-s],[0,1,0],[s,0,c]]``.

BlocksExchange conventions verified on ``sample_at.xml`` (tests/io/test_io_pvlba.py), reprojecting
the stored tie points through the stored poses (105 observations):

* ``Pose/Rotation`` is cam_from_world (rows = camera axes), ``Pose/Center`` the camera centre,
  camera frame x right, y down, z forward (``CameraOrientation`` XRightYDown).
* Distortion is Brown's model on normalized coordinates with ContextCapture's tangential naming,
  i.e. ``P1`` multiplies ``(r^2 + 2 x^2)`` and ``P2`` multiplies ``2 x y`` (OpenCV's p2 and p1):
  mean error 0.482 px, RMS 0.565 px; with OpenCV's naming 0.834 / 0.994 px; without distortion
  17.0 px.
* Measurements and principal point share one pixel origin (shifting measurements by +-0.5 px
  raises the mean error to 0.80 / 0.84 px); polarref takes it to be COLMAP's.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from xml.parsers import expat
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.camera import Camera
from polarref.core.geometry import Rigid3
from polarref.io.text import FormatError, parse_numbers, read_lines, read_tracks
from polarref.model import Observations, build_reconstruction


def rotation_from_pvl_euler(euler) -> np.ndarray:
    """PVL-BA angles (..., 3) = (ey, ex, ez) [rad] -> world-to-camera R (..., 3, 3), per the spec."""
    e = np.asarray(euler, dtype=np.float64)
    c1, c2, c3 = np.cos(e[..., 0]), np.cos(e[..., 1]), np.cos(e[..., 2])
    s1, s2, s3 = np.sin(e[..., 0]), np.sin(e[..., 1]), np.sin(e[..., 2])
    rows = [[c1 * c3 - s1 * s2 * s3, c2 * s3, s1 * c3 + c1 * s2 * s3],
            [-c1 * s3 - s1 * s2 * c3, c2 * c3, -s1 * s3 + c1 * s2 * c3],
            [-s1 * c2, -s2, c1 * c2]]
    return np.stack([np.stack(r, -1) for r in rows], -2)


def pvl_euler_from_rotation(R) -> np.ndarray:
    """Inverse of :func:`rotation_from_pvl_euler` with ex in [-pi/2, pi/2]; (..., 3, 3) -> (..., 3)."""
    R = np.asarray(R, dtype=np.float64)
    ex = np.arcsin(np.clip(-R[..., 2, 1], -1.0, 1.0))
    ey = np.arctan2(-R[..., 2, 0], R[..., 2, 2])
    ez = np.arctan2(R[..., 0, 1], R[..., 1, 1])
    return np.stack([ey, ex, ez], axis=-1)


@dataclass(frozen=True)
class PVLBAProblem:
    """A PVL-BA problem (indices 0-based in memory).

    Attributes:
        K: (G, 3, 3) intrinsic matrix per camera group.
        euler: (N, 3) stored angles (ey, ex, ez) [rad].
        centers: (N, 3) camera centres (world).
        group: (N,) int64 camera group of each image (0-based; the file stores 1-based).
        points: (M, 3) object points.
        obs: observations (image index, point index, undistorted pixels).
        track_start: (M + 1,) int64 offsets of each point's observations.
        image_names: (N,) names (from the XML source; empty strings when read from the 4 files).
    """

    K: np.ndarray
    euler: np.ndarray
    centers: np.ndarray
    group: np.ndarray
    points: np.ndarray
    obs: Observations
    track_start: np.ndarray
    image_names: tuple[str, ...] = ()

    @property
    def R(self) -> np.ndarray:
        """(N, 3, 3) world-to-camera rotations (cam_from_world)."""
        return rotation_from_pvl_euler(self.euler)

    @property
    def num_images(self) -> int:
        return len(self.centers)

    @property
    def num_points(self) -> int:
        return len(self.points)

    def project(self) -> np.ndarray:
        """Predicted pixels (L, 2) of every observation (NaN behind the camera)."""
        R = self.R[self.obs.image]
        Xc = np.einsum("lij,lj->li", R, self.points[self.obs.point] - self.centers[self.obs.image])
        K = self.K[self.group[self.obs.image]]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = Xc[:, :2] / Xc[:, 2:3]
        uv = np.stack([K[:, 0, 0] * x[:, 0] + K[:, 0, 1] * x[:, 1] + K[:, 0, 2],
                       K[:, 1, 1] * x[:, 1] + K[:, 1, 2]], axis=1)
        return np.where((Xc[:, 2] > 0)[:, None], uv, np.nan)

    def reprojection_errors(self) -> np.ndarray:
        """(L,) pixel distance between projection and observation."""
        return np.linalg.norm(self.project() - self.obs.uv, axis=1)

    def to_reconstruction(self, width: int | None = None, height: int | None = None):
        """As a :class:`polarref.model.Reconstruction`: one PINHOLE camera per group
        (id group + 1; skew must be 0), image ids index + 1, point ids index + 1. Image size
        defaults to twice the principal point (the four files do not store it)."""
        cams = []
        for k in self.K:
            if k[0, 1] != 0:
                raise ValueError(f"camera group with skew {k[0, 1]} cannot be PINHOLE")
            w = width or max(1, int(round(2 * k[0, 2])))
            h = height or max(1, int(round(2 * k[1, 2])))
            cams.append(Camera("PINHOLE", w, h, [k[0, 0], k[1, 1], k[0, 2], k[1, 2]]))
        R = self.R
        poses = [Rigid3(R[i], -R[i] @ self.centers[i]) for i in range(self.num_images)]
        names = [n or f"image_{i:05d}" for i, n in enumerate(self.image_names or ("",) * self.num_images)]
        return build_reconstruction(cams, self.group, poses, names, self.obs, self.points)


# ---- the four files ------------------------------------------------------------------------

def _cam_file(folder: Path) -> Path:
    found = sorted(p for p in folder.glob("Cam-*-.txt") if re.fullmatch(r"Cam-\d+-\.txt", p.name))
    if len(found) != 1:
        raise FormatError(folder, None, f"expected exactly one Cam-<num_images>-.txt, found "
                          f"{[p.name for p in found]}")
    return found[0]


def read_pvlba(folder) -> PVLBAProblem:
    """Read a PVL-BA problem folder; FormatError names the file and line."""
    folder = Path(folder)
    cal = folder / "cal.txt"
    rows = [(i + 1, s.split()) for i, s in enumerate(read_lines(cal)) if s.strip()]
    if not rows or len(rows) % 3:
        raise FormatError(cal, rows[-1][0] if rows else 1,
                          f"expected 3 rows per camera group, found {len(rows)} rows")
    K = np.array([parse_numbers(cal, n, t, float, 3, "K entries") for n, t in rows]).reshape(-1, 3, 3)
    for g, k in enumerate(K):
        if not (k[0, 0] > 0 and k[1, 1] > 0) or np.any(k[2] != [0, 0, 1]) or k[1, 0] != 0:
            raise FormatError(cal, rows[3 * g][0], f"group {g + 1}: not an upper-triangular K "
                              f"with positive focal lengths")
    camp = _cam_file(folder)
    n_images = int(camp.name.split("-")[1])
    cams = []
    for i, s in enumerate(read_lines(camp)):
        if not s.strip():
            continue
        vals = parse_numbers(camp, i + 1, s.split(), float, 7, "values (ey ex ez Xc Yc Zc camera_id)")
        if vals[6] != int(vals[6]) or not 1 <= vals[6] <= len(K):
            raise FormatError(camp, i + 1, f"camera_id {vals[6]:g} not in 1..{len(K)} (cal.txt)")
        cams.append(vals)
    if len(cams) != n_images:
        raise FormatError(camp, None, f"file name says {n_images} images, found {len(cams)} lines")
    cams = np.array(cams).reshape(-1, 7)
    xyzp = folder / "XYZ.txt"
    pts = [(i + 1, parse_numbers(xyzp, i + 1, s.split(), float, 3, "coordinates (X Y Z)"))
           for i, s in enumerate(read_lines(xyzp)) if s.strip()]
    featp = folder / "Feature.txt"
    obs, starts = read_tracks(featp, n_images, "image")
    if len(starts) - 1 != len(pts):
        raise FormatError(featp, None, f"{len(starts) - 1} tracks but XYZ.txt has {len(pts)} points")
    return PVLBAProblem(K=K, euler=cams[:, :3].copy(), centers=cams[:, 3:6].copy(),
                        group=cams[:, 6].astype(np.int64) - 1,
                        points=np.array([p for _, p in pts]).reshape(-1, 3),
                        obs=obs,
                        track_start=starts,
                        image_names=("",) * len(cams))


def write_pvlba(problem: PVLBAProblem, folder) -> None:
    """Write the four files into ``folder`` (created if needed)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    g = lambda v: f"{v:.17g}"  # noqa: E731
    (folder / "cal.txt").write_text("".join(
        "\n".join(" ".join(g(v) for v in row) for row in k) + "\n" for k in problem.K))
    (folder / f"Cam-{problem.num_images}-.txt").write_text("".join(
        " ".join(g(v) for v in np.r_[e, c]) + f" {int(grp) + 1}\n"
        for e, c, grp in zip(problem.euler, problem.centers, problem.group)))
    (folder / "XYZ.txt").write_text("".join(" ".join(g(v) for v in p) + "\n" for p in problem.points))
    lines = []
    for j in range(problem.num_points):
        s = slice(problem.track_start[j], problem.track_start[j + 1])
        parts = [str(s.stop - s.start)]
        for i, (u, v) in zip(problem.obs.image[s], problem.obs.uv[s]):
            parts += [str(int(i)), g(u), g(v)]
        lines.append(" ".join(parts) + "\n")
    (folder / "Feature.txt").write_text("".join(lines))


# ---- BlocksExchange XML --------------------------------------------------------------------

@dataclass(frozen=True)
class BrownDistortion:
    """ContextCapture's Brown model on normalized coordinates (see module docstring)."""

    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0  # multiplies (r^2 + 2 x^2) in x and 2 x y in y (OpenCV's p2)
    p2: float = 0.0  # multiplies 2 x y in x and (r^2 + 2 y^2) in y (OpenCV's p1)

    def distort(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distorted normalized points (..., 2) and their Jacobian (..., 2, 2)."""
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        rad = 1 + self.k1 * r2 + self.k2 * r2**2 + self.k3 * r2**3
        drad = self.k1 + 2 * self.k2 * r2 + 3 * self.k3 * r2**2  # d rad / d r2
        xd = x * rad + self.p1 * (r2 + 2 * x * x) + 2 * self.p2 * x * y
        yd = y * rad + self.p2 * (r2 + 2 * y * y) + 2 * self.p1 * x * y
        J = np.stack([np.stack([rad + 2 * x * x * drad + 6 * self.p1 * x + 2 * self.p2 * y,
                                2 * x * y * drad + 2 * self.p1 * y + 2 * self.p2 * x], -1),
                      np.stack([2 * x * y * drad + 2 * self.p2 * x + 2 * self.p1 * y,
                                rad + 2 * y * y * drad + 6 * self.p2 * y + 2 * self.p1 * x], -1)], -2)
        return np.stack([xd, yd], -1), J

    def undistort(self, xy_d: np.ndarray, iterations: int = 50) -> np.ndarray:
        """Invert :meth:`distort` by Newton's method (..., 2); NaN where it does not converge."""
        x = np.array(xy_d, dtype=np.float64)
        for _ in range(iterations):
            f, J = self.distort(x)
            step = np.linalg.solve(J, (f - xy_d)[..., None])[..., 0]
            x = x - step
            if np.all(np.abs(step) < 1e-15):
                break
        ok = np.max(np.abs(self.distort(x)[0] - xy_d), axis=-1) < 1e-12
        return np.where(ok[..., None], x, np.nan)


def _parse_xml(path: Path):
    """Parse with expat so every element's source line is known: (root, {id(element): line})."""
    if not path.is_file():
        raise FormatError(path, None, "file not found")
    builder = ET.TreeBuilder()
    lines: dict[int, int] = {}
    parser = expat.ParserCreate()

    def start(tag, attrs):
        lines[id(builder.start(tag, attrs))] = parser.CurrentLineNumber

    parser.StartElementHandler = start
    parser.EndElementHandler = builder.end
    parser.CharacterDataHandler = builder.data
    try:
        parser.Parse(path.read_bytes(), True)
    except expat.ExpatError as exc:
        raise FormatError(path, exc.lineno, f"XML syntax error: {expat.ErrorString(exc.code)}") from exc
    return builder.close(), lines


def read_blocks_exchange(path) -> PVLBAProblem:
    """Convert a BlocksExchange XML (one block) to an undistorted :class:`PVLBAProblem`.

    Photos without a complete pose are skipped and measurements on them dropped (PVL-BA rule);
    tie points left with no measurement are dropped. Measurements are undistorted with the
    photogroup's Brown model and keep the photogroup's K. FormatError names file and line.
    """
    path = Path(path)
    root, lines = _parse_xml(path)

    def num(el, sub: str, default=None) -> float:
        node = el.find(sub)
        if node is None or node.text is None or not node.text.strip():
            if default is not None:
                return default
            raise FormatError(path, lines.get(id(el)), f"<{el.tag}> lacks <{sub}>")
        try:
            return float(node.text)
        except ValueError as exc:
            raise FormatError(path, lines.get(id(node)), f"<{sub}>: bad number {node.text!r}") from exc

    Ks, dists, euler, centers, groups, names, photo_index = [], [], [], [], [], [], {}
    for pg in root.iter("Photogroup"):
        model = (pg.findtext("CameraModelType") or "Perspective").strip()
        orient = (pg.findtext("CameraOrientation") or "XRightYDown").strip()
        if model != "Perspective" or orient != "XRightYDown":
            raise FormatError(path, lines.get(id(pg)), f"unsupported photogroup: CameraModelType "
                              f"{model!r}, CameraOrientation {orient!r}")
        f = num(pg, "FocalLengthPixels")
        aspect = num(pg, "AspectRatio", 1.0)
        skew = num(pg, "Skew", 0.0)
        Ks.append([[f, skew, num(pg, "PrincipalPoint/x")], [0, f * aspect, num(pg, "PrincipalPoint/y")],
                   [0, 0, 1]])
        dist = pg.find("Distortion")
        dists.append(BrownDistortion(*(num(dist, k, 0.0) for k in ("K1", "K2", "K3", "P1", "P2")))
                     if dist is not None else BrownDistortion())
        for ph in pg.findall("Photo"):
            pid = int(num(ph, "Id"))
            rot, cen = ph.find("Pose/Rotation"), ph.find("Pose/Center")
            keys = [f"M_{i}{j}" for i in range(3) for j in range(3)]
            if rot is None or cen is None or any(rot.find(k) is None for k in keys) \
                    or any(cen.find(a) is None for a in "xyz"):
                continue  # incomplete pose: not part of the BA problem
            R = np.array([num(rot, k) for k in keys]).reshape(3, 3)
            if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
                raise FormatError(path, lines.get(id(rot)), f"photo {pid}: rotation is not a rotation")
            photo_index[pid] = len(centers)
            euler.append(pvl_euler_from_rotation(R))
            centers.append([num(cen, a) for a in "xyz"])
            groups.append(len(Ks) - 1)
            names.append((ph.findtext("ImagePath") or "").strip())
    if not centers:
        raise FormatError(path, None, "no photo with a complete pose")
    Ks = np.array(Ks, dtype=np.float64)
    groups = np.array(groups, dtype=np.int64)
    points, obs_point, obs_img, obs_raw, starts = [], [], [], [], [0]
    for tp in root.iter("TiePoint"):
        meas = []
        for m in tp.findall("Measurement"):
            pid = int(num(m, "PhotoId"))
            if pid in photo_index:
                meas.append((photo_index[pid], num(m, "x"), num(m, "y")))
        if not meas:
            continue
        points.append([num(tp, f"Position/{a}") for a in "xyz"])
        for i, u, v in meas:
            obs_point.append(len(points) - 1)
            obs_img.append(i)
            obs_raw.append((u, v))
        starts.append(starts[-1] + len(meas))
    obs_img = np.array(obs_img, dtype=np.int64)
    obs_raw = np.array(obs_raw, dtype=np.float64).reshape(-1, 2)
    obs_uv = np.empty_like(obs_raw)
    for g, (K, dist) in enumerate(zip(Ks, dists)):
        sel = groups[obs_img] == g
        Kinv = np.linalg.inv(K)
        xy_d = (np.c_[obs_raw[sel], np.ones(sel.sum())] @ Kinv.T)[:, :2]
        xy = dist.undistort(xy_d)
        obs_uv[sel] = (np.c_[xy, np.ones(len(xy))] @ K.T)[:, :2]
    return PVLBAProblem(K=Ks, euler=np.array(euler), centers=np.array(centers), group=groups,
                        points=np.array(points).reshape(-1, 3),
                        obs=Observations.from_arrays(obs_img, np.array(obs_point, dtype=np.int64), obs_uv),
                        track_start=np.array(starts, dtype=np.int64),
                        image_names=tuple(names))
