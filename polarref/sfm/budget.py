"""Image size and feature budget of a run, as pycolmap users expect them.

pycolmap's SIFT extraction detects on images downscaled to ``max_image_size`` = 3200 px (longer
side) and keeps at most ``max_num_features`` = 8192 keypoints. Photo folders (cameras from
EXIF, no ``gt/``) get exactly these unless the run's feature settings were changed. A
``--max-image-size`` given alone keeps pycolmap's 8192 up to 3200 px and scales the budget with
the side above it. Not down: with the budget linear in the side below 3200 px (4096 at 1600),
the Sceaux photos at 1600 px registered 10 of 11 images with 4,898 tie points, with 8192 11 of
11 with 10,266 (pycolmap 11, 8,373).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from polarref.sfm.features import FeatureConfig

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


def for_photos(features: FeatureConfig, default: FeatureConfig) -> tuple[FeatureConfig, str]:
    """(settings, rule) for a folder of photos.

    Untouched settings: pycolmap's size and budget. Only the image size changed (``--max-image-size``
    alone): the budget scales with it. Anything else: as configured.
    """
    if features == default:
        return (dataclasses.replace(features, max_image_size=COLMAP_MAX_IMAGE_SIZE,
                                    max_num_features=COLMAP_MAX_FEATURES),
                f"photos: pycolmap's max_image_size {COLMAP_MAX_IMAGE_SIZE}, max_num_features {COLMAP_MAX_FEATURES}")
    if dataclasses.replace(features, max_image_size=default.max_image_size) == default:
        n = scaled_features(features.max_image_size)
        return (dataclasses.replace(features, max_num_features=n),
                f"photos: max_image_size {features.max_image_size} given, max_num_features {n} "
                f"({COLMAP_MAX_FEATURES} up to {COLMAP_MAX_IMAGE_SIZE} px, linear in the side above)")
    return features, "as configured"


def describe(features: FeatureConfig, rule: str, sizes: list[tuple[int, int]],
             keypoints: list[int]) -> FeatureBudget:
    """The record of what ran: ``sizes`` (width, height) of the originals, keypoints per image."""
    cap = features.max_image_size
    sides = [min(max(w, h), cap) if cap else max(w, h) for w, h in sizes]
    return FeatureBudget(cap, features.max_num_features, rule,
                         float(sum(sides) / max(len(sides), 1)), float(sum(keypoints) / max(len(keypoints), 1)))
