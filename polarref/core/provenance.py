"""Provenance of a result: which code, on which machine, with which packages, threads and seeds.

One function, :func:`collect`, shared by every writer of results (``compare``'s metrics.json,
``sfm``'s metrics.json, ``bench ba``'s bench.json) and by ``polarref doctor``. It never
raises: a field it cannot determine is recorded as unknown ("" / None) rather than aborting a
finished run for want of a version string.
"""

from __future__ import annotations

import dataclasses
import importlib
import os
import platform
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

# Module names as imported; the keys in ``versions`` use the distribution's common name.
PACKAGES = {"numpy": "numpy", "scipy": "scipy", "sympy": "sympy", "mitsuba": "mitsuba", "drjit": "drjit",
            "pycolmap": "pycolmap", "opencv": "cv2", "matplotlib": "matplotlib", "threadpoolctl": "threadpoolctl"}
THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _git(repo: Path, *args: str) -> str | None:
    try:
        r = subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout if r.returncode == 0 else None


def git_state(repo: Path | None = None) -> tuple[str, bool | None]:
    """(HEAD commit as 40 hex digits or "", dirty flag or None outside a git checkout).

    Dirty means a file outside ``reports/`` differs from HEAD or is untracked and not ignored:
    an untracked module imports as readily as a tracked one, so a run with one is not
    reproducible from the commit. Ignored files (caches, outputs, the venv) do not count, nor
    do the committed example reports: regenerating them one after another rewrites tracked
    files, which says nothing about the code that produced the numbers.
    """
    from polarref.core.data import REPO_ROOT

    repo = Path(repo or REPO_ROOT)
    head = (_git(repo, "rev-parse", "HEAD") or "").strip()
    if len(head) != 40:
        return "", None
    status = _git(repo, "status", "--porcelain", "--untracked-files=normal", "--", ".", ":(exclude)reports")
    return head, None if status is None else bool(status.strip())


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or ""


def _package_versions() -> dict[str, str]:
    """name -> version, "missing (...)" when the import fails; polarref's own version first."""
    from polarref import __version__

    out = {"polarref": str(__version__), "python": sys.version.split()[0]}
    for name, module in PACKAGES.items():
        try:
            out[name] = str(getattr(importlib.import_module(module), "__version__", "unknown version"))
        except Exception as exc:  # provenance must report, never crash
            out[name] = f"missing ({type(exc).__name__})"
    return out


def blas_threads() -> int | None:
    """The largest thread count of the loaded BLAS libraries (None: none loaded / unknown)."""
    try:
        from threadpoolctl import ThreadpoolController

        counts = [int(c.num_threads) for c in ThreadpoolController().lib_controllers if c.user_api == "blas"]
    except Exception:
        return None
    return max(counts) if counts else None


@dataclass
class Provenance:
    """The environment record of a run (embedded as ``environment`` in result files)."""

    git_commit: str                  # HEAD, 40 hex digits ("" outside a git checkout)
    git_dirty: bool | None           # files differ from HEAD or are untracked (None: unknown)
    cpu_count: int
    cpu_model: str
    machine: str                     # e.g. x86_64
    platform: str
    python: str
    versions: dict[str, str]         # package -> version
    threads: dict[str, int]          # stage or variable -> threads
    seeds: dict[str, int]


def collect_record(seeds: dict[str, int] | None = None, threads: dict[str, int] | None = None) -> Provenance:
    """The environment record of this process.

    Args:
        seeds: the seeds of the run (name -> seed), recorded as given.
        threads: thread counts the caller set for its stages (name -> count), e.g.
            ``{"pycolmap": 1, "ba_blas": 1}``; the process's BLAS default and the thread
            environment variables are added.
    """
    commit, dirty = git_state()
    th = dict(threads or {})
    b = blas_threads()
    if b is not None:
        th.setdefault("blas_default", b)
    for var in THREAD_ENV:
        if os.environ.get(var, "").isdigit():
            th.setdefault(var, int(os.environ[var]))
    return Provenance(commit or "", dirty, int(os.cpu_count() or 0), cpu_model(), platform.machine(),
                      platform.platform(), sys.version.split()[0], _package_versions(), th, dict(seeds or {}))


def collect(seeds: dict[str, int] | None = None, threads: dict[str, int] | None = None) -> dict:
    """:func:`collect_record` in its JSON form (the ``environment`` object of a result file)."""
    return dataclasses.asdict(collect_record(seeds, threads))
