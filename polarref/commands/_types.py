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


def refine_groups(text: str) -> tuple[str, ...]:
    """``focal,pp,dist`` (any subset, each once), ``all`` or ``none`` -> the groups, ordered.

    An empty value or an empty / repeated item is a typo, not "none"."""
    from polarref.ba.refine import parse_refine

    items = [s.strip().lower() for s in text.split(",")]
    if not text.strip() or any(not s for s in items):
        raise argparse.ArgumentTypeError(f"empty intrinsics group in {text!r}; give focal,pp,dist "
                                         "(comma-separated), all or none")
    repeated = sorted({s for s in items if items.count(s) > 1})
    if repeated:
        raise argparse.ArgumentTypeError(f"{', '.join(repeated)} given twice in {text!r}")
    if len(items) > 1 and {"all", "none"} & set(items):
        raise argparse.ArgumentTypeError(f"all / none stand alone, got {text!r}")
    try:
        return parse_refine(items)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def camera_spec(text: str) -> str:
    """``MODEL:p1,p2,...`` checked for a known model, its parameter count and finite numbers
    (the image size is applied later, once the images are read)."""
    from polarref.camera import Camera

    model, sep, params = text.partition(":")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected MODEL:p1,p2,... (e.g. PINHOLE:fx,fy,cx,cy), got {text!r}")
    try:
        values = [float(v) for v in params.replace(" ", "").split(",")]
        Camera(model.strip().upper(), 1, 1, values)
    except (ValueError, TypeError) as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from None
    return text
