"""Measurements of the BA bench beside its timings: peak memory of one solve, cold-process time.

* Peak memory: the solve runs in a forked child; the child's resident-set high-water mark
  (``VmHWM``) minus its resident set at the fork (``VmRSS``, the parent's pages it shares) is
  the memory that solve added at its peak: its copy of the problem, its own structures and
  arrays (Ceres: pycolmap's reconstruction and Ceres' problem). Linux resets the high-water
  mark at fork, so nothing the parent did before counts.
* Cold process: ``python -m polarref ba PROBLEM`` in a fresh interpreter, timed from outside;
  its output JSON gives the solve's own first-iteration latency (numba loads its cached
  kernels on first call), set beside the same figure from the warm bench process.
"""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from polarref.bench.ba_records import ColdProcess


def _status_kib(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise RuntimeError(f"/proc/self/status has no {field}")


def forked(fn) -> tuple[object, float]:
    """(fn(), peak MiB that fn added) with fn run in a forked child; an exception in the child
    is raised here as RuntimeError naming it. Falls back to an in-process call (peak NaN)
    where fork or /proc is missing."""
    if not hasattr(os, "fork") or not Path("/proc/self/status").exists():
        return fn(), float("nan")
    rfd, wfd = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: never returns into the caller's stack
        code = 0
        try:
            os.close(rfd)
            base = _status_kib("VmRSS")
            try:
                out = (True, fn(), (_status_kib("VmHWM") - base) / 1024.0)
            except BaseException as exc:  # reported to the parent, which raises it
                out = (False, f"{type(exc).__name__}: {exc}", 0.0)
            with os.fdopen(wfd, "wb") as f:
                pickle.dump(out, f)
        except BaseException:
            code = 1
        finally:
            os._exit(code)
    os.close(wfd)
    with os.fdopen(rfd, "rb") as f:
        data = f.read()
    os.waitpid(pid, 0)
    if not data:
        raise RuntimeError("the solve's child process died without a result (out of memory?)")
    ok, value, peak = pickle.loads(data)
    if not ok:
        raise RuntimeError(value)
    return value, peak


def cached(path: Path, fn):
    """fn()'s value, pickled at ``path`` the first time and read from there afterwards (a
    scratch cache of finished solves; written atomically so a killed run leaves no half file)."""
    if path.exists():
        with path.open("rb") as f:
            return pickle.load(f)
    value = fn()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    with tmp.open("wb") as f:
        pickle.dump(value, f)
    os.replace(tmp, path)
    return value


def cold_process(problem: str, param: str = "euclidean") -> ColdProcess:
    """Time ``polarref ba PROBLEM`` in a fresh interpreter: process wall, the solve's wall and
    its first iteration's latency (from the solve's start), as that process measured them."""
    with tempfile.TemporaryDirectory(prefix="polarref-cold-") as tmp:
        out = Path(tmp) / "ba.json"
        cmd = [sys.executable, "-m", "polarref", "--no-progress", "ba", problem, "--param", param,
               "--out", str(out)]
        t = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, env=os.environ.copy())
        wall = time.perf_counter() - t
        if proc.returncode != 0:
            return ColdProcess(" ".join(cmd[1:]), error=(proc.stderr.strip().splitlines() or ["no message"])[-1])
        return _cold_from_json(json.loads(out.read_text()), "python " + " ".join(cmd[1:-2]), wall)


def _cold_from_json(doc, command: str, wall: float) -> ColdProcess:
    """The cold-process record from ``polarref ba``'s output JSON (its summary's fields)."""
    trace = doc.get("trace") or []
    return ColdProcess(command, process_wall_s=wall, solve_wall_s=doc["wall_s"], setup_s=doc.get("setup_s"),
                       first_iteration_s=trace[0]["wall_s"] if trace else None, iterations=doc["iterations"])


def kernel_load_s() -> float | None:
    """Seconds a fresh interpreter takes to load every compiled kernel (numba's disk cache):
    ``kernels.warm_up()`` timed inside it; None without numba."""
    code = ("import time, polarref.ba.kernels as k\n"
            "t = time.perf_counter(); ok = k.available(); k.warm_up()\n"
            "print(time.perf_counter() - t if ok else -1)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=os.environ.copy())
    if proc.returncode != 0:
        return None
    v = float(proc.stdout.strip().splitlines()[-1])
    return None if v < 0 else v
