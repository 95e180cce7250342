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


def summary_to_json(runs: list[dict], value: str, median_key: str, threshold: float) -> dict[str, dict]:
    """The per-form summary of the scripts' JSON runs (dicts with "form", "repeat" and ``value``),
    in their file format: ``{form: {median_key, ratio_to_euclidean, ratio_paired_min,
    ratio_paired_max, within_threshold}}``."""
    return {form: {median_key: p.median, "ratio_to_euclidean": p.ratio, "ratio_paired_min": p.paired_min,
                   "ratio_paired_max": p.paired_max, "within_threshold": p.within}
            for form, p in ratio_summary([(r["form"], r["repeat"], r[value]) for r in runs], threshold)}
