"""Image pairs to match, chosen once per scene and written to disk, so every method matches the
same pairs (ours reads the file, pycolmap imports it with ``match_image_pairs``).

* ``sequential``: each image with the next ``overlap`` images in capture order.
* ``spatial``: each image with its ``k`` nearest images by pose prior. "Near" is the distance
  between camera centres plus the distance between *look points* (where the optical axis meets
  the scene: the ground plane for aerial blocks, the point closest to the body centre for an
  orbiter), so a nadir and an oblique image of the same ground are near although their centres
  are not, and two orbit views are near when they look from similar directions. Pairs whose
  optical axes differ by more than ``max_angle_deg`` are left out.

The file is COLMAP's match-list format (``name1 name2`` per line) behind ``#`` header lines that
record how it was made; its name carries a digest of its pairs, so a cache keyed by the path is
keyed by the content.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.core.atomic import atomic_write
from polarref.core.errors import PolarrefError

PAIRS_FORMAT = "polarref-pairs/1"
LOOK_MODES = ("ground", "object")


@dataclass(frozen=True)
class PosePriors:
    """Noisy pose priors of N images, in capture order.

    names: N image names; centers (N, 3) world; axes (N, 3) unit optical axes in the world.
    """

    names: list[str]
    centers: np.ndarray
    axes: np.ndarray


@dataclass(frozen=True)
class PairingConfig:
    """How pairs are chosen (recorded in the pairs file's header)."""

    method: str = "spatial+sequential"  # spatial | sequential | spatial+sequential
    k: int = 12                          # spatial: nearest neighbours per image
    overlap: int = 5                     # sequential: the next N images
    look: str = "ground"                 # ground (aerial) | object (orbiter)
    ground_z: float = 0.0                # look == ground: height of the reference plane
    object_center: tuple[float, float, float] = (0.0, 0.0, 0.0)  # look == object
    max_angle_deg: float = 60.0          # spatial: largest angle between paired optical axes

    def validate(self) -> None:
        if self.method not in ("spatial", "sequential", "spatial+sequential"):
            raise PolarrefError(f"unknown pairing {self.method!r} (spatial, sequential, spatial+sequential)")
        if self.look not in LOOK_MODES:
            raise PolarrefError(f"unknown look mode {self.look!r} ({', '.join(LOOK_MODES)})")
        if self.k < 1 or self.overlap < 1:
            raise PolarrefError(f"k and overlap must be >= 1, got {self.k}, {self.overlap}")


@dataclass(frozen=True)
class PairSet:
    """Chosen pairs: indices (i < j) into ``names``, sorted."""

    names: list[str]
    pairs: list[tuple[int, int]]
    config: PairingConfig

    @property
    def digest(self) -> str:
        blob = "\n".join(f"{self.names[i]} {self.names[j]}" for i, j in self.pairs)
        return hashlib.sha256(blob.encode()).hexdigest()[:12]


def priors_from_scene(meta: dict) -> PosePriors:
    """Pose priors of a rendered scene (``scene.json``'s ``priors`` section, image order)."""
    pri = meta.get("priors")
    if not pri or not pri.get("views"):
        raise PolarrefError("the scene has no pose priors (scene.json 'priors'); render a twin preset")
    from polarref.core.geometry import rotmat_from_quat

    names = [v["name"] for v in meta["views"]]
    if len(pri["views"]) != len(names):
        raise PolarrefError(f"scene.json has {len(pri['views'])} priors for {len(names)} views")
    centers = np.array([p["center"] for p in pri["views"]], float)
    axes = np.array([rotmat_from_quat(np.array(p["qvec"], float))[2] for p in pri["views"]])
    return PosePriors(names, centers, axes)


def look_points(priors: PosePriors, config: PairingConfig) -> np.ndarray:
    """(N, 3) where each prior optical axis meets the scene (see the module docstring)."""
    C, A = priors.centers, priors.axes
    if config.look == "object":
        t = ((np.asarray(config.object_center, float) - C) * A).sum(1)
    else:
        down = np.minimum(A[:, 2], -0.05)  # a near-horizontal axis meets the plane far away: cap it
        t = (config.ground_z - C[:, 2]) / down
    return C + np.maximum(t, 0.0)[:, None] * A


def sequential_pairs(n: int, overlap: int) -> set[tuple[int, int]]:
    return {(i, j) for i in range(n) for j in range(i + 1, min(n, i + 1 + overlap))}


def spatial_pairs(priors: PosePriors, config: PairingConfig) -> set[tuple[int, int]]:
    """Each image with its ``k`` nearest by centre + look-point distance (axes within the limit)."""
    C, L, A = priors.centers, look_points(priors, config), priors.axes
    n = len(C)
    cos_max = np.cos(np.radians(config.max_angle_deg))
    out: set[tuple[int, int]] = set()
    for i in range(n):  # one row at a time: O(N) memory for thousands of images
        d = np.linalg.norm(C - C[i], axis=1) + np.linalg.norm(L - L[i], axis=1)
        d[A @ A[i] < cos_max] = np.inf
        d[i] = np.inf
        k = min(config.k, n - 1)
        nearest = np.argsort(d, kind="stable")[:k]
        out.update((min(i, int(j)), max(i, int(j))) for j in nearest if np.isfinite(d[j]))
    return out


def select(priors: PosePriors, config: PairingConfig) -> PairSet:
    """The pairs of ``config.method`` (deterministic: no random choice involved)."""
    config.validate()
    n = len(priors.names)
    pairs: set[tuple[int, int]] = set()
    if "spatial" in config.method:
        pairs |= spatial_pairs(priors, config)
    if "sequential" in config.method:
        pairs |= sequential_pairs(n, config.overlap)
    return PairSet(list(priors.names), sorted(pairs), config)


def write_pairs(path: str | os.PathLike, pair_set: PairSet, provenance: dict | None = None) -> Path:
    """Write the pairs file (atomic). Returns ``path``."""
    import dataclasses
    import json

    head = {"format": PAIRS_FORMAT, "pairs": len(pair_set.pairs), "images": len(pair_set.names),
            "digest": pair_set.digest, "config": dataclasses.asdict(pair_set.config), **(provenance or {})}
    lines = [f"# {json.dumps(head, sort_keys=True)}"]
    lines += [f"{pair_set.names[i]} {pair_set.names[j]}" for i, j in pair_set.pairs]
    path = Path(path)
    atomic_write(path, ("\n".join(lines) + "\n").encode())
    return path


def read_pairs(path: str | os.PathLike, names: list[str], skip_unknown: bool = False) -> list[tuple[int, int]]:
    """Pairs of a match-list file as sorted index pairs (i < j) into ``names``.

    Raises PolarrefError naming the first line that is malformed or, unless ``skip_unknown``
    (an image the pipeline skipped, e.g. without features), names an image not in ``names``.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise PolarrefError(f"cannot read pairs file {path}: {exc.strerror or exc}") from exc
    index = {n: i for i, n in enumerate(names)}
    out: set[tuple[int, int]] = set()
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 2 or parts[0] == parts[1]:
            raise PolarrefError(f"{path}:{lineno}: expected two different image names, got {line!r}")
        if skip_unknown and not (parts[0] in index and parts[1] in index):
            continue
        try:
            i, j = index[parts[0]], index[parts[1]]
        except KeyError as exc:
            raise PolarrefError(f"{path}:{lineno}: image {exc.args[0]!r} is not among the {len(names)} images") from exc
        out.add((min(i, j), max(i, j)))
    return sorted(out)


def pairs_file_name(pair_set: PairSet) -> str:
    """Content-addressed file name for ``pair_set``."""
    return f"pairs-{pair_set.config.method}-{pair_set.digest}.txt"
