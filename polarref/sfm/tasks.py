"""The SfM front end as independent tasks for :mod:`polarref.core.execution`.

* :func:`extract_image`: the SIFT features of one image.
* :func:`match_chunk`: putative matching and geometric verification of a chunk of pairs.

Both take small task records and, on a cluster, exchange arrays through ``.npz`` files written
with an atomic rename (a task killed half-way leaves nothing behind and is simply run again).
Every pair keeps its own RANSAC seed (``seed + 7919 i + j``), so the result does not depend on
the chunking or on which worker ran what.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.camera import Camera
from polarref.sfm import features as F
from polarref.sfm.cache import save_matches
from polarref.sfm.matching import MatchConfig
from polarref.sfm.verification import VerifyConfig


@dataclass(frozen=True)
class ExtractTask:
    """Features of ``image``; written to ``out`` (``.npz``) when set, else returned in memory."""

    image: str
    config: F.FeatureConfig
    out: str | None = None


@dataclass(frozen=True)
class ExtractDone:
    name: str
    features: F.Features | None = None  # in-process runs only
    path: str | None = None             # cluster runs: the per-image file
    skipped: str = ""                   # reason when the image could not be read


def extract_image(task: ExtractTask) -> ExtractDone:
    path = Path(task.image)
    img = F.read_image(path)
    if img is None:
        return ExtractDone(path.name, skipped="unreadable (OpenCV could not decode it)")
    feats = F.extract(img, path.name, task.config)
    if task.out is None:
        return ExtractDone(path.name, features=feats)
    F.save(Path(task.out), [feats])
    return ExtractDone(path.name, path=task.out)


@dataclass(frozen=True)
class MatchTask:
    """Match and verify ``pairs`` (image indices into the features file)."""

    features: str                       # .npz of every image (polarref.sfm.features.save)
    pairs: tuple[tuple[int, int], ...]
    cameras: tuple[Camera, ...]         # per unique camera
    camera_of_image: tuple[int, ...]
    focal: float
    matching: MatchConfig
    verification: VerifyConfig
    out: str                            # .npz of the chunk's putative and verified matches


@dataclass(frozen=True)
class MatchDone:
    path: str
    matching_s: float
    verification_s: float
    pid: int


_FEATURES: dict[tuple[str, int], list[F.Features]] = {}


def _features(path: str) -> list[F.Features]:
    """Features file cached per process (a worker matches many chunks of one image set)."""
    key = (path, os.stat(path).st_mtime_ns)
    if key not in _FEATURES:
        _FEATURES.clear()
        _FEATURES[key] = F.load(Path(path))
    return _FEATURES[key]


def match_chunk(task: MatchTask) -> MatchDone:
    from polarref.sfm import rays as R_
    from polarref.sfm.matching import match_pairs
    from polarref.sfm.verification import verify_pairs

    feats = _features(task.features)
    pairs = [tuple(p) for p in task.pairs]
    t0 = time.perf_counter()
    putative = match_pairs([f.descriptors for f in feats], pairs, task.matching)
    t1 = time.perf_counter()
    used = sorted({i for p in pairs for i in p})
    xy: list = [None] * len(feats)
    for i in used:
        cam = task.cameras[task.camera_of_image[i]]
        xy[i] = R_.normalized(R_.bearings(cam, feats[i].keypoints))
    geoms = verify_pairs(xy, putative, task.focal, task.verification)
    t2 = time.perf_counter()
    save_matches(Path(task.out), putative, geoms)
    return MatchDone(task.out, t1 - t0, t2 - t1, os.getpid())


def chunks(pairs: list[tuple[int, int]], workers: int, per_worker: int = 4,
           smallest: int = 8) -> list[list[tuple[int, int]]]:
    """Split ``pairs`` in order into about ``per_worker`` chunks per worker (>= ``smallest`` pairs)."""
    size = max(smallest, -(-len(pairs) // max(1, workers * per_worker)))
    return [pairs[k:k + size] for k in range(0, len(pairs), size)]
