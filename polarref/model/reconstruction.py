"""The one reconstruction type shared by our SfM, the BA adapter, the io readers and the reports.

Pixel coordinates follow COLMAP (origin at the corner of the first pixel). Cameras are
``polarref.camera.Camera`` only (other camera types are converted where they enter). The
pycolmap conversions are in :mod:`polarref.model.colmap`; this module keeps thin methods.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from polarref.camera import Camera
from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3
from polarref.model.observations import Observations
from polarref.model.colmap_text import refuse_names_for_text


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

    def check_cameras(self) -> None:
        """Raise TypeError unless every camera is a ``polarref.camera.Camera`` (a foreign camera
        type, e.g. synth's, must be converted where it enters)."""
        for cam_id, cam in self.cameras.items():
            if not isinstance(cam, Camera):
                raise TypeError(f"Reconstruction camera {cam_id} is a {type(cam).__name__}, not "
                                "polarref.camera.Camera; convert it first")

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

    def flat_observations(self, point_ids=None) -> tuple[Observations, np.ndarray, np.ndarray]:
        """The observations of ``point_ids`` (default: all, sorted) as flat arrays.

        Returns:
            (obs, image_ids (N,), point_ids (P,)): ``obs.point`` indexes ``point_ids``, in point
            then track order; ``obs.image`` indexes ``image_ids`` (the sorted ids of the
            registered images that observe them), -1 for a track element naming an image not in
            the reconstruction; ``obs.uv`` the keypoint, NaN where the image is unknown or the
            keypoint index is out of range (the callers count or score those).
        """
        pids = np.array(sorted(self.points3D) if point_ids is None else list(point_ids), np.int64)
        tracks = [np.asarray(self.points3D[int(p)].track, np.int64).reshape(-1, 2) for p in pids]
        rows = np.concatenate(tracks) if tracks else np.zeros((0, 2), np.int64)
        point = np.repeat(np.arange(len(pids)), [len(t) for t in tracks]).astype(np.int64)
        image_ids = np.array(sorted(set(rows[:, 0].tolist()) & set(self.images)), np.int64)
        image = np.searchsorted(image_ids, rows[:, 0]).astype(np.int64)
        known = image < len(image_ids)
        known[known] = image_ids[image[known]] == rows[known, 0]
        image[~known] = -1
        obs = Observations(image, point, np.full((len(rows), 2), np.nan))
        for k, sel in obs.by_image():  # one vectorized gather per image
            kp = self.images[int(image_ids[k])].keypoints
            idx = rows[sel, 1]
            ok = (idx >= 0) & (idx < len(kp))
            obs.uv[sel[ok]] = kp[idx[ok]]
        return obs, image_ids, pids

    def observation_errors(self) -> tuple[np.ndarray, np.ndarray]:
        """(errors (K,) px, point index (K,)) of every observation, vectorized per image.

        Order: points by sorted id, each point's track in order; the point index refers to
        ``sorted(self.points3D)``. The one behind-camera rule of polarref's metrics: an
        observation whose point has depth <= 0 in its camera, or whose projection or keypoint
        is not finite (unknown image or keypoint), gets error ``inf`` (so "finite" selects the
        usable errors, and every observation is still counted).
        """
        obs, image_ids, pids = self.flat_observations()
        if not len(pids):
            return np.zeros(0), np.zeros(0, np.int64)
        xyz = np.array([self.points3D[p].xyz for p in pids], dtype=np.float64).reshape(-1, 3)
        errs = np.full(len(obs), np.inf)
        for k, sel in obs.by_image():  # one project call per image
            im = self.images[int(image_ids[k])]
            Xc = im.cam_from_world.apply(xyz[obs.point[sel]])
            uv = np.asarray(self.cameras[im.camera_id].project(Xc), dtype=np.float64)
            e = np.linalg.norm(uv - obs.uv[sel], axis=1)
            e[~(Xc[:, 2] > 0) | ~np.isfinite(e)] = np.inf
            errs[sel] = e
        return errs, obs.point

    def reprojection_errors(self) -> np.ndarray:
        """Per-observation reprojection error in px, (num_observations,); order and the
        behind-camera rule (``inf``) of :meth:`observation_errors`."""
        return self.observation_errors()[0]

    # ---- files ---------------------------------------------------------------------------
    def write_text(self, path: str | Path) -> None:
        """Write cameras.txt, images.txt and points3D.txt (COLMAP text format) atomically per file."""
        path = Path(path)
        # before anything is written: COLMAP text cuts a name at its first space
        refuse_names_for_text([im.name for im in self.images.values()], str(path))
        path.mkdir(parents=True, exist_ok=True)
        self.check_cameras()
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
        from polarref.core.atomic import atomic_write

        for name, lines in (("cameras.txt", cams), ("images.txt", imgs), ("points3D.txt", pts)):
            atomic_write(path / name, "\n".join(lines) + "\n")


def build_reconstruction(cameras, camera_of_image, cam_from_world, names, obs: Observations,
                         points) -> Reconstruction:
    """The one flat-arrays -> :class:`Reconstruction` builder (io readers, BA adapter).

    Args:
        cameras: list of :class:`polarref.camera.Camera`; camera id = list index + 1.
        camera_of_image: (N,) 0-based index into ``cameras`` per image.
        cam_from_world: list of N :class:`polarref.core.geometry.Rigid3`.
        names: N image names.
        obs: :class:`Observations` with 0-based image / point indices, pixels in COLMAP's
            convention.
        points: (P, 3) world points.

    Image ids are ``index + 1``, point ids ``index + 1``; each image's keypoints are its
    observations in input order; each track lists a point's observations in input order.
    """
    obs = Observations.from_arrays(obs.image, obs.point, obs.uv)
    obs.validate(len(names), len(points), finite=False)
    rec = Reconstruction()
    for c, camera in enumerate(cameras):
        rec.cameras[c + 1] = camera
    rec.check_cameras()
    slot = obs.slot_in_image(len(names))
    order = np.argsort(obs.image, kind="stable")
    starts = np.searchsorted(obs.image[order], np.arange(len(names) + 1))
    for i in range(len(names)):
        mine = order[starts[i]:starts[i + 1]]
        rec.images[i + 1] = Image(i + 1, names[i], int(camera_of_image[i]) + 1, cam_from_world[i],
                                  obs.uv[mine], obs.point[mine] + 1)
    by_point = np.argsort(obs.point, kind="stable")
    pstarts = np.searchsorted(obs.point[by_point], np.arange(len(points) + 1))
    for j in range(len(points)):
        mine = by_point[pstarts[j]:pstarts[j + 1]]
        track = np.stack([obs.image[mine] + 1, slot[mine]], axis=1).astype(np.int64)
        rec.points3D[j + 1] = Point3D(np.array(points[j], dtype=np.float64), track.reshape(-1, 2))
    return rec
