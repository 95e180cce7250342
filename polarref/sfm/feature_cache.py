"""Reading the features cache (``features-<key>.npz``, written by :func:`polarref.sfm.features.save`)
in two steps: keypoints first, descriptors only when matching needs them.

At 631 views of 4096 features the float16 descriptors are 0.66 GB, and a run whose matches are
cached never reads them. This lives apart from :mod:`polarref.sfm.features` on purpose: the cache
key hashes that module's source, and how the file is read does not change what it holds.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from polarref.sfm.features import Features


def load_without_descriptors(path: Path) -> list[Features]:
    """The cached features with ``descriptors=None`` (fill them with :func:`load_descriptors`)."""
    with np.load(path, allow_pickle=False) as z:
        names, sizes = z["names"], z["sizes"]
        return [Features(str(n), int(w), int(h), z[f"kp{i}"], None, z[f"sc{i}"], z[f"or{i}"], z[f"co{i}"])
                for i, (n, (w, h)) in enumerate(zip(names, sizes))]


def load_descriptors(path: Path, feats: list[Features]) -> None:
    """Fill in the (K, 128) float16 descriptors of ``feats`` read from ``path``, in place."""
    with np.load(path, allow_pickle=False) as z:
        if [str(n) for n in z["names"]] != [f.name for f in feats]:
            raise ValueError(f"{path} holds other images than the features to fill in")
        for i, f in enumerate(feats):
            if f.descriptors is None:
                de = z[f"de{i}"]
                if len(de) != len(f.keypoints):
                    raise ValueError(f"{path}: image {f.name} has {len(de)} descriptors for {len(f.keypoints)} keypoints")
                f.descriptors = de


def mean_keypoints(path: Path) -> float | None:
    """Mean keypoints per image of a features cache, from the ``kp<i>`` array headers alone (nothing
    is loaded). None when the file is absent or unreadable."""
    try:
        with zipfile.ZipFile(path) as z:
            counts = []
            for member in (n for n in z.namelist() if n.startswith("kp") and n.endswith(".npy")):
                with z.open(member) as fh:
                    version = np.lib.format.read_magic(fh)
                    shape = (np.lib.format.read_array_header_1_0(fh) if version == (1, 0)
                             else np.lib.format.read_array_header_2_0(fh))[0]
                counts.append(shape[0])
    except (OSError, ValueError, zipfile.BadZipFile, KeyError):
        return None
    return float(np.mean(counts)) if counts else None
