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


@dataclass
class SceneFolder:
    """What a scene folder holds (nothing is read yet but the listing)."""

    root: Path
    image_dir: Path                 # root/images if present, else root
    image_names: list[str]          # sorted file names in image_dir
    gt_kind: str                    # "colmap" (gt/), "strecha" (gt_dense_cameras/) or "" (none)
    rendered: bool                  # has scene.json (a synth render)
    mesh_path: Path | None          # root/mesh.ply when present

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


def discover(root: str | Path) -> SceneFolder:
    """Read the layout of the scene folder ``root``; PolarrefError when it is not a folder."""
    root = Path(root)
    if not root.is_dir():
        raise PolarrefError(f"scene folder not found: {root}")
    image_dir = root / "images" if (root / "images").is_dir() else root
    names = [p.name for p in list_images(image_dir)]
    gt_kind = "strecha" if (root / "gt_dense_cameras").is_dir() else "colmap" if (root / "gt").is_dir() else ""
    mesh = root / "mesh.ply"
    return SceneFolder(root, image_dir, names, gt_kind, (root / "scene.json").is_file(),
                       mesh if mesh.is_file() else None)
