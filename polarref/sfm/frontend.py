"""The front end (features, matching, verification) on every core of this process, with threads.

Why threads and not processes: the heavy work of all three stages runs in C/C++ that releases
the GIL (OpenCV's SIFT and five-point RANSAC, the BLAS product of the matcher), so threads use
every core without copying descriptors between processes through files (what the Dask workers
of :mod:`polarref.core.execution` must do, and what made a second worker buy 3 % on the 168-view
comet). Threads also work inside the daemonic job processes of ``polarref compare``, which may
not start worker processes of their own.

Each image and each pair is computed exactly as in the one-thread loop (per-pair RANSAC seeds,
``cv2.setRNGSeed`` is per thread), and results are merged in input order, so the output does
not depend on the thread count (tests/sfm/test_sfm_frontend.py). Inside the pool BLAS and OpenCV's
own parallel loops run on one thread each, so N threads use N cores, not N x N.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator, Sequence, TypeVar

import numpy as np

from polarref.core.progress import track
from polarref.sfm.matching import MatchConfig, match_descriptors
from polarref.sfm.verification import TwoViewGeometry, VerifyConfig, verify_pair

T = TypeVar("T")
R = TypeVar("R")

Pair = tuple[int, int]


def thread_count(requested: int) -> int:
    """``requested`` threads; 0 = every core this process may use, but no more than
    ``OMP_NUM_THREADS`` when set (a Dask worker's jobs run with 1, so N workers stay N cores)."""
    if requested > 0:
        return int(requested)
    from polarref.core.execution import available_cores

    cap = os.environ.get("OMP_NUM_THREADS", "").strip()
    return min(available_cores(), int(cap)) if cap.isdigit() and int(cap) > 0 else available_cores()


@contextmanager
def one_thread_inside() -> Iterator[None]:
    """BLAS and OpenCV single-threaded while the pool runs (restored after)."""
    import cv2
    from threadpoolctl import threadpool_limits

    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with threadpool_limits(1, user_api="blas"):
            yield
    finally:
        cv2.setNumThreads(before)


def thread_map(fn: Callable[[T], R], items: Sequence[T], threads: int, desc: str) -> list[R]:
    """``[fn(x) for x in items]`` on ``threads`` threads, in input order."""
    if threads <= 1 or len(items) <= 1:
        return [fn(x) for x in track(items, desc=desc, total=len(items))]
    with one_thread_inside(), ThreadPoolExecutor(max_workers=threads, thread_name_prefix=f"polarref-{desc}") as pool:
        return list(track(pool.map(fn, items), desc=desc, total=len(items)))


@dataclass(frozen=True)
class ChunkMatches:
    """Putative and verified matches of one chunk of pairs, with the thread CPU seconds of each step."""

    putative: dict[Pair, np.ndarray]
    geometries: dict[Pair, TwoViewGeometry]
    matching_s: float
    verification_s: float


@dataclass(frozen=True)
class FrontEndInput:
    """What every chunk reads (shared by the threads, never written)."""

    descriptors: list[np.ndarray]     # (K_i, 128) float32 per image
    xy: list[np.ndarray]              # (K_i, 2) normalized coordinates per image
    focal: float
    matching: MatchConfig
    verification: VerifyConfig


def match_and_verify_chunk(data: FrontEndInput, pairs: list[Pair]) -> ChunkMatches:
    t0 = time.thread_time()
    putative = {(i, j): match_descriptors(data.descriptors[i], data.descriptors[j], data.matching) for i, j in pairs}
    t1 = time.thread_time()
    geoms = {}
    guessed = set(data.verification.uncalibrated_images)
    for (i, j), m in putative.items():  # as verify_pairs, without its progress bar (one per thread)
        g = verify_pair(data.xy[i], data.xy[j], m, data.focal, data.verification, data.verification.seed + 7919 * i + j,
                        calibrated=i not in guessed and j not in guessed)
        if g is not None:
            g.pair = (i, j)
            geoms[(i, j)] = g
    return ChunkMatches(putative, geoms, t1 - t0, time.thread_time() - t1)


def chunked(pairs: list[Pair], threads: int, per_thread: int = 8, smallest: int = 4) -> list[list[Pair]]:
    """``pairs`` in order, in about ``per_thread`` chunks per thread (load balance vs overhead)."""
    size = max(smallest, -(-len(pairs) // max(1, threads * per_thread)))
    return [pairs[k:k + size] for k in range(0, len(pairs), size)]


def match_and_verify_threaded(data: FrontEndInput, pairs: list[Pair], threads: int) -> tuple[ChunkMatches, ...]:
    """Every chunk's matches, in pair order."""
    return tuple(thread_map(lambda c: match_and_verify_chunk(data, c), chunked(pairs, threads), threads, "matching"))
