"""Stage 1: SIFT keypoints and descriptors (OpenCV), in COLMAP pixel convention.

OpenCV puts the centre of the first pixel at (0, 0); COLMAP (and polarref) at (0.5, 0.5), which
is +0.5. But OpenCV's SIFT reports keypoints a further +0.25 px off (measured: a Gaussian blob
centred on pixel (70, 50) is found at (70.24, 50.24), at every octave): it doubles the image for
the first octave with a pixel-centre-aligned resize and maps the keypoints back with a plain
factor 0.5, which shifts them by half an upsampled pixel. So the conversion is
``+0.5 - OPENCV_SIFT_BIAS = +0.25`` (the pycolmap notes measured COLMAP's SIFT at OpenCV + 0.25,
which agrees). Images larger than ``max_image_size`` are downscaled for detection
(INTER_AREA) and the keypoints are scaled back to the original resolution: with the corner
origin this is an exact multiplication by ``W / w`` (x) and ``H / h`` (y), so the camera of the
original images stays valid (COLMAP does the same).
"""

from __future__ import annotations

import logging
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.core.atomic import atomic_open
from polarref.io.scene_folder import IMAGE_SUFFIXES, list_images  # noqa: F401 (re-exported)

log = logging.getLogger(__name__)

OPENCV_SIFT_BIAS = 0.25  # px (detection resolution) added by OpenCV's 2x first-octave upsampling


@dataclass(frozen=True)
class FeatureConfig:
    """SIFT settings."""

    max_num_features: int = 4096      # strongest keypoints kept per image (by detector response)
    contrast_threshold: float = 0.01  # OpenCV SIFT contrastThreshold (OpenCV default 0.04 finds too few on synthetic
    #                                   renders; 0.02 equals COLMAP's peak threshold; 0.01 gave 28-view comet 0.048
    #                                   vs 0.066 deg, 1090 -> ~2000 keypoints per image)
    edge_threshold: float = 10.0      # OpenCV SIFT edgeThreshold (Lowe's r)
    n_octave_layers: int = 3          # scales per octave
    sigma: float = 1.6                # blur of the first octave
    root_sift: bool = True            # Hellinger kernel (Arandjelovic & Zisserman 2012): L1, sqrt, so dot = similarity
    max_image_size: int = 0           # 0 = full resolution, else downscale so max(w, h) <= this
    selection: str = "response"       # over max_num_features: keep the strongest ("response") or drop the finest
    #                                   octaves first ("coarse", COLMAP's rule), by response within an octave


@dataclass
class Features:
    """Keypoints of one image.

    Attributes:
        name: image file name (relative to the image folder).
        width, height: original image size in px.
        keypoints: (K, 2) float64, COLMAP pixel convention, original resolution.
        descriptors: (K, 128) float16, unit L2 norm (RootSIFT or L2-normalized SIFT), rounded
            to float16 once, so cached and fresh runs match bit for bit; consumers compute in
            float32 (an exact conversion). Held as float16: at 631 views of 4096 features the
            float32 copies were 1.3 GB of the features stage's 2.4 GB peak.
        scales: (K,) keypoint size in original px; orientations: (K,) degrees.
        colors: (K, 3) uint8 RGB sampled at the keypoints.
    """

    name: str
    width: int
    height: int
    keypoints: np.ndarray
    descriptors: np.ndarray
    scales: np.ndarray
    orientations: np.ndarray
    colors: np.ndarray


def read_image(path: Path) -> np.ndarray | None:
    """BGR uint8 image, or None when OpenCV cannot decode it."""
    import cv2

    try:  # decode from bytes: cv2.imread would print its own warning besides ours
        data = np.fromfile(path, dtype=np.uint8)
    except OSError:
        return None
    img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if img is None or img.size == 0:
        return None
    if img.dtype != np.uint8:  # 16-bit PNG/TIFF: keep the range, drop precision
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img


