"""glibc heap thresholds that keep the bundle adjuster's per-iteration arrays in memory.

Each LM iteration allocates its residuals, Jacobians and normal-equation blocks afresh
(on the ParallaxBA fake pile, 26,050 observations, ~7-12 MB per evaluation). glibc serves a
block above its mmap threshold with fresh pages and, by its dynamic rule, raises that
threshold (and the trim threshold, to twice it) only to the largest block freed so far. A BA
process of this size settles near 4 / 8 MB: the iteration's freed arrays exceed the trim
threshold, go back to the kernel, and are faulted in again at the next evaluation. Measured
in solves (reports/bench-ba/notes.md, seventh pass), that costs the polar form ~0.8 ms of its
~10 ms per iteration on the fake pile, the Euclidean form ~0.1 ms.

:func:`keep_heap` sets the two thresholds to the ceilings of glibc's own dynamic rule
(mmap 32 MiB, trim 64 MiB): the state a long-running process adapts to, so at most 64 MiB of
freed heap is held between solves. It is process-wide, so it is called where the process is
ours: every ``polarref`` command (cli.py), every isolated job (isolated.py: the campaign's and
the comparison's stages, peers included, so both sides run under it), ``polarref bench ba``
(which records it in bench.json) and scripts/profile_ba.py. A library caller of ``solve``
keeps glibc's dynamic rule unless it calls :func:`keep_heap` itself. A no-op (reported) where
the C library is not glibc.

:func:`solve_scope` (around every ``solve``) raises the trim threshold to 1 GiB for the length
of one solve and sets it back after: the mapper's larger local BAs free more than 64 MiB per
iteration at once (the polar form's evaluation arrays), which then came back as page faults at
every evaluation. Stop 45, ad hoc (captured rosetta local BA of 228 cameras and 112,646
observations, CPU time): polar 455 -> 248 ms per solve, Euclidean 146 -> 141 ms. A solve holds
at most what it allocated; memory it freed is handed back at the next free after its end.
"""

from __future__ import annotations

import ctypes
import logging
import sys
from collections.abc import Iterator
from contextlib import contextmanager

log = logging.getLogger(__name__)

M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameters (malloc.h)
MMAP_THRESHOLD = 32 << 20  # glibc's DEFAULT_MMAP_THRESHOLD_MAX on 64-bit
TRIM_THRESHOLD = 2 * MMAP_THRESHOLD  # what its dynamic rule sets beside it
SOLVE_TRIM_THRESHOLD = 1 << 30  # within one solve: freed heap held (solve_scope)

_state: str | None = None  # set once per process by keep_heap
_libc = None  # glibc, once keep_heap has set its thresholds
_depth = 0  # nested solve_scope (a solve inside a solve: the outer one restores)


def keep_heap() -> str:
    """Set glibc's mmap and trim thresholds (module docstring) once per process; the state
    as one line for the records."""
    global _state
    if _state is not None:
        return _state
    state = "C library defaults (not glibc)"
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None)
            ok = (libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
                  and libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1)
        except (OSError, AttributeError):  # no mallopt: musl and other C libraries
            ok = False
        if ok:
            global _libc
            _libc = libc
            state = (f"glibc mallopt: mmap threshold {MMAP_THRESHOLD >> 20} MiB, "
                     f"trim threshold {TRIM_THRESHOLD >> 20} MiB, "
                     f"{SOLVE_TRIM_THRESHOLD >> 20} MiB within a solve")
        log.debug("heap: %s", state)
    _state = state
    return state


def heap_state() -> str:
    """The heap setting in force, as :func:`keep_heap` reports it (without setting it)."""
    return _state if _state is not None else "C library defaults (dynamic thresholds)"


@contextmanager
def solve_scope() -> Iterator[None]:
    """One solve's freed heap held until its end, then handed back (module docstring); a
    no-op unless the process called :func:`keep_heap` (glibc)."""
    global _depth
    if _libc is None:
        yield
        return
    if _depth == 0:
        _libc.mallopt(M_TRIM_THRESHOLD, SOLVE_TRIM_THRESHOLD)
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        if _depth == 0:
            _libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD)
