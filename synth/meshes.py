"""Triangle meshes as plain arrays: subdivision, normals, OBJ/PLY input, PLY output.

Vertices are (V, 3) float64, faces (F, 3) int64, counter-clockwise seen from outside.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from polarref.core.atomic import atomic_open
from polarref.core.errors import PolarrefError


def subdivide(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split every triangle into four at its edge midpoints (shared midpoints merged)."""
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    e.sort(axis=1)
    uniq, inv = np.unique(e, axis=0, return_inverse=True)
    mid = len(V) + inv.reshape(3, -1).T  # (F, 3): midpoint index of edges 01, 12, 20
    V2 = np.concatenate([V, 0.5 * (V[uniq[:, 0]] + V[uniq[:, 1]])])
    a, b, c = F[:, 0], F[:, 1], F[:, 2]
    m01, m12, m20 = mid[:, 0], mid[:, 1], mid[:, 2]
    F2 = np.concatenate([np.stack([a, m01, m20], 1), np.stack([m01, b, m12], 1),
                         np.stack([m20, m12, c], 1), np.stack([m01, m12, m20], 1)])
    return V2, F2


def icosphere(level: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere subdivided ``level`` times: 10 * 4**level + 2 vertices."""
    t = (1.0 + 5**0.5) / 2.0
    V = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                  [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    F = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                  [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                  [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], np.int64)
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    for _ in range(level):
        V, F = subdivide(V, F)
        V /= np.linalg.norm(V, axis=1, keepdims=True)
    return V, F


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3)."""
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n = np.zeros_like(V)
    for k in range(3):
        np.add.at(n, F[:, k], fn)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def mean_edge_length(V: np.ndarray, F: np.ndarray) -> float:
    return float(np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1).mean())


def read_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh from OBJ (v/f lines) or PLY; raises PolarrefError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise PolarrefError(f"mesh file not found: {path}")
    suffix = path.suffix.lower()
    try:
        if suffix == ".obj":
            V, F = _read_obj(path)
        elif suffix == ".ply":
            V, F = _read_ply(path)
        else:
            raise ValueError("unsupported extension (use .obj or .ply)")
    except (ValueError, IndexError, UnicodeDecodeError) as exc:
        raise PolarrefError(f"mesh {path} is not a readable triangle mesh: {exc}") from exc
    if len(V) < 4 or len(F) < 4:
        raise PolarrefError(f"mesh {path} is not a triangle mesh ({len(V)} vertices, {len(F)} faces)")
    if F.min() < 0 or F.max() >= len(V) or not np.isfinite(V).all():
        raise PolarrefError(f"mesh {path} has out-of-range face indices or non-finite vertices")
    return V, F


def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    verts, faces = [], []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "v":
                verts.append([float(x) for x in parts[1:4]])
            elif parts[0] == "f":
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    return np.array(verts, float).reshape(-1, 3), np.array(faces, np.int64).reshape(-1, 3)


_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4",
              "uint": "<u4", "float": "<f4", "double": "<f8", "int8": "i1", "uint8": "u1",
              "int16": "<i2", "uint16": "<u2", "int32": "<i4", "uint32": "<u4",
              "float32": "<f4", "float64": "<f8"}


def _read_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Binary little-endian PLY with a vertex element and a face list of triangles (ours)."""
    with open(path, "rb") as fh:
        if fh.readline().strip() != b"ply":
            raise ValueError("missing 'ply' magic")
        elements: list[tuple[str, int, list[tuple[str, ...]]]] = []
        fmt = None
        while True:
            line = fh.readline().decode("ascii").split()
            if not line:
                continue
            if line[0] == "format":
                fmt = line[1]
            elif line[0] == "element":
                elements.append((line[1], int(line[2]), []))
            elif line[0] == "property":
                elements[-1][2].append(tuple(line[1:]))
            elif line[0] == "end_header":
                break
        if fmt != "binary_little_endian":
            raise ValueError(f"only binary_little_endian PLY is supported, got {fmt}")
        V = F = None
        for name, count, props in elements:
            if name == "vertex":
                dt = np.dtype([(p[1], _PLY_TYPES[p[0]]) for p in props])
                data = np.frombuffer(fh.read(dt.itemsize * count), dtype=dt, count=count)
                V = np.stack([data["x"], data["y"], data["z"]], 1).astype(float)
            elif name == "face":
                (kind, ctype, itype, _), = props
                dt = np.dtype([("n", _PLY_TYPES[ctype]), ("i", _PLY_TYPES[itype], 3)])
                data = np.frombuffer(fh.read(dt.itemsize * count), dtype=dt, count=count)
                if (data["n"] != 3).any():
                    raise ValueError("only triangle faces are supported")
                F = data["i"].astype(np.int64)
            else:
                raise ValueError(f"unexpected PLY element {name!r}")
    if V is None or F is None:
        raise ValueError("PLY lacks vertex or face element")
    return V, F


def write_ply(path: str | os.PathLike, V: np.ndarray, F: np.ndarray, rgb: np.ndarray | None = None) -> None:
    """Binary PLY: float64 x y z (exact ground truth), optional uchar RGB, int32 triangles. Atomic."""
    path = Path(path)
    props = ["property double x", "property double y", "property double z"]
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    if rgb is not None:
        props += ["property uchar red", "property uchar green", "property uchar blue"]
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    header = "\n".join(["ply", "format binary_little_endian 1.0", f"element vertex {len(V)}", *props,
                        f"element face {len(F)}", "property list uchar int vertex_indices",
                        "end_header"]) + "\n"
    vert = np.empty(len(V), dtype=fields)
    vert["x"], vert["y"], vert["z"] = V[:, 0], V[:, 1], V[:, 2]
    if rgb is not None:
        vert["red"], vert["green"], vert["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    face = np.empty(len(F), dtype=[("n", "u1"), ("i", "<i4", 3)])
    face["n"], face["i"] = 3, F
    with atomic_open(path) as fh:
        fh.write(header.encode("ascii"))
        fh.write(vert.tobytes())
        fh.write(face.tobytes())
