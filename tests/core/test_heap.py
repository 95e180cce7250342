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


_SCOPE = """
import resource, sys
import numpy as np
from polarref.core.heap import keep_heap, solve_scope
keep_heap()
def rnd():
    arrs = [np.ones(3 << 20) for _ in range(4)]  # 4 x 24 MiB in the heap (< 32 MiB), freed together
    del arrs
def faults(scoped, nested):
    with solve_scope() if scoped else open("/dev/null"):
        for _ in range(2):
            rnd()
        if nested:  # an inner solve's exit leaves the outer solve's setting in force
            with solve_scope():
                rnd()
        f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        for _ in range(10):
            rnd()
        return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0
print(faults(sys.argv[1] != "plain", sys.argv[1] == "nested"))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux only")
@pytest.mark.parametrize("mode", ["scoped", "nested"])
def test_solve_scope_holds_what_the_trim_threshold_gives_back(mode):
    """96 MiB freed together per round: past keep_heap's 64 MiB trim threshold, so every round
    faults its pages in again; inside one solve (solve_scope, nested or not) they stay."""
    if "glibc" not in heap.keep_heap():
        pytest.skip("not glibc here")
    run = lambda m: int(subprocess.run([sys.executable, "-c", _SCOPE, m], capture_output=True,
                                       text=True, check=True).stdout.strip())
    # at least one fault per 2 MiB (huge) page faulted in again (here: 15,370 of 4 KiB pages)
    huge_pages = 10 * (4 * 24 << 20) // (2 << 20)
    assert run("plain") >= huge_pages
    assert run(mode) < huge_pages // 10


def test_solve_scope_is_a_no_op_without_keep_heap():
    """A library caller that never opted in keeps glibc's dynamic thresholds (nothing set)."""
    out = subprocess.run([sys.executable, "-c", "from polarref.core import heap\n"
                          "with heap.solve_scope(): pass\nprint(heap.heap_state(), heap._libc)"],
                         capture_output=True, text=True, check=True).stdout
    assert out.strip() == "C library defaults (dynamic thresholds) None"
