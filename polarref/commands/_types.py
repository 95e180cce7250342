"""argparse ``type=`` checkers: an out-of-range option is a usage error (exit 2), caught by the
parser before any work starts."""

from __future__ import annotations

import argparse
import math


def int_range(lo: int | None = None, hi: int | None = None):
    """An integer type accepting ``lo <= value <= hi`` (None: unbounded)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if lo is not None and value < lo or hi is not None and value > hi:
            raise argparse.ArgumentTypeError(f"{value} is out of range {_span(lo, hi)}")
        return value

    parse.__name__ = "integer"
    return parse


def float_range(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False):
    """A finite float type accepting ``lo <= value <= hi`` (``lo < value`` if ``lo_open``)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
        if lo is not None and (value <= lo if lo_open else value < lo) or hi is not None and value > hi:
            raise argparse.ArgumentTypeError(f"{value:g} is out of range {_span(lo, hi, lo_open)}")
        return value

    parse.__name__ = "number"
    return parse


def _span(lo, hi, lo_open: bool = False) -> str:
    left = "(" if lo_open else "["
    return f"{left}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"


positive_int = int_range(1)
nonneg_int = int_range(0)
positive_float = float_range(0.0, lo_open=True)
nonneg_float = float_range(0.0)
SEED = int_range(0, 2**32 - 1)          # numpy's seed range
MAX_IMAGE_SIDE = 16384                  # render/detect sizes beyond this are a typo, not a request
