"""Run one method in its own process, with a timeout, capturing its failure.

A comparison must survive any one method failing: an exception, a crash inside C++ (pycolmap),
or a run that never ends. Each job therefore runs in a fresh ``spawn`` process whose stdout and
stderr (including glog output from COLMAP) go to a log file; the job (a module-level function)
returns a typed record (a dataclass, see ``polarref.core.records``) written to a result file. The
parent sees one of: ok (the record), failed (exception text or exit code plus the last log
line), timeout (process killed after ``timeout_s``).

Finished work is not repeated (hloc style): with ``reuse``, a job whose result file holds a
successful result of the same function with the same arguments is loaded instead of run again,
so an interrupted hour-long comparison resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import multiprocessing as mp
import os
import sys
import time
import traceback
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Generic, TypeVar

from polarref.core import records
from polarref.core.records import JsonValue
from polarref.core.atomic import atomic_write
from polarref.core.heap import keep_heap
from polarref.core.status import RunStatus

log = logging.getLogger(__name__)


R = TypeVar("R")


@dataclass
class JobOutcome(Generic[R]):
    """What came back from one isolated job."""

    status: RunStatus
    reason: str = ""                # failure reason (one line)
    wall_s: float = 0.0             # wall time of the child process, spawn included
    result: R | None = None         # the job's record (ok only)
    reused: bool = False            # loaded from an earlier run's result file, not run now


def job_name(job: Callable) -> str:
    """``module:qualname`` of a job function (stored with its result)."""
    return f"{job.__module__}:{job.__qualname__}"


def _return_type(job: Callable):
    try:
        return typing.get_type_hints(job).get("return")
    except Exception:  # builtins and C functions carry no usable annotations
        return None


def _encode(result) -> Any:
    return records.to_dict(result) if dataclasses.is_dataclass(result) else result


def _decode(job: Callable, value, where: Path):
    tp = _return_type(job)
    if tp is not None and dataclasses.is_dataclass(tp):
        return records.from_dict(tp, value, label=str(where), where="result")
    return value


@dataclass(frozen=True)
class _JobFile:
    """``<tag>.result.json``: the job's call and its outcome (``wall_s`` once the parent timed it)."""

    ok: bool
    job: str = ""
    kwargs: dict[str, JsonValue] | None = None
    result: JsonValue = None          # the job's record in its JSON form
    error: str = ""
    wall_s: float | None = None


def _job_file_to_json(f: _JobFile) -> str:
    if not f.ok:
        return json.dumps({"ok": False, "error": f.error})
    out = {"ok": True, "job": f.job, "kwargs": f.kwargs, "result": f.result}
    if f.wall_s is not None:
        out["wall_s"] = f.wall_s
    return json.dumps(out, allow_nan=True)


def _job_file_from_json(path: Path) -> _JobFile | None:
    """The result file at ``path``; None when it is absent or not one."""
    try:
        payload = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(payload, dict):
        return None
    if not payload.get("ok"):
        return _JobFile(False, error=str(payload.get("error", "unknown error")))
    wall = payload.get("wall_s")
    return _JobFile(True, str(payload.get("job", "")), payload.get("kwargs"), payload.get("result"),
                    wall_s=None if wall is None else float(wall))


def finished_kwargs(result_path: Path) -> tuple[tuple[str, JsonValue], ...] | None:
    """The (name, value) arguments a finished job ran with (its ``<tag>.result.json``); None if it did not finish."""
    done = _job_file_from_json(result_path)
    return tuple(done.kwargs.items()) if done is not None and done.ok and done.kwargs is not None else None


def _child(job: Callable, kwargs: dict[str, JsonValue], result_path: str, log_path: str) -> None:
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    sys.stdout.flush(), sys.stderr.flush()
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(levelname)s %(name)s: %(message)s")
    keep_heap()  # the process is ours, as a polarref command's (heap.py)
    try:
        done = _JobFile(True, job_name(job), kwargs, _encode(job(**kwargs)))
    except BaseException as exc:  # report everything, including SystemExit from a library
        traceback.print_exc()
        done = _JobFile(False, error=f"{type(exc).__name__}: {exc}".strip())
    atomic_write(result_path, _job_file_to_json(done))


def _last_log_line(log_path: Path) -> str:
    try:
        lines = [ln.strip() for ln in log_path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1][:300] if lines else ""


def has_finished_result(result_path: Path) -> bool:
    """Whether ``result_path`` holds a successful, timed result (of whichever call)."""
    f = _job_file_from_json(result_path)
    return f is not None and f.ok and f.wall_s is not None


