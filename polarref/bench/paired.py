"""Ratios of interleaved repeats to a baseline method, paired within each repeat (the scripts'
summaries of per-form timings: twin_ba_forms.py, mapper_ba_forms.py)."""

from __future__ import annotations

import statistics
from dataclasses import dataclass
from typing import Sequence


@dataclass(frozen=True)
class PairedRatio:
    """One form against the baseline: its median, the ratio of the medians, the range of the
    ratios paired within a repeat, and whether the ratio is within the threshold."""

    median: float
    ratio: float
    paired_min: float
    paired_max: float
    within: bool


def ratio_summary(samples: Sequence[tuple[str, int, float]], threshold: float,
                  baseline: str = "euclidean") -> tuple[tuple[str, PairedRatio], ...]:
    """Per form, in first-seen order, from (form, repeat, value) samples."""
    base = statistics.median(v for f, _, v in samples if f == baseline)
    out = []
    for form in dict.fromkeys(f for f, _, _ in samples):
        mine = [(r, v) for f, r, v in samples if f == form]
        paired = [v / b for r, v in mine for f, rb, b in samples if f == baseline and rb == r]
        med = statistics.median(v for _, v in mine)
        out.append((form, PairedRatio(med, med / base, min(paired), max(paired), med / base <= threshold)))
    return tuple(out)
