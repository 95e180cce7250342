"""A spawned process's own peak memory, not the one Linux carries over from its parent."""

from __future__ import annotations

import multiprocessing as mp
import resource
import sys

import numpy as np
import pytest

from polarref.core.memory import maxrss_mb, own_peak_mb, vmhwm_mb

HELD_MB = 300


def _in_child(fn):
    """What ``fn(queue)`` puts on the queue, run in a freshly spawned interpreter."""
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    child = ctx.Process(target=fn, args=(queue,))
    child.start()
    out = queue.get(timeout=120)
    child.join(60)
    return out


def _report(queue) -> None:
    queue.put((own_peak_mb(), maxrss_mb()))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the inherited ru_maxrss is Linux's")
def test_spawned_child_reports_its_own_peak_not_the_parents():
    held = np.ones(HELD_MB * 2**20 // 8)  # resident in the parent while the child starts
    own, inherited = _in_child(_report)
    assert held.sum() == held.size
    assert inherited >= HELD_MB  # the premise: ru_maxrss starts at the parent's mark
    assert 10.0 < own < HELD_MB / 2  # an interpreter with numpy, far below what the parent holds


def _resident_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * resource.getpagesize() / 2**20


def _grow(queue) -> None:
    before = own_peak_mb()
    extra = int(before - _resident_mb()) + 64  # enough to pass the old mark by about 64 MiB
    block = np.ones(extra * 2**20 // 8)
    queue.put((before, own_peak_mb(), float(block[-1])))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_own_peak_grows_with_what_this_process_touches():
    # in a fresh process: the test runner's own mark may be many GiB after the suite's big tests
    before, after, one = _in_child(_grow)
    assert one == 1.0
    assert before + 48 <= after <= before + 64 + 32


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_vmhwm_is_at_least_what_is_resident_now_and_at_most_maxrss():
    resident = _resident_mb()
    hwm = vmhwm_mb()
    assert hwm is not None and resident - 1.0 <= hwm <= maxrss_mb() + 1.0
    assert own_peak_mb() == pytest.approx(hwm, abs=1.0)
