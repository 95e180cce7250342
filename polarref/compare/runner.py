"""Run one method in its own process, with a timeout, capturing its failure.

A comparison must survive any one method failing: an exception, a crash inside C++ (pycolmap),
or a run that never ends. Each job therefore runs in a fresh ``spawn`` process whose stdout and
stderr (including glog output from COLMAP) go to a log file; the job returns a JSON-able dict
written to a result file. The parent sees one of: ok (the dict), failed (exception text or exit
code plus the last log line), timeout (process killed after ``timeout_s``).
"""

from __future__ import annotations

import importlib
import json
import logging
import multiprocessing as mp
import os
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from polarref.compare.schema import STATUS_FAILED, STATUS_OK, STATUS_TIMEOUT

log = logging.getLogger(__name__)


@dataclass
class JobOutcome:
    """What came back from one isolated job."""

    status: str                     # ok | failed | timeout
    reason: str = ""                # failure reason (one line)
    wall_s: float = 0.0             # wall time of the child process, spawn included
    result: dict = field(default_factory=dict)


def _child(job: str, kwargs: dict, result_path: str, log_path: str) -> None:
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    sys.stdout.flush(), sys.stderr.flush()
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        module_name, func_name = job.split(":")
        func = getattr(importlib.import_module(module_name), func_name)
        result = func(**kwargs)
        payload = {"ok": True, "result": result}
    except BaseException as exc:  # report everything, including SystemExit from a library
        traceback.print_exc()
        payload = {"ok": False, "error": f"{type(exc).__name__}: {exc}".strip()}
    tmp = result_path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(payload, f, allow_nan=True)
    os.replace(tmp, result_path)


def _last_log_line(log_path: Path) -> str:
    try:
        lines = [ln.strip() for ln in log_path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1][:300] if lines else ""


def run_isolated(job: str, kwargs: dict, timeout_s: float, work_dir: Path, tag: str) -> JobOutcome:
    """Run ``module:function(**kwargs)`` in a spawned process.

    Args:
        job: "package.module:function"; the function returns a JSON-serialisable dict.
        kwargs: JSON-able keyword arguments (paths as str).
        timeout_s: wall-clock limit; the process is killed after it.
        work_dir: where ``<tag>.log`` and ``<tag>.result.json`` go.
    """
    work_dir.mkdir(parents=True, exist_ok=True)
    log_path = work_dir / f"{tag}.log"
    result_path = work_dir / f"{tag}.result.json"
    for p in (log_path, result_path):
        if p.exists():
            p.unlink()
    ctx = mp.get_context("spawn")  # fork after pycolmap/OpenMP threads started is unsafe
    proc = ctx.Process(target=_child, args=(job, kwargs, str(result_path), str(log_path)), daemon=True)
    t0 = time.perf_counter()
    proc.start()
    proc.join(timeout_s)
    if proc.is_alive():
        proc.kill()
        proc.join(10)
        return JobOutcome(STATUS_TIMEOUT, f"timed out after {timeout_s:.0f} s (process killed)",
                          time.perf_counter() - t0)
    wall = time.perf_counter() - t0
    if not result_path.exists():
        tail = _last_log_line(log_path)
        return JobOutcome(STATUS_FAILED, f"process died with exit code {proc.exitcode}"
                          + (f"; last log line: {tail}" if tail else ""), wall)
    payload = json.loads(result_path.read_text())
    if not payload.get("ok"):
        return JobOutcome(STATUS_FAILED, payload.get("error", "unknown error"), wall)
    return JobOutcome(STATUS_OK, "", wall, payload.get("result") or {})


# ---- one isolated job as a task of polarref.execution -----------------------------------------
@dataclass(frozen=True)
class IsolatedTask:
    """:func:`run_isolated` arguments as a small picklable record (paths as str)."""

    job: str
    kwargs: dict
    timeout_s: float
    work_dir: str
    tag: str


def isolated_task(task: IsolatedTask) -> JobOutcome:
    """Run one job in its own process on whichever worker takes this task.

    A daemonic worker process may not start children; Dask workers are daemonic unless started
    with ``DASK_DISTRIBUTED__WORKER__DAEMON=False`` (``--workers`` sets it).
    """
    if mp.current_process().daemon:
        return JobOutcome(STATUS_FAILED, "this Dask worker is a daemonic process and cannot start the job's "
                          "isolated process; start workers with DASK_DISTRIBUTED__WORKER__DAEMON=False")
    return run_isolated(task.job, task.kwargs, task.timeout_s, Path(task.work_dir), task.tag)


def run_isolated_with(executor, job: str, kwargs: dict, timeout_s: float, work_dir: Path, tag: str) -> JobOutcome:
    """:func:`run_isolated` through ``executor`` (a polarref.execution executor); blocks until done."""
    if executor.in_process:
        return run_isolated(job, kwargs, timeout_s, work_dir, tag)
    return executor.map(isolated_task, [IsolatedTask(job, kwargs, timeout_s, str(work_dir), tag)],
                        desc=f"job-{tag}")[0]
