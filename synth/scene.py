"""A rendered scene on disk: layout, ground-truth writing and :func:`load_scene`.

Layout of a scene folder ``DIR``::

    scene.json        all parameters, seed, Mitsuba variant, versions, cameras (written first)
    mesh.ply          the rendered surface (float64 vertices, uchar albedo), world units (m)
    gt/               COLMAP text model: cameras.txt (one PINHOLE), images.txt (cam_from_world),
                      points3D.txt (empty: the surface is mesh.ply; score points against it)
    images/NNNN.png   8-bit sRGB renders
    depth/NNNN.npy    float32 (H, W) z-depth along the camera's +z axis (not range) of the
                      surface seen through each pixel centre; 0 where the ray hits nothing
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.core.atomic import atomic_write
from polarref.core.errors import PolarrefError
from polarref.core.geometry import Rigid3

SCENE_JSON = "scene.json"


@dataclass(frozen=True)
class PinholeCamera:
    """COLMAP ``PINHOLE`` camera: params (fx, fy, cx, cy), pixel-corner origin (or ``RADIAL``
    (f, cx, cy, k1, k2) for scenes rendered with distortion, synth/distort.py)."""

    width: int
    height: int
    params: np.ndarray  # (4,)
    model: str = "PINHOLE"
    camera_id: int = 1


@dataclass(frozen=True)
class View:
    """One rendered image with its exact pose."""

    image_id: int
    name: str  # file name inside images/ (also the COLMAP image name)
    cam_from_world: Rigid3
    image_path: Path
    depth_path: Path


@dataclass(frozen=True)
class Scene:
    """A loaded scene folder; see the module docstring for the file layout."""

    root: Path
    camera: PinholeCamera
    views: list[View]
    center: np.ndarray  # (3,) bounding-sphere centre used to frame the views
    radius: float  # bounding-sphere radius: the scene scale, world units
    meta: dict  # the whole scene.json

    @property
    def gt_dir(self) -> Path:
        return self.root / "gt"

    @property
    def mesh_path(self) -> Path:
        return self.root / "mesh.ply"

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (V, 3) float64, faces (F, 3) int64) of the rendered surface."""
        from synth.meshes import read_mesh

        return read_mesh(self.mesh_path)

    def depth(self, i: int) -> np.ndarray:
        """z-depth map (H, W) float32 of view index ``i`` (0 = no surface)."""
        return np.load(self.views[i].depth_path)

    def polarref_camera(self):
        """The camera as ``polarref.camera.Camera``."""
        return polarref_camera(self.camera)


def polarref_camera(camera: PinholeCamera):
    """``polarref.camera.Camera`` of a scene camera: the only type a Reconstruction holds, so
    the conversion happens here, where synth hands cameras to polarref."""
    from polarref.camera import Camera

    return Camera(model=camera.model, width=camera.width, height=camera.height,
                  params=np.asarray(camera.params))


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path`` and rename it into place."""
    atomic_write(path, data)


def write_gt(root: Path, camera: PinholeCamera, names: list[str], poses: list[Rigid3]) -> None:
    """COLMAP text model of the exact cameras in ``root/gt`` (empty points3D.txt)."""
    from polarref.model import Image, Reconstruction

    rec = Reconstruction(cameras={camera.camera_id: polarref_camera(camera)})
    for i, (name, pose) in enumerate(zip(names, poses), start=1):
        rec.images[i] = Image(image_id=i, name=name, camera_id=camera.camera_id, cam_from_world=pose)
    rec.write_text(root / "gt")


def load_scene(root: str | os.PathLike) -> Scene:
    """Load a rendered scene folder (raises PolarrefError if it is not one)."""
    root = Path(root)
    meta_path = root / SCENE_JSON
    if not meta_path.is_file():
        raise PolarrefError(f"not a rendered scene (no {SCENE_JSON}): {root}")
    try:
        meta = json.loads(meta_path.read_text())
        cam = meta["camera"]
        camera = PinholeCamera(int(cam["width"]), int(cam["height"]), np.array(cam["params"], float),
                               model=cam.get("model", "PINHOLE"))
        views = [View(int(v["image_id"]), v["name"], Rigid3(np.array(v["R"]), np.array(v["tvec"])),
                      root / "images" / v["name"], root / "depth" / (Path(v["name"]).stem + ".npy"))
                 for v in meta["views"]]
    except (KeyError, ValueError, TypeError) as exc:
        raise PolarrefError(f"malformed {meta_path}: {exc}") from exc
    missing = [v.name for v in views if not (v.image_path.is_file() and v.depth_path.is_file())]
    if missing:
        raise PolarrefError(f"scene {root} is incomplete: {len(missing)} of {len(views)} views not "
                            f"rendered (first: {missing[0]}); run polarref render again to resume")
    return Scene(root, camera, views, np.array(meta["scale"]["center"], float),
                 float(meta["scale"]["radius"]), meta)
