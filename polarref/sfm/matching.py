"""Stage 2: descriptor matching (ratio test + mutual nearest neighbour) and pair selection.

Descriptors are unit-norm, so one matrix product gives every squared distance
(``|a - b|^2 = 2 - 2 a.b``); the row top-2 gives Lowe's ratio test, the column argmax the
mutual check. Exact, no approximate nearest-neighbour search.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Generic, Literal, TypeVar

import numpy as np

from polarref.core.errors import PolarrefError
from polarref.core.progress import track

CHUNK_ELEMENTS = 1 << 19  # similarity entries per row block (2 MiB of float32)
SINGLE_THREAD_BELOW = 3000 * 3000  # pairs with fewer similarity entries match with single-threaded BLAS

Pair = tuple[int, int]   # image indices (i, j), i < j
V = TypeVar("V")


@dataclass(frozen=True, eq=False)
class ByPair(Mapping[Pair, V], Generic[V]):
    """One value per image pair, in the order the pairs were given; read as a mapping pair -> value.

    A record rather than a dict so a stage's result says what it holds and cannot be edited
    downstream; lookups by pair go through an index built once (``by_pair[(i, j)]``).
    """

    pairs: tuple[Pair, ...]
    entries: tuple[V, ...]        # entries[k] belongs to pairs[k]
    _index: dict[Pair, int] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if len(self.pairs) != len(self.entries):
            raise ValueError(f"{len(self.pairs)} pairs but {len(self.entries)} entries")
        object.__setattr__(self, "_index", {p: k for k, p in enumerate(self.pairs)})

    def __getitem__(self, pair: Pair) -> V:
        return self.entries[self._index[pair]]

    def __iter__(self) -> Iterator[Pair]:
        return iter(self.pairs)

    def __len__(self) -> int:
        return len(self.pairs)


@dataclass(frozen=True, eq=False)
class PairMatches(ByPair[np.ndarray]):
    """Putative matches of image pairs: ``entries[k]`` is an (M_k, 2) int32 array of keypoint
    indices into images ``pairs[k] = (i, j)``, sorted by the index in i."""


@dataclass(frozen=True)
class MatchConfig:
    """Matching and pairing settings."""

    ratio: float = 0.8                 # Lowe's ratio d1/d2 (COLMAP default 0.8)
    max_distance: float = 0.7          # max L2 distance of unit descriptors (COLMAP default 0.7)
    mutual: bool = True                # keep a match only if it is also the best in the other direction
    pairing: Literal["exhaustive", "sequential", "spatial", "file"] = "exhaustive"
    sequential_overlap: int = 10       # sequential: match each image with the next N (by name order)
    spatial_neighbors: int = 10        # spatial: match each image with its N nearest pose priors
    exhaustive_max_images: int = 200   # refuse exhaustive beyond this (quadratic cost)
    pairs_file: str = ""               # file: a match list (polarref.sfm.pairing; content-addressed name)


def select_pairs(num_images: int, config: MatchConfig,
                 centers: np.ndarray | None = None, names: list[str] | None = None) -> list[tuple[int, int]]:
    """Image index pairs (i < j) to match.

    Args:
        num_images: N.
        centers: (N, 3) pose-prior camera centres, required for ``spatial``.
        names: N image names, required for ``file`` (the file names images, not indices).
    """
    n = num_images
    if config.pairing == "file":
        from polarref.sfm.pairing import read_pairs

        if names is None or len(names) != n:
            raise PolarrefError("pairing from a file needs the image names")
        return read_pairs(config.pairs_file, names, skip_unknown=True)  # pairs of skipped images drop out
    if config.pairing == "exhaustive":
        if n > config.exhaustive_max_images:
            raise PolarrefError(f"exhaustive matching of {n} images exceeds exhaustive_max_images="
                                f"{config.exhaustive_max_images}; use sequential or spatial pairing")
        return [(i, j) for i in range(n) for j in range(i + 1, n)]
    if config.pairing == "sequential":
        k = max(1, config.sequential_overlap)
        return [(i, j) for i in range(n) for j in range(i + 1, min(n, i + 1 + k))]
    if config.pairing == "spatial":
        if centers is None or len(centers) != n:
            raise PolarrefError("spatial pairing needs one pose-prior centre per image")
        c = np.asarray(centers, dtype=np.float64)
        d = np.linalg.norm(c[:, None] - c[None], axis=-1)
        np.fill_diagonal(d, np.inf)
        k = min(config.spatial_neighbors, n - 1)
        nn = np.argsort(d, axis=1, kind="stable")[:, :k]
        return sorted({(min(i, j), max(i, j)) for i in range(n) for j in nn[i]})
    raise PolarrefError(f"unknown pairing {config.pairing!r} (exhaustive, sequential, spatial, file)")


def match_descriptors(desc1: np.ndarray, desc2: np.ndarray, config: MatchConfig) -> np.ndarray:
    """Match two descriptor sets.

    Args:
        desc1: (K1, D) unit-norm float32 or float16 (the features' storage; the similarities
            are taken in float32, ~1 ms per 4096 x 128 conversion beside a 56-75 ms product);
            desc2: (K2, D).
    Returns:
        (M, 2) int32 index pairs (into desc1, desc2), sorted by the first index.
    """
    desc1, desc2 = np.asarray(desc1, np.float32), np.asarray(desc2, np.float32)
    if len(desc1) < 2 or len(desc2) < 2:
        return np.zeros((0, 2), np.int32)
    if config.mutual:
        fast = _match_mutual_by_column_max(desc1, desc2, config)
        if fast is not None:
            return fast
    return _match_by_column_argmax(desc1, desc2, config)


def _keep(s1: np.ndarray, s2: np.ndarray, config: MatchConfig) -> np.ndarray:
    """Lowe's ratio test and the distance cap on the best and second-best cosine similarities."""
    d1 = np.sqrt(np.maximum(2.0 - 2.0 * s1, 0.0))
    d2 = np.sqrt(np.maximum(2.0 - 2.0 * s2, 0.0))
    return (d1 <= config.max_distance) & (d1 < config.ratio * d2)


