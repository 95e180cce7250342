"""One reading of a scene folder on disk: where its images are and which ground truth it has.

Layouts understood (``polarref sfm``, ``polarref compare`` and ``polarref dense`` all use this):

* images directly in the folder, or in ``images/``;
* ground truth as Strecha ``*.camera`` files in ``gt_dense_cameras/`` (the Strecha
  fountain/Herz-Jesu sets; preferred when both exist), or as a COLMAP model in ``gt/``;
* a rendered scene (``scene.json``, optional ``mesh.ply``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from polarref.camera import Camera
from polarref.core.errors import PolarrefError
from polarref.model.colmap import read_model
from polarref.model.run import SkippedImage  # noqa: F401 (re-exported: the readers name it)

if TYPE_CHECKING:
    from polarref.model import Reconstruction

# Image files every stage reads. No ".exr": OpenCV decodes EXR only with OPENCV_IO_ENABLE_OPENEXR.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


def list_images(image_dir: str | Path) -> list[Path]:
    """Image files directly inside ``image_dir``, sorted by name."""
    return sorted(p for p in Path(image_dir).iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


@dataclass(frozen=True)
class Scene:
    """One scene as every stage sees it: the one scene record of polarref.

    :func:`discover` fills the folder's listing (nothing is read but the file names);
    :func:`polarref.compare.run.scenes.prepare` also the fixed camera, the ground truth keyed by the
    image names the methods see (after any downscaling) and how the scene came about. It lives
    with the readers because its ground truth is read by them (COLMAP folder, Strecha cameras).
    """

    root: Path
    image_dir: Path                 # root/images if present, else root (or downscaled copies)
    image_names: list[str]          # sorted file names in image_dir
    gt_kind: str = ""               # "colmap" (gt/), "strecha" (gt_dense_cameras/) or "" (none)
    rendered: bool = False          # has scene.json (a synth render)
    mesh_path: Path | None = None   # root/mesh.ply when present
    # prepared (polarref compare, twins):
    name: str = ""                  # e.g. "comet-small", a twin, or the folder's name
    kind: str = ""                  # synthetic | real
    source: str = ""                # as given by the user
    camera: Camera | None = None    # the fixed intrinsics every method uses
    gt: Reconstruction | None = None  # ground truth keyed by image_names, or None
    preset: str = ""                # render / compare preset name ("" when the folder did not record one)
    seed: int = -1                  # render seed (-1 for real data)
    downscale: float = 1.0          # original width / used width
    render_s: float = 0.0           # seconds spent rendering in this run (0 when reused)
    mitsuba_variant: str = ""

    def read_ground_truth(self) -> Reconstruction | None:
        """The ground-truth cameras/poses (image names as in ``image_names``), or None without any.

        Strecha ``.camera`` files give the principal point with a +0.5 shift to COLMAP's
        corner pixel origin (see ``polarref.io.strecha``).
        """
        from polarref.model import Reconstruction

        if self.gt_kind == "colmap":
            return read_model(self.root / "gt")
        if self.gt_kind == "strecha":
            from polarref.io import strecha

            return strecha.read_ground_truth(self.root / "gt_dense_cameras", self.image_names)
        return None


def discover(root: str | Path) -> Scene:
    """Read the layout of the scene folder ``root``; PolarrefError when it is not a folder."""
    root = Path(root)
    if not root.is_dir():
        raise PolarrefError(f"scene folder not found: {root}")
    image_dir = root / "images" if (root / "images").is_dir() else root
    names = [p.name for p in list_images(image_dir)]
    gt_kind = "strecha" if (root / "gt_dense_cameras").is_dir() else "colmap" if (root / "gt").is_dir() else ""
    mesh = root / "mesh.ply"
    return Scene(root, image_dir, names, gt_kind, (root / "scene.json").is_file(),
                 mesh if mesh.is_file() else None)
