"""Image size and feature budget of a run: the one rule, as pycolmap users expect it.

pycolmap's SIFT extraction detects on images downscaled to ``max_image_size`` = 3200 px (longer
side) and keeps at most ``max_num_features`` = 8192 keypoints. :func:`choose` decides, once per
run, before any image is decoded:

- Photo folders (cameras from EXIF, no ``gt/``) with untouched feature settings: exactly
  pycolmap's size and budget.
- Photo folders with only the image size changed (``--max-image-size`` alone, 0 = full size):
  pycolmap's 8192 up to 3200 px, the budget scaling with the side above. Not down: with the
  budget linear in the side below 3200 px (4096 at 1600), the Sceaux photos at 1600 px
  registered 10 of 11 images with 4,898 tie points, with 8192 11 of 11 with 10,266 (pycolmap 11,
  8,373).
- Anything else: as configured, except that a full-resolution setting that was not asked for
  (``SfMConfig.full_size`` false) detects images larger than 3200 px at 3200 px: SIFT's memory
  grows with the pixels (commands/sfm.py: ~235 B per detection pixel, 5.6 GB for 24 MP).
  Smaller images are untouched, so rendered scenes keep their settings and cache.
"""

from __future__ import annotations

import dataclasses
import logging
import warnings
from dataclasses import dataclass
from pathlib import Path

from polarref.sfm.features import FeatureConfig, list_images

log = logging.getLogger(__name__)

COLMAP_MAX_IMAGE_SIZE = 3200   # px, pycolmap SiftExtractionOptions.max_image_size
COLMAP_MAX_FEATURES = 8192     # pycolmap SiftExtractionOptions.max_num_features


@dataclass(frozen=True)
class FeatureBudget:
    """What metrics.json states about image size and keypoints."""

    max_image_size: int        # px, longer side detection runs at (0 = full resolution)
    max_num_features: int      # keypoints kept per image
    rule: str                  # how they were chosen (see the module docstring)
    mean_detection_side: float = 0.0   # px, mean longer side SIFT actually ran on
    mean_keypoints: float = 0.0        # per image, after the budget


def scaled_features(max_image_size: int) -> int:
    """The budget for a maximum image size (0 = full size): pycolmap's 8192 up to 3200 px,
    linear in the side above."""
    if max_image_size <= COLMAP_MAX_IMAGE_SIZE:
        return COLMAP_MAX_FEATURES
    return round(COLMAP_MAX_FEATURES * max_image_size / COLMAP_MAX_IMAGE_SIZE)


def choose(features: FeatureConfig, default: FeatureConfig, *, photos: bool, full_size: bool,
           sizes: list[tuple[int, int]]) -> tuple[FeatureConfig, str]:
    """(settings, rule) of a run (see the module docstring).

    Args:
        features: the configured settings; ``default``: the untouched ones.
        photos: a folder of photos (cameras from EXIF), not a calibrated or rendered scene.
        full_size: ``max_image_size`` 0 was asked for (``--max-image-size 0``), not defaulted.
        sizes: (width, height) of every image, from the file headers (:func:`header_sizes`).
    """
    rep = dataclasses.replace
    largest = max((max(wh) for wh in sizes), default=0)
    if photos and features == default and not full_size:
        return (rep(features, max_image_size=COLMAP_MAX_IMAGE_SIZE, max_num_features=COLMAP_MAX_FEATURES),
                f"photos: pycolmap's max_image_size {COLMAP_MAX_IMAGE_SIZE}, max_num_features {COLMAP_MAX_FEATURES}")
    if photos and rep(features, max_image_size=default.max_image_size) == default:
        side = features.max_image_size
        n = scaled_features(min(side, largest) if side else largest)
        given = f"max_image_size {side} given" if side else f"full size asked (largest side {largest} px)"
        return (rep(features, max_num_features=n),
                f"photos: {given}, max_num_features {n} "
                f"({COLMAP_MAX_FEATURES} up to {COLMAP_MAX_IMAGE_SIZE} px, linear in the side above)")
    if features.max_image_size == 0 and not full_size and largest > COLMAP_MAX_IMAGE_SIZE:
        big = sum(max(wh) > COLMAP_MAX_IMAGE_SIZE for wh in sizes)
        log.warning("%d image(s) larger than %d px (largest side %d px): features detected at %d px to bound "
                    "SIFT's memory (--max-image-size 0 keeps full size)", big, COLMAP_MAX_IMAGE_SIZE, largest,
                    COLMAP_MAX_IMAGE_SIZE)
        return (rep(features, max_image_size=COLMAP_MAX_IMAGE_SIZE),
                f"as configured, images over {COLMAP_MAX_IMAGE_SIZE} px detected at {COLMAP_MAX_IMAGE_SIZE} px "
                "(SIFT memory; full size not asked)")
    return features, "as configured"


def header_size(path: Path) -> tuple[int, int] | None:
    """(width, height) from the file's header (no decoding); None when unreadable."""
    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():  # a huge image is what the size rule is for, not news
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                return im.size
    except (OSError, UnidentifiedImageError, ValueError, Image.DecompressionBombError):
        return None


def header_sizes(image_dir: Path) -> list[tuple[int, int]]:
    """(width, height) of every readable image in ``image_dir`` (none when it is not a folder)."""
    paths = list_images(image_dir) if Path(image_dir).is_dir() else []
    return [wh for wh in map(header_size, paths) if wh is not None]


def describe(features: FeatureConfig, rule: str, sizes: list[tuple[int, int]],
             keypoints: list[int]) -> FeatureBudget:
    """The record of what ran: ``sizes`` (width, height) of the originals, keypoints per image."""
    cap = features.max_image_size
    sides = [min(max(w, h), cap) if cap else max(w, h) for w, h in sizes]
    return FeatureBudget(cap, features.max_num_features, rule,
                         float(sum(sides) / max(len(sides), 1)), float(sum(keypoints) / max(len(keypoints), 1)))
