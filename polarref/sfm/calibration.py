"""Cameras from EXIF when no calibration is given, and the report of the refined cameras.

EXIF focal length: ``pycolmap.infer_camera_from_image`` (COLMAP's reader: the 35 mm equivalent
focal length, else the focal length in mm with COLMAP's sensor-width database for the make
and model, else the focal-plane resolution). Without any of these the focal length is
``DEFAULT_FOCAL_FACTOR * max(width, height)`` (COLMAP's ``default_focal_length_factor``),
with one warning naming how many images got it. Principal point: the image centre. Model:
SIMPLE_RADIAL (COLMAP's default) with k = 0.

Grouping (``mode``): ``per-model`` (default) one camera per (make, model, width, height);
``single`` one camera for all images (all the same size); ``per-image`` one each. A group's
focal length is the median of its images' EXIF focal lengths.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from polarref.camera import Camera
from polarref.core.errors import PolarrefError

log = logging.getLogger(__name__)

DEFAULT_FOCAL_FACTOR = 1.2
CAMERA_MODES = ("per-model", "single", "per-image")
EXIF_MODEL = "SIMPLE_RADIAL"
# COLMAP's ba_refine_* defaults are focal and extra params, not pp; the mapper refines pp only in
# its final rounds, only with enough images per camera, and keeps it only near the centre
# (sfm/mapper.py: pp_min_images, pp_max_offset)
EXIF_REFINE = ("focal", "pp", "dist")
# Focal lengths outside [0.1, 20] x max(width, height) (a 360 deg to a 3 deg field of view, about
# 3.6 mm to 720 mm at 35 mm equivalent) are a broken tag (65535, 1), not a lens.
FOCAL_FACTOR_RANGE = (0.1, 20.0)


def check_focal(focal_px: float, width: int, height: int, what: str) -> None:
    """PolarrefError naming ``what`` when ``focal_px`` is not a physically possible focal length."""
    lo, hi = (k * max(width, height) for k in FOCAL_FACTOR_RANGE)
    if not (np.isfinite(focal_px) and lo <= focal_px <= hi):
        raise PolarrefError(f"{what}: focal length {focal_px:.6g} px is impossible for a {width}x{height} image "
                            f"(expected {FOCAL_FACTOR_RANGE[0]:g}..{FOCAL_FACTOR_RANGE[1]:g} x {max(width, height)} "
                            "px); fix the EXIF tag or give the camera (MODEL:params)")


@dataclass(frozen=True)
class ExifCamera:
    """What EXIF says about one image."""

    make: str
    model: str
    focal_px: float | None  # None: no usable focal length in EXIF


def read_exif(path: Path) -> ExifCamera:
    """Make, model and focal length in px of one image (empty / None where EXIF lacks them)."""
    import pycolmap

    make = model = ""
    try:
        from PIL import Image  # Pillow ships with matplotlib; only make/model come from it

        with Image.open(path) as im:
            ex = im.getexif()
            make, model = str(ex.get(0x010F, "")).strip(), str(ex.get(0x0110, "")).strip()
    except Exception:  # no Pillow, unreadable EXIF: group by size only
        pass
    try:
        cam = pycolmap.infer_camera_from_image(str(path))
    except Exception:
        return ExifCamera(make, model, None)
    ok = bool(cam.has_prior_focal_length) and np.isfinite(cam.params[0]) and cam.params[0] > 0
    return ExifCamera(make, model, float(cam.params[0]) if ok else None)


def cameras_from_exif(paths: list[Path], sizes: list[tuple[int, int]], mode: str = "per-model"):
    """(cameras, camera index per image (N,), source per camera "exif" | "default").

    ``sizes``: (width, height) per image, as read for feature extraction.
    """
    if mode not in CAMERA_MODES:
        raise PolarrefError(f"unknown camera mode {mode!r}; choose {', '.join(CAMERA_MODES)}")
    infos = [read_exif(p) for p in paths]
    for p, info, (w, h) in zip(paths, infos, sizes):
        if info.focal_px is not None:
            check_focal(info.focal_px, w, h, f"{p} (EXIF)")
    if mode == "single":
        if len(set(sizes)) > 1:
            raise PolarrefError(f"one camera for all images, but the images have {len(set(sizes))} different sizes "
                                f"({', '.join(f'{w}x{h}' for w, h in sorted(set(sizes))[:3])})")
        keys = [0] * len(paths)
    elif mode == "per-image":
        keys = list(range(len(paths)))
    else:
        keys = [(i.make, i.model, w, h) for i, (w, h) in zip(infos, sizes)]
    order = {}
    idx = np.array([order.setdefault(k, len(order)) for k in keys], np.int64)
    missing = [p.name for p, i in zip(paths, infos) if i.focal_px is None]
    if missing:
        # not a warning: the guess only starts P4Pf / BA, which estimate the focal length
        log.info("%d of %d images have no EXIF focal length (%s%s): starting from f = %.1f x max(width, "
                 "height), estimated during registration", len(missing), len(paths), ", ".join(missing[:3]),
                 ", ..." if len(missing) > 3 else "", DEFAULT_FOCAL_FACTOR)
    cameras, sources = [], []
    for g in range(len(order)):
        members = np.flatnonzero(idx == g)
        w, h = sizes[int(members[0])]
        focals = [infos[i].focal_px for i in members if infos[i].focal_px is not None]
        f = float(np.median(focals)) if focals else DEFAULT_FOCAL_FACTOR * max(w, h)
        cameras.append(Camera(EXIF_MODEL, w, h, [f, w / 2.0, h / 2.0, 0.0]))
        sources.append("exif" if focals else "default")
    return cameras, idx, sources


@dataclass
class CameraReport:
    """One camera of a reconstruction: start and refined intrinsics, error against GT if known."""

    camera_id: int
    model: str
    width: int
    height: int
    names: tuple[str, ...]
    initial: list[float]
    refined: list[float]
    source: str  # exif | default | given | gt
    num_images: int
    gt: list[float] | None = None  # GT params when the GT camera has the same model
    focal_error_rel: float | None = None  # |f - f_gt| / f_gt (mean of fx, fy)
    principal_point_error_px: float | None = None
    distortion_error: list[float] | None = None  # refined - GT, per coefficient

    def to_dict(self) -> dict:
        return asdict(self)


def camera_reports(initial: list, refined: list, sources: list[str], camera_of_image: np.ndarray,
                   names: list[str], gt=None) -> list[CameraReport]:
    """Reports of cameras ``refined`` (started from ``initial``); GT camera = that of the
    group's first image in ``gt`` (matched by image name)."""
    gt_by_name = {im.name: gt.cameras[im.camera_id] for im in gt.images.values()} if gt else {}
    out = []
    for c, (c0, c1) in enumerate(zip(initial, refined)):
        members = np.flatnonzero(camera_of_image == c)
        rep = CameraReport(c + 1, c1.model, c1.width, c1.height, tuple(c1.param_names),
                           c0.params.tolist(), c1.params.tolist(), sources[c], len(members))
        g = next((gt_by_name[names[i]] for i in members if names[i] in gt_by_name), None)
        if g is not None:
            s = c1.width / g.width  # GT of another resolution: compare in our pixels
            gf = 0.5 * (g.fx + g.fy) * s
            rep.focal_error_rel = float(abs(0.5 * (c1.fx + c1.fy) - gf) / gf)
            rep.principal_point_error_px = float(np.linalg.norm(
                c1.principal_point - g.principal_point * s))
            if g.model == c1.model:
                gp = g.rescaled(s).params if s != 1 else g.params
                rep.gt = gp.tolist()
                rep.distortion_error = [float(a - b) for a, b in zip(c1.distortion, g.distortion)]
        out.append(rep)
    return out