def normalize_descriptors(desc: np.ndarray, root_sift: bool) -> np.ndarray:
    """(K, 128) raw SIFT -> (K, 128) float32 with unit L2 norm (RootSIFT if asked)."""
    d = np.asarray(desc, dtype=np.float32)
    if root_sift:
        d = np.sqrt(d / np.maximum(np.abs(d).sum(1, keepdims=True), 1e-12))
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def extract(image: np.ndarray, name: str, config: FeatureConfig) -> Features:
    """Detect SIFT on one BGR image (H, W, 3) uint8."""
    import cv2

    height, width = image.shape[:2]
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    scale = 1.0
    if config.max_image_size and max(width, height) > config.max_image_size:
        scale = config.max_image_size / max(width, height)
        gray = cv2.resize(gray, (round(width * scale), round(height * scale)), interpolation=cv2.INTER_AREA)
    sx, sy = width / gray.shape[1], height / gray.shape[0]
    if config.selection not in ("response", "coarse"):
        raise ValueError(f"selection must be 'response' or 'coarse', got {config.selection!r}")
    # "coarse" needs every keypoint to choose from (nfeatures=0: no cap inside OpenCV)
    cap = config.max_num_features if config.selection == "response" else 0
    sift = cv2.SIFT_create(nfeatures=cap, nOctaveLayers=config.n_octave_layers,
                           contrastThreshold=config.contrast_threshold,
                           edgeThreshold=config.edge_threshold, sigma=config.sigma)
    kps, desc = sift.detectAndCompute(gray, None)
    if desc is None or not kps:
        return Features(name, width, height, np.zeros((0, 2)), np.zeros((0, 128), np.float16),
                        np.zeros(0), np.zeros(0), np.zeros((0, 3), np.uint8))
    # OpenCV may return a few more than nfeatures (ties in response); keep the strongest.
    response = np.array([k.response for k in kps])
    if config.selection == "coarse":
        octave = np.array([((k.octave & 255) ^ 128) - 128 for k in kps])  # signed byte: -1 = upsampled
        order = np.lexsort((-response, -octave))[: config.max_num_features]
    else:
        order = np.argsort(-response, kind="stable")[: config.max_num_features]
    pts = np.array([kps[i].pt for i in order], dtype=np.float64)
    xy = (pts + 0.5 - OPENCV_SIFT_BIAS) * np.array([sx, sy])
    ij = np.clip(np.floor(xy).astype(int), 0, [width - 1, height - 1])
    colors = image[ij[:, 1], ij[:, 0], ::-1].astype(np.uint8)
    return Features(
        name=name, width=width, height=height, keypoints=xy,
        descriptors=normalize_descriptors(desc[order], config.root_sift).astype(np.float16),
        scales=np.array([kps[i].size for i in order]) * sx,
        orientations=np.array([kps[i].angle for i in order]),
        colors=colors,
    )


def _arrays(feats: list[Features]):
    """(name, array) of the ``.npz`` members, one image at a time."""
    yield "names", np.array([f.name for f in feats])
    yield "sizes", np.array([[f.width, f.height] for f in feats]).reshape(-1, 2)
    for i, f in enumerate(feats):
        yield f"kp{i}", f.keypoints
        yield f"de{i}", f.descriptors.astype(np.float16, copy=False)  # exact: extract() rounded
        yield f"sc{i}", f.scales
        yield f"or{i}", f.orientations
        yield f"co{i}", f.colors


def save(path: Path, feats: list[Features]) -> None:
    """Store features of several images in one ``.npz`` (atomic rename), written member by
    member as ``np.savez`` lays them out: its dict of every float16 copy at once was a quarter
    of the features stage's peak memory at 493 views (2.0 GB)."""
    with atomic_open(path) as fh, zipfile.ZipFile(fh, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name, arr in _arrays(feats):
            with zf.open(name + ".npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(arr), allow_pickle=False)


def load(path: Path) -> list[Features]:
    with np.load(path, allow_pickle=False) as z:
        names, sizes = z["names"], z["sizes"]
        return [Features(str(n), int(w), int(h), z[f"kp{i}"], z[f"de{i}"],
                         z[f"sc{i}"], z[f"or{i}"], z[f"co{i}"])
                for i, (n, (w, h)) in enumerate(zip(names, sizes))]
