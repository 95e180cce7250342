"""This process's own peak resident memory.

``getrusage(RUSAGE_SELF).ru_maxrss`` is not it for a process started by ``spawn`` (every isolated
job, every campaign stage): Linux carries the parent's high-water mark into the child at exec, so
the child reports at least the parent's peak. A child of a campaign runner that had compiled the
kernels and scored three models showed 2,200 MiB in every stage while its sampled peak was 1,635.
``VmHWM`` in ``/proc/self/status`` belongs to the process image and starts again at exec.
"""

from __future__ import annotations

import resource
from pathlib import Path


def vmhwm_mb() -> float | None:
    """``VmHWM`` of this process image, MiB; None where ``/proc`` does not tell it."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return None


def maxrss_mb() -> float:
    """``ru_maxrss`` of this process, MiB: floored at the spawning parent's mark on Linux."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def own_peak_mb() -> float:
    """Peak resident set of this process image, MiB: ``VmHWM``, else ``ru_maxrss`` (no ``/proc``)."""
    hwm = vmhwm_mb()
    return maxrss_mb() if hwm is None else hwm
