"""A small binary little-endian PLY writer for coloured point clouds.

MeshLab, CloudCompare, Open3D and ``plyfile`` all read this layout: one ``vertex`` element with
float32 ``x y z`` and uchar ``red green blue``. float32 keeps 7 significant digits, far below
any reconstruction error we report; the COLMAP model beside it keeps float64.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from polarref.core.atomic import atomic_open

_VERTEX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                    ("red", "u1"), ("green", "u1"), ("blue", "u1")])


def write_points_ply(path: str | Path, xyz: np.ndarray, rgb: np.ndarray | None = None,
                     comment: str = "") -> Path:
    """Write points ``xyz`` (N, 3) with colours ``rgb`` (N, 3) uint8 (grey when None), atomically.

    Raises:
        ValueError: wrong shapes or non-finite coordinates (a PLY with NaN breaks most viewers).
    """
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    if rgb is None:
        rgb = np.full((len(xyz), 3), 160, dtype=np.uint8)
    rgb = np.asarray(rgb)
    if rgb.shape != xyz.shape:
        raise ValueError(f"PLY: colours {rgb.shape} do not match points {xyz.shape}")
    if not np.isfinite(xyz).all():
        raise ValueError("PLY: non-finite point coordinates")
    data = np.empty(len(xyz), dtype=_VERTEX)
    for k, axis in enumerate("xyz"):
        data[axis] = xyz[:, k]
    for k, channel in enumerate(("red", "green", "blue")):
        data[channel] = np.clip(rgb[:, k], 0, 255)
    header = ["ply", "format binary_little_endian 1.0"]
    if comment:
        header.append("comment " + comment.replace("\n", " "))
    header += [f"element vertex {len(xyz)}", "property float x", "property float y", "property float z",
               "property uchar red", "property uchar green", "property uchar blue", "end_header"]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(data.tobytes())
    return path
