"""Ratios of interleaved repeats to a baseline method, paired within each repeat (the scripts'
summaries of per-form timings: twin_ba_forms.py, mapper_ba_forms.py)."""

from __future__ import annotations

import statistics


def ratio_summary(runs: list[dict], value: str, median_key: str, threshold: float,
                  baseline: str = "euclidean") -> dict[str, dict]:
    """Per form of ``runs`` (dicts with "form", "repeat" and ``value``): the median of ``value``
    (stored under ``median_key``), its ratio to the baseline's median, the range of the ratios
    paired within a repeat, and whether the ratio is within ``threshold``."""
    base = statistics.median(r[value] for r in runs if r["form"] == baseline)
    out = {}
    for form in dict.fromkeys(r["form"] for r in runs):
        mine = [r for r in runs if r["form"] == form]
        paired = [r[value] / b[value] for r in mine for b in runs
                  if b["form"] == baseline and b["repeat"] == r["repeat"]]
        med = statistics.median(r[value] for r in mine)
        out[form] = {median_key: med, "ratio_to_euclidean": med / base, "ratio_paired_min": min(paired),
                     "ratio_paired_max": max(paired), "within_threshold": med / base <= threshold}
    return out