def _match_mutual_by_column_max(desc1: np.ndarray, desc2: np.ndarray, config: MatchConfig) -> np.ndarray | None:
    """The mutual matches without a column argmax (issue 34): numpy's argmax along the first axis
    of a C-ordered block walks it column by column and cost as much as the matrix product itself
    (0.061 of 0.145 s CPU per 4096 x 4096 pair), while the column max is a fast reduction. Row i's
    best column b is mutual when its similarity is b's column maximum and no other row reaches it;
    a column whose maximum several rows reach (identical descriptors) returns None, and the caller
    takes the argmax path, whose first-row rule decides such ties. The same matches either way."""
    n1, n2 = len(desc1), len(desc2)
    best = np.empty(n1, np.int64)
    s1 = np.empty(n1, np.float32)
    s2 = np.empty(n1, np.float32)
    col_val = np.full(n2, -np.inf, np.float32)
    col_cnt = np.zeros(n2, np.int64)          # rows reaching the column maximum so far
    step = max(16, CHUNK_ELEMENTS // n2)      # row blocks stay in the cache
    count = np.uint16 if step < 2**16 else np.int64   # summing bytes into uint16: half the time of a bool sum
    for r0 in range(0, n1, step):
        blk = desc1[r0:r0 + step] @ desc2.T
        rows = np.arange(len(blk))
        b = blk.argmax(1)
        best[r0:r0 + step] = b
        s1[r0:r0 + step] = blk[rows, b]
        bm = blk.max(0)
        cnt = (blk == bm).view(np.uint8).sum(0, dtype=count)
        higher, same = bm > col_val, bm == col_val
        col_cnt[same] += cnt[same]
        col_cnt[higher] = cnt[higher]
        col_val[higher] = bm[higher]
        blk[rows, b] = -np.inf
        s2[r0:r0 + step] = blk.max(1)
    mutual = s1 == col_val[best]
    if (col_cnt[best[mutual]] > 1).any():
        return None
    keep = _keep(s1, s2, config) & mutual
    return np.stack([np.flatnonzero(keep), best[keep]], 1).astype(np.int32)


def _match_by_column_argmax(desc1: np.ndarray, desc2: np.ndarray, config: MatchConfig) -> np.ndarray:
    """The matches with the column argmax of every row block (the reference; ties go to the first row)."""
    n1, n2 = len(desc1), len(desc2)
    best = np.empty(n1, np.int64)
    s1 = np.empty(n1, np.float32)
    s2 = np.empty(n1, np.float32)
    col_val = np.full(n2, -np.inf, np.float32)
    col_arg = np.zeros(n2, np.int64)
    # Row blocks keep every pass over the similarity matrix inside the cache (5-10x faster than
    # full-matrix passes; a column argmax over a large C-ordered matrix is especially slow).
    step = max(16, CHUNK_ELEMENTS // n2)
    for r0 in range(0, n1, step):
        blk = desc1[r0:r0 + step] @ desc2.T  # (B, K2) cosine similarities
        rows = np.arange(len(blk))
        b = blk.argmax(1)
        best[r0:r0 + step] = b
        s1[r0:r0 + step] = blk[rows, b]
        if config.mutual:
            ca = blk.argmax(0)
            cv = blk[ca, np.arange(n2)]
            upd = cv > col_val
            col_val[upd] = cv[upd]
            col_arg[upd] = ca[upd] + r0
        blk[rows, b] = -np.inf
        s2[r0:r0 + step] = blk.max(1)
    keep = _keep(s1, s2, config)
    if config.mutual:
        keep &= col_arg[best] == np.arange(n1)
    return np.stack([np.flatnonzero(keep), best[keep]], 1).astype(np.int32)


def match_pairs(descriptors: list[np.ndarray], pairs: list[Pair], config: MatchConfig) -> PairMatches:
    """Putative matches of each pair, in the order of ``pairs``.

    Args:
        descriptors: per image a (K_i, D) unit-norm float32 array.
        pairs: image index pairs (i, j), i < j.

    BLAS runs single-threaded for pairs below ``SINGLE_THREAD_BELOW`` similarity entries: there
    OpenBLAS's thread hand-offs cost more than they bring (measured on the shared 2-core machine,
    per pair: ~2000 x 2000 descriptors 0.13 s with 2 threads vs 0.017 s with 1; 4096 x 4096
    0.056 s with 2 vs 0.075 s with 1).
    """
    from threadpoolctl import threadpool_limits

    small = {p for p in pairs if len(descriptors[p[0]]) * len(descriptors[p[1]]) < SINGLE_THREAD_BELOW}
    order = [p for p in pairs if p in small] + [p for p in pairs if p not in small]
    done = {}
    # one limits context for all small pairs: entering threadpool_limits scans the loaded
    # libraries (~10 ms each time; 16 s of a 168-view run's profile when entered per pair)
    limits = threadpool_limits(1, user_api="blas")
    try:
        for k, (i, j) in enumerate(track(order, desc="matching", total=len(order))):
            if k == len(small):
                limits.restore_original_limits()
            done[(i, j)] = match_descriptors(descriptors[i], descriptors[j], config)
    finally:
        limits.restore_original_limits()
    return PairMatches(tuple(pairs), tuple(done[p] for p in pairs))
