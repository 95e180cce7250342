"""The files ``polarref sfm`` writes for a finished model: COLMAP text and/or binary, and a PLY.

COLMAP text comes from :meth:`Reconstruction.write_text`; the binary model is pycolmap's own
writer (``Reconstruction.write_binary``), so COLMAP, pycolmap and hloc read it natively;
``points3D.ply`` (coloured, binary) opens directly in MeshLab or CloudCompare.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np

from polarref.io.ply import write_points_ply
from polarref.model import Reconstruction
from polarref.model.colmap import to_pycolmap

FORMATS = ("text", "binary", "both")
BINARY_FILES = ("cameras.bin", "images.bin", "points3D.bin", "rigs.bin", "frames.bin")


def write_binary(rec: Reconstruction, model_dir: Path) -> None:
    """COLMAP binary files via pycolmap, written to a scratch folder and moved in file by file."""
    model_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=model_dir, prefix=".bin-") as tmp:
        to_pycolmap(rec).write_binary(tmp)
        for p in sorted(Path(tmp).iterdir()):
            shutil.move(str(p), model_dir / p.name)


def write_ply(rec: Reconstruction, path: Path) -> Path:
    """All 3D points with their colours, in point-id order."""
    ids, xyz = rec.points_array()
    rgb = np.array([rec.points3D[int(i)].color for i in ids], dtype=np.uint8).reshape(-1, 3)
    return write_points_ply(path, xyz, rgb, comment=f"polarref sparse model, {len(ids)} points")


def write_model(rec: Reconstruction, model_dir: str | Path, model_format: str = "text") -> list[Path]:
    """Write ``rec`` into ``model_dir`` as ``model_format`` (text | binary | both) plus points3D.ply.

    A format not asked for is not left behind from an earlier run (so the folder is one model).
    """
    if model_format not in FORMATS:
        raise ValueError(f"unknown model format {model_format!r} (choose from {', '.join(FORMATS)})")
    model_dir = Path(model_dir)
    model_dir.mkdir(parents=True, exist_ok=True)
    if model_format in ("text", "both"):
        rec.write_text(model_dir)
    else:
        for name in ("cameras.txt", "images.txt", "points3D.txt"):
            (model_dir / name).unlink(missing_ok=True)
    if model_format in ("binary", "both"):
        write_binary(rec, model_dir)
    else:
        for name in BINARY_FILES:
            (model_dir / name).unlink(missing_ok=True)
    write_ply(rec, model_dir / "points3D.ply")
    return sorted(model_dir.iterdir())
