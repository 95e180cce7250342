"""polarref.core.heap: glibc's thresholds set once, and the page faults they remove.

The fault count runs in fresh interpreters (the allocator's state is per process): a loop
shaped like an LM iteration (one large array freed, then several smaller ones allocated,
touched and freed together) faults its pages in at every round under glibc's dynamic
thresholds, and not after the first round with :func:`keep_heap`.
"""

import subprocess
import sys

import pytest

from polarref.core import heap

_LOOP = """
import resource, sys
import numpy as np
if sys.argv[1] == "keep":
    from polarref.core.heap import keep_heap
    keep_heap()
def rnd():
    a = np.ones(4 << 17)  # 4 MiB: raises the dynamic mmap threshold to 4 MiB when freed
    del a
    arrs = [np.ones(3 << 17) for _ in range(4)]  # 4 x 3 MiB in the heap, then freed together
    del arrs
for _ in range(3):
    rnd()
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    rnd()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


def _faults(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", _LOOP, mode], capture_output=True, text=True,
                         check=True)
    return int(out.stdout.strip())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux only")
def test_keep_heap_sets_glibc_thresholds_once():
    state = heap.keep_heap()
    if "glibc" not in state:
        pytest.skip(f"not glibc here: {state}")
    assert "mmap threshold 32 MiB" in state and "trim threshold 64 MiB" in state
    assert heap.keep_heap() == state == heap.heap_state()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux only")
def test_keep_heap_removes_the_per_round_page_faults():
    if "glibc" not in heap.keep_heap():
        pytest.skip("not glibc here")
    default, kept = _faults("default"), _faults("keep")
    pages = 20 * (4 * 3 << 20) // 4096  # the 20 rounds' 3 MiB arrays, in 4 KiB pages
    # glibc's dynamic thresholds: the 12 MiB freed each round exceed its 8 MiB trim
    # threshold and come back as faults (about one per page; huge pages give fewer)
    assert default > 0.2 * pages
    assert kept < 0.05 * pages
