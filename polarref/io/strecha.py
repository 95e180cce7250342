"""Strecha et al. (CVPR 2008) ground-truth ``*.camera`` files.

Layout (9 rows): rows 1-3 K; row 4 radial distortion (zeros in the published data); rows 5-7
R, the camera-to-world rotation (``world_from_cam``); row 8 the camera centre C; row 9 ``width
height``. Projection ``x ~ K R^T (X - C)``, so ``cam_from_world = (R^T, -R^T C)``.

Verified on fountain-P11 (tests/io/test_io_strecha.py) by the epipolar (Sampson) error of SIFT
matches between neighbouring views under the ground-truth poses: median 0.11-0.19 px at full
resolution on pairs 3-4, 4-5, 5-6, 3-5 (97-98 % of ratio-test matches below 2 px); reading R as
world-to-camera instead gives ~80-95 px.

Pixel origin: the data cannot decide it. Over 19 view pairs (25,657 SIFT matches, full
resolution) the RMS Sampson error is 0.3425 / 0.3418 / 0.3422 / 0.3473 px when OpenCV keypoints
are shifted by 0 / +0.25 / +0.5 / -0.5 px, and per-pair optima scatter from -0.75 to +1.75 px.
polarref assumes the common multi-view convention that K puts pixel centres at integer
coordinates (OpenCV, Hartley-Zisserman), so ``pixel_offset = 0.5`` is added to cx, cy to reach
COLMAP's corner origin; pass ``pixel_offset=0`` to keep K as stored.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.camera import Camera
from polarref.core.geometry import Rigid3, skew
from polarref.io.text import FormatError, parse_numbers, read_lines
from polarref.model import Image, Reconstruction


@dataclass(frozen=True)
class StrechaView:
    """One ground-truth view.

    Attributes:
        name: image file name (the ``.camera`` file name without that suffix).
        camera: PINHOLE :class:`polarref.camera.Camera` (full resolution).
        cam_from_world: :class:`polarref.core.geometry.Rigid3`.
        distortion: (3,) the stored row 4 (zeros in the published data).
    """

    name: str
    camera: Camera
    cam_from_world: Rigid3
    distortion: np.ndarray


def read_strecha_camera(path, pixel_offset: float = 0.5) -> StrechaView:
    """Read one ``*.camera`` file; FormatError names the file and line.

    ``pixel_offset`` is added to cx, cy (module docstring: K -> COLMAP pixel convention).
    """
    path = Path(path)
    rows = [(i + 1, s.split()) for i, s in enumerate(read_lines(path)) if s.strip()]
    if len(rows) != 9:
        raise FormatError(path, rows[-1][0] if rows else 1,
                          f"expected 9 non-empty rows (K, distortion, R, C, size), found {len(rows)}")
    vals = [parse_numbers(path, n, t, float, 3, "values") for n, t in rows[:8]]
    size = parse_numbers(path, rows[8][0], rows[8][1], float, 2, "values (width height)")
    K, dist, R, C = np.array(vals[:3]), np.array(vals[3]), np.array(vals[4:7]), np.array(vals[7])
    if K[1, 0] != 0 or np.any(K[2] != [0, 0, 1]) or not (K[0, 0] > 0 and K[1, 1] > 0):
        raise FormatError(path, rows[0][0], f"not a calibration matrix: {K.tolist()}")
    if abs(K[0, 1]) > 1e-9 * K[0, 0]:
        raise FormatError(path, rows[0][0], f"skew {K[0, 1]} is not supported (PINHOLE)")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0:
        raise FormatError(path, rows[4][0], "rows 5-7 are not a rotation matrix")
    # the files print 6 digits; re-orthonormalize so downstream code gets an exact rotation
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    width, height = size
    if width != int(width) or height != int(height) or width <= 0 or height <= 0:
        raise FormatError(path, rows[8][0], f"bad image size {size}")
    camera = Camera("PINHOLE", int(width), int(height),
                    [K[0, 0], K[1, 1], K[0, 2] + pixel_offset, K[1, 2] + pixel_offset])
    name = path.name[:-len(".camera")] if path.name.endswith(".camera") else path.stem
    return StrechaView(name, camera, Rigid3(R.T, -R.T @ C), dist)


def read_strecha_folder(folder, pixel_offset: float = 0.5) -> list[StrechaView]:
    """All ``*.camera`` files of a folder, sorted by name."""
    folder = Path(folder)
    files = sorted(folder.glob("*.camera"))
    if not files:
        raise FormatError(folder, None, "no *.camera files")
    return [read_strecha_camera(f, pixel_offset) for f in files]


def read_ground_truth(folder, names=None, pixel_offset: float = 0.5):
    """Ground truth as a :class:`polarref.model.Reconstruction` (no points).

    Args:
        folder: folder with ``<name>.camera`` files.
        names: image names in the wanted order (default: every ``*.camera`` file, sorted);
            image ids are 1, 2, ... in this order.
        pixel_offset: added to cx, cy (see module docstring).

    Cameras with identical intrinsics share one camera id.
    """
    folder = Path(folder)
    if names is None:
        views = read_strecha_folder(folder, pixel_offset)
    else:
        views = [read_strecha_camera(folder / f"{n}.camera", pixel_offset) for n in names]
    rec = Reconstruction()
    ids: dict = {}
    for i, v in enumerate(views, start=1):
        cam_id = ids.setdefault(v.camera, len(ids) + 1)
        rec.cameras[cam_id] = v.camera
        rec.images[i] = Image(i, v.name, cam_id, v.cam_from_world)
    return rec


def fundamental_matrix(view_a: StrechaView, view_b: StrechaView) -> np.ndarray:
    """(3, 3) F with ``x_b^T F x_a = 0`` for homogeneous pixels of the two views."""
    rel = view_b.cam_from_world.compose(view_a.cam_from_world.inverse())
    Ka_inv = np.linalg.inv(view_a.camera.calibration_matrix())
    Kb_inv = np.linalg.inv(view_b.camera.calibration_matrix())
    return Kb_inv.T @ skew(rel.t) @ rel.R @ Ka_inv


def sampson_error(F: np.ndarray, uv_a: np.ndarray, uv_b: np.ndarray) -> np.ndarray:
    """First-order geometric epipolar error (N,) in pixels for matches (N, 2) x2."""
    xa = np.c_[uv_a, np.ones(len(uv_a))]
    xb = np.c_[uv_b, np.ones(len(uv_b))]
    Fxa = xa @ F.T
    Ftxb = xb @ F
    num = np.sum(xb * Fxa, axis=1)
    den = Fxa[:, 0] ** 2 + Fxa[:, 1] ** 2 + Ftxb[:, 0] ** 2 + Ftxb[:, 1] ** 2
    return np.abs(num) / np.sqrt(den)
