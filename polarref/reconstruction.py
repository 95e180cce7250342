"""The one reconstruction type shared by our SfM, the pycolmap adapter and the reports.

Conversions to and from ``pycolmap.Reconstruction`` and the COLMAP text format live here and
nowhere else. Pixel coordinates follow COLMAP (origin at the corner of the first pixel).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from polarref.camera import Camera
from polarref.errors import PolarrefError
from polarref.geometry import Rigid3


@dataclass
class Image:
    """One registered image. keypoints (K, 2) float64; point3D_ids (K,) int64, -1 = none."""

    image_id: int
    name: str
    camera_id: int
    cam_from_world: Rigid3
    keypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    point3D_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


@dataclass
class Point3D:
    """A triangulated point. xyz (3,); track (L, 2) int64 rows (image_id, point2D_idx)."""

    xyz: np.ndarray
    track: np.ndarray
    error: float = -1.0
    color: np.ndarray = field(default_factory=lambda: np.zeros(3, dtype=np.uint8))


@dataclass
class Reconstruction:
    """Cameras (``polarref.camera.Camera``), registered images and 3D points, by integer id."""

    cameras: dict[int, Camera] = field(default_factory=dict)
    images: dict[int, Image] = field(default_factory=dict)
    points3D: dict[int, Point3D] = field(default_factory=dict)

    # ---- summaries -------------------------------------------------------------------
    @property
    def num_observations(self) -> int:
        return int(sum(len(p.track) for p in self.points3D.values()))

    def centers(self, image_ids: list[int] | None = None) -> np.ndarray:
        """Camera centres (N, 3) in world coordinates, in ``image_ids`` order (default: sorted)."""
        ids = sorted(self.images) if image_ids is None else image_ids
        return np.array([self.images[i].cam_from_world.center for i in ids]).reshape(-1, 3)

    def points_array(self) -> tuple[np.ndarray, np.ndarray]:
        """(ids (P,), xyz (P, 3)) of all 3D points, sorted by id."""
        ids = np.array(sorted(self.points3D), dtype=np.int64)
        xyz = np.array([self.points3D[i].xyz for i in ids]).reshape(-1, 3)
        return ids, xyz

    def observations(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All observations in track order: (image_ids (K,), point_ids (K,), point2D_idx (K,))."""
        rows = [(np.full(len(p.track), pid), p.track) for pid, p in self.points3D.items()]
        if not rows:
            empty = np.zeros(0, dtype=np.int64)
            return empty, empty, empty
        pids = np.concatenate([r[0] for r in rows]).astype(np.int64)
        tracks = np.concatenate([r[1] for r in rows]).astype(np.int64).reshape(-1, 2)
        return tracks[:, 0], pids, tracks[:, 1]

    def reprojection_errors(self) -> np.ndarray:
        """Per-observation reprojection error in px, (num_observations,), track order.

        Vectorized per image: one ``project`` call per image, not per observation.
        """
        image_ids, point_ids, idx = self.observations()
        errs = np.full(len(image_ids), np.nan)
        if len(image_ids) == 0:
            return errs
        xyz = {pid: p.xyz for pid, p in self.points3D.items()}
        X = np.array([xyz[int(i)] for i in point_ids]).reshape(-1, 3)
        for image_id in np.unique(image_ids):
            sel = image_ids == image_id
            img = self.images[int(image_id)]
            uv = self.cameras[img.camera_id].project(img.cam_from_world.apply(X[sel]))
            errs[sel] = np.linalg.norm(uv - img.keypoints[idx[sel]], axis=1)
        return errs

    # ---- pycolmap ----------------------------------------------------------------------
    def to_pycolmap(self):
        """Build a ``pycolmap.Reconstruction`` (trivial rigs and frames)."""
        import pycolmap

        rec = pycolmap.Reconstruction()
        for cam_id, cam in self.cameras.items():
            try:
                rec.add_camera_with_trivial_rig(cam.to_pycolmap(int(cam_id)))
            except ValueError as exc:
                raise PolarrefError(f"camera {cam_id}: {exc}") from exc
        for img in self.images.values():
            pimg = pycolmap.Image(name=img.name, keypoints=np.asarray(img.keypoints, dtype=np.float64),
                                  camera_id=int(img.camera_id), image_id=int(img.image_id))
            pose = pycolmap.Rigid3d(pycolmap.Rotation3d(img.cam_from_world.R), img.cam_from_world.t)
            rec.add_image_with_trivial_frame(pimg, pose)
        for pid, p in sorted(self.points3D.items()):
            track = pycolmap.Track()
            for image_id, idx in p.track:
                track.add_element(int(image_id), int(idx))
            point = pycolmap.Point3D(xyz=np.asarray(p.xyz, dtype=np.float64), track=track,
                                     color=np.asarray(p.color, dtype=np.uint8))
            rec.add_point3D_with_id(int(pid), point)  # keeps our ids; links the images' points2D
        return rec

    @staticmethod
    def from_pycolmap(rec) -> "Reconstruction":
        """Copy a ``pycolmap.Reconstruction``; only registered images are kept."""
        out = Reconstruction()
        for cam_id, c in rec.cameras.items():
            try:
                out.cameras[int(cam_id)] = Camera.from_pycolmap(c)
            except ValueError as exc:
                raise PolarrefError(f"camera {cam_id}: {exc}") from exc
        for image_id, im in rec.images.items():
            if not im.has_pose:
                continue
            pose = im.cam_from_world()
            kps = np.array([p.xy for p in im.points2D], dtype=np.float64).reshape(-1, 2)
            ids = np.array([p.point3D_id if p.has_point3D() else -1 for p in im.points2D],
                           dtype=np.int64)
            out.images[int(image_id)] = Image(int(image_id), im.name, int(im.camera_id),
                                              Rigid3(pose.rotation.matrix(), pose.translation),
                                              kps, ids)
        for pid, p in rec.points3D.items():
            track = np.array([(e.image_id, e.point2D_idx) for e in p.track.elements],
                             dtype=np.int64).reshape(-1, 2)
            out.points3D[int(pid)] = Point3D(np.array(p.xyz, dtype=np.float64), track,
                                             float(p.error), np.array(p.color, dtype=np.uint8))
        return out

    # ---- files ---------------------------------------------------------------------------
    @staticmethod
    def read(path: str | Path) -> "Reconstruction":
        """Read a COLMAP model folder (text or binary)."""
        import pycolmap

        path = Path(path)
        if not path.is_dir():
            raise PolarrefError(f"COLMAP model folder not found: {path}")
        names = {p.name for p in path.iterdir()}
        if not ({"cameras.txt", "images.txt"} <= names or {"cameras.bin", "images.bin"} <= names):
            raise PolarrefError(f"not a COLMAP model (no cameras/images .txt or .bin): {path}")
        try:
            rec = pycolmap.Reconstruction(str(path))
            # inside the try: names that are not UTF-8 fail only when converted
            return Reconstruction.from_pycolmap(rec)
        except Exception as exc:  # pycolmap raises generic errors on malformed files
            raise PolarrefError(f"cannot read COLMAP model {path}: {exc}") from exc

    def write_text(self, path: str | Path) -> None:
        """Write cameras.txt, images.txt and points3D.txt (COLMAP text format) atomically per file."""
        path = Path(path)
        path.mkdir(parents=True, exist_ok=True)
        cams = ["# CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]"]
        for cam_id, c in sorted(self.cameras.items()):
            params = " ".join(repr(float(v)) for v in np.asarray(c.params))
            cams.append(f"{cam_id} {c.model} {int(c.width)} {int(c.height)} {params}")
        imgs = ["# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME", "# POINTS2D[] as (X, Y, POINT3D_ID)"]
        for image_id, im in sorted(self.images.items()):
            q = im.cam_from_world.quat
            t = im.cam_from_world.t
            vals = " ".join(repr(float(v)) for v in (*q, *t))
            imgs.append(f"{image_id} {vals} {im.camera_id} {im.name}")
            imgs.append(" ".join(f"{float(x)!r} {float(y)!r} {int(i)}"
                                 for (x, y), i in zip(im.keypoints, im.point3D_ids)))
        pts = ["# POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX)"]
        for pid, p in sorted(self.points3D.items()):
            xyz = " ".join(repr(float(v)) for v in p.xyz)
            rgb = " ".join(str(int(v)) for v in p.color)
            track = " ".join(f"{int(a)} {int(b)}" for a, b in p.track)
            pts.append(f"{pid} {xyz} {rgb} {float(p.error)!r} {track}")
        from polarref.atomic import atomic_write

        for name, lines in (("cameras.txt", cams), ("images.txt", imgs), ("points3D.txt", pts)):
            atomic_write(path / name, "\n".join(lines) + "\n")
