"""The on-disk cache of the SfM front end: content keys, checksummed entries, match files."""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from polarref.core.atomic import atomic_open, atomic_write
from polarref.core.data import cache_root
from polarref.core.geometry import Rigid3
from polarref.sfm.verification import TwoViewGeometry

log = logging.getLogger(__name__)


# Every cache entry has a sidecar ``<entry>.sha256`` written after it; an entry whose bytes do not
# match (disk error, killed writer of an older version, hand edit) is reported once, deleted and
# recomputed instead of breaking every later run.
def _checksum(path: Path) -> str:
    # streamed: reading the entry whole put a second copy of the 631-view feature cache (717 MiB)
    # on top of the features stage's peak, when it was sealed and again whenever it was checked
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def seal(path: Path) -> None:
    """Record the checksum of the cache entry ``path`` (call after writing it)."""
    atomic_write(path.with_name(path.name + ".sha256"), _checksum(path) + "\n")


def cache_valid(path: Path) -> bool:
    """True when ``path`` and its checksum exist and agree; a corrupt entry is removed (warned once)."""
    side = path.with_name(path.name + ".sha256")
    if not (path.is_file() and side.is_file()):
        return False
    try:
        ok = side.read_text().strip() == _checksum(path)
    except (OSError, UnicodeDecodeError):
        ok = False
    if not ok:
        log.warning("cache entry %s is corrupt (checksum mismatch); recomputing it", path)
        for p in (path, side):
            p.unlink(missing_ok=True)
    return ok


def hash_parts(*parts) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(p if isinstance(p, bytes) else repr(p).encode())
    return h.hexdigest()[:24]


def code_digest(*modules) -> str:
    """Hash of the source of the stage modules, so a code change invalidates cached results."""
    return hash_parts(*[Path(m.__file__).read_bytes() for m in modules])


def cache_dir_for(config) -> Path:
    """The cache folder of an :class:`polarref.sfm.config.SfMConfig` (created)."""
    d = Path(config.cache_dir) if config.cache_dir else cache_root() / "sfm"
    d.mkdir(parents=True, exist_ok=True)
    return d


def save_matches(path: Path, m: Mapping[tuple[int, int], np.ndarray],
                 g: Mapping[tuple[int, int], TwoViewGeometry]) -> None:
    arrays = {}
    for (i, j), v in m.items():
        arrays[f"m_{i}_{j}"] = v
    for (i, j), v in g.items():
        arrays[f"g_{i}_{j}"] = v.inliers
        arrays[f"p_{i}_{j}"] = np.concatenate([v.cam2_from_cam1.R.ravel(), v.cam2_from_cam1.t, [v.num_matches]])
    with atomic_open(path) as fh:
        np.savez(fh, **arrays)
    seal(path)


def load_matches(path: Path):
    m, g = {}, {}
    with np.load(path) as z:
        for k in z.files:
            kind, i, j = k.split("_")
            key = (int(i), int(j))
            if kind == "m":
                m[key] = z[k]
            elif kind == "g":
                p = z[f"p_{i}_{j}"]
                g[key] = TwoViewGeometry(key, z[k], Rigid3(p[:9].reshape(3, 3), p[9:12]), int(p[12]))
    return m, g