def _finished(job: Callable, kwargs: dict[str, JsonValue], result_path: Path) -> JobOutcome | None:
    """The earlier successful result of this very job call, or None (absent, failed, other inputs)."""
    f = _job_file_from_json(result_path)
    if f is None or not f.ok or f.job != job_name(job) or f.kwargs != json.loads(json.dumps(kwargs)) \
            or f.wall_s is None:
        return None
    try:
        result = _decode(job, f.result, result_path)
    except records.RecordError as exc:  # written by an older polarref: run it again
        log.info("not reusing %s: %s", result_path, exc)
        return None
    return JobOutcome(RunStatus.OK, "", f.wall_s, result, reused=True)


def run_isolated(job: Callable[..., R], kwargs: dict[str, JsonValue], timeout_s: float, work_dir: Path, tag: str,
                 reuse: bool = False) -> JobOutcome[R]:
    """Run ``job(**kwargs)`` in a spawned process.

    Args:
        job: a module-level function (the child imports it by name); it returns a typed record
            (dataclass) or a JSON-serialisable value.
        kwargs: JSON-able keyword arguments (paths as str).
        timeout_s: wall-clock limit; the process is killed after it.
        work_dir: where ``<tag>.log`` and ``<tag>.result.json`` go.
        reuse: load the result of an earlier successful run of the same job with the same
            arguments from ``<tag>.result.json`` instead of running it again.
    """
    work_dir.mkdir(parents=True, exist_ok=True)
    log_path = work_dir / f"{tag}.log"
    result_path = work_dir / f"{tag}.result.json"
    if reuse and (done := _finished(job, kwargs, result_path)) is not None:
        log.info("%s: reusing the finished result %s", job_name(job), result_path)
        return done
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
        return JobOutcome(RunStatus.TIMEOUT, f"timed out after {timeout_s:.0f} s (process killed)",
                          time.perf_counter() - t0)
    wall = time.perf_counter() - t0
    if not result_path.exists():
        tail = _last_log_line(log_path)
        return JobOutcome(RunStatus.FAILED, f"process died with exit code {proc.exitcode}"
                          + (f"; last log line: {tail}" if tail else ""), wall)
    done = _job_file_from_json(result_path)
    if done is None:
        return JobOutcome(RunStatus.FAILED, "malformed job result: not a result file", wall)
    if not done.ok:
        return JobOutcome(RunStatus.FAILED, done.error, wall)
    try:
        result = _decode(job, done.result, result_path)
    except records.RecordError as exc:
        return JobOutcome(RunStatus.FAILED, f"malformed job result: {exc}", wall)
    # a finished job, complete with its time: what a rerun may reuse
    atomic_write(result_path, _job_file_to_json(dataclasses.replace(done, wall_s=wall)))
    return JobOutcome(RunStatus.OK, "", wall, result)


# ---- one isolated job as a task of polarref.core.execution -----------------------------------------
@dataclass(frozen=True)
class IsolatedTask:
    """:func:`run_isolated` arguments as a small picklable record (paths as str)."""

    job: Callable
    kwargs: dict[str, JsonValue]
    timeout_s: float
    work_dir: str
    tag: str
    reuse: bool = False


def isolated_task(task: IsolatedTask) -> JobOutcome:
    """Run one job in its own process on whichever worker takes this task.

    A daemonic worker process may not start children; Dask workers are daemonic unless started
    with ``DASK_DISTRIBUTED__WORKER__DAEMON=False`` (``--workers`` sets it).
    """
    if mp.current_process().daemon:
        return JobOutcome(RunStatus.FAILED, "this Dask worker is a daemonic process and cannot start the job's "
                          "isolated process; start workers with DASK_DISTRIBUTED__WORKER__DAEMON=False")
    return run_isolated(task.job, task.kwargs, task.timeout_s, Path(task.work_dir), task.tag, task.reuse)


def run_isolated_with(executor, job: Callable[..., R], kwargs: dict[str, JsonValue], timeout_s: float, work_dir: Path, tag: str,
                      reuse: bool = False) -> JobOutcome[R]:
    """:func:`run_isolated` through ``executor`` (a polarref.core.execution executor); blocks until done."""
    if executor.in_process:
        return run_isolated(job, kwargs, timeout_s, work_dir, tag, reuse)
    return executor.map(isolated_task, [IsolatedTask(job, kwargs, timeout_s, str(work_dir), tag, reuse)],
                        desc=f"job-{tag}")[0]
