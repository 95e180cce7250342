"""Dense stage 4: fuse the filtered views into one coloured point cloud with normals.

Every view contributes the consistency-filtered (already multi-view averaged) points of its
pixels; the same surface is then present once per view that saw it, so the union is averaged on
a voxel grid (position, colour and normal per occupied voxel) whose cell is about one working
pixel's footprint: the density of a single view, without the duplicates.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.lib.recfunctions as rfn

from polarref.core.atomic import atomic_open
from polarref.dense.consistency import FilteredView


# One vertex of the fused cloud's PLY (write_point_cloud / read_point_cloud).
_PLY = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4"),
                 ("red", "u1"), ("green", "u1"), ("blue", "u1")])
_PLY_TYPES = {"<f8": "double", "<f4": "float", "|u1": "uchar"}


@dataclass
class PointCloud:
    """points (P, 3) float64, normals (P, 3) float64 unit (0 = unknown), colors (P, 3) uint8."""

    points: np.ndarray
    normals: np.ndarray
    colors: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def transformed(self, sim) -> "PointCloud":
        """Copy mapped by a :class:`polarref.core.geometry.Sim3` (normals rotated)."""
        return PointCloud(sim.apply(self.points), self.normals @ sim.R.T, self.colors)


def fuse(filtered: list[FilteredView], voxel: float) -> PointCloud:
    """Voxel-averaged union of the views' points; ``voxel`` > 0 in model units."""
    pts = [f.points for f in filtered if len(f.points)]
    if not pts:
        return PointCloud(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3), np.uint8))
    P = np.concatenate(pts)
    N = np.concatenate([f.normals for f in filtered if len(f.points)])
    C = np.concatenate([f.colors for f in filtered if len(f.points)]).astype(np.float64)
    keys = np.floor((P - P.min(0)) / voxel).astype(np.int64)
    _, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    m = len(counts)

    def mean(a: np.ndarray) -> np.ndarray:
        return np.stack([np.bincount(inv, weights=a[:, c], minlength=m) for c in range(a.shape[1])], 1) \
            / counts[:, None]

    normals = mean(N)
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.where(norm > 1e-9, normals / np.maximum(norm, 1e-12), 0.0)
    return PointCloud(mean(P), normals, np.clip(np.round(mean(C)), 0, 255).astype(np.uint8))


def write_point_cloud(path: Path, cloud: PointCloud) -> None:
    """Binary PLY: double x y z, float nx ny nz, uchar red green blue (atomic)."""
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(cloud)}"]
    header += [f"property {_PLY_TYPES[_PLY.fields[n][0].str]} {n}" for n in _PLY.names]
    header.append("end_header")
    flat = np.hstack([cloud.points, cloud.normals, cloud.colors.astype(np.float64)])
    data = rfn.unstructured_to_structured(flat, dtype=_PLY)
    with atomic_open(path) as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        fh.write(data.tobytes())


def read_point_cloud(path: Path) -> PointCloud:
    """Read a PLY written by :func:`write_point_cloud`."""
    with open(path, "rb") as fh:
        n = 0
        while (line := fh.readline().decode("ascii").strip()) != "end_header":
            if line.startswith("element vertex"):
                n = int(line.split()[2])
        data = np.frombuffer(fh.read(_PLY.itemsize * n), dtype=_PLY, count=n)
    columns = lambda names: rfn.structured_to_unstructured(data[list(names)])
    return PointCloud(columns(("x", "y", "z")).astype(np.float64), columns(("nx", "ny", "nz")).astype(np.float64),
                      columns(("red", "green", "blue")).astype(np.uint8))
