"""How a method ran: its settings beside its times (``MethodSettings``), one record for the SfM
bench's cells (:mod:`polarref.bench.records`) and the twin campaign's (issue 34)."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Setting:
    """One option of a method, by dotted name, as it prints (JSON text of its value)."""

    name: str
    value: str


@dataclass(frozen=True)
class MethodSettings:
    """How one method ran in one cell: what makes the comparison level, then every option."""

    method: str                   # ours | pycolmap
    parallel: int                 # ours: front-end worker threads (SfMConfig.threads); pycolmap: num_threads
    threads_per_process: int      # BLAS / OpenMP / OpenCV threads of the cell's main process
    max_num_features: int         # SIFT keypoints kept per image
    max_image_size: int           # SIFT detection side cap (0: full resolution)
    ignore_two_view_tracks: bool  # the mapper drops two-view tracks (pycolmap's default; ours never)
    pairing: str
    options: tuple[Setting, ...] = ()   # every option of the method (ours: SfMConfig; pycolmap: its option objects)


def json_default(obj):
    """numpy scalars as numbers; paths, enums and sets of pycolmap's option dicts as text."""
    if isinstance(obj, np.ndarray):    # e.g. pycolmap's global mapper options hold arrays
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (set, frozenset, tuple)):
        return sorted(map(str, obj))
    return str(obj)


def _flatten(prefix: str, value):
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _flatten(f"{prefix}.{k}" if prefix else str(k), v)
    else:
        yield prefix, value


def flatten_settings(value) -> tuple[Setting, ...]:
    """Every leaf of a nested option tree (dataclass-as-dict or pycolmap ``todict()``) as a Setting."""
    return tuple(Setting(k, json.dumps(v, default=json_default, sort_keys=True)) for k, v in _flatten("", value))
