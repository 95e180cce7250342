"""Helpers for the execution tests: a real ``dask scheduler`` + ``dask worker`` processes on
127.0.0.1, and comparison of output folders and metrics files with timings left out."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

DASK = str(Path(sys.executable).parent / "dask")
# Keys whose values are wall/CPU times (or the time of day): they differ run to run by nature.
TIMING_KEYS = {"runtime_s", "wall_s", "setup_s", "time_in", "stage_runtime_s", "total_runtime_s", "created",
               "seconds", "render_s", "runtime_per_iteration_s", "total_s", "final_ba_trace",
               "ba_traces", "command"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class SubprocessCluster:
    """``dask scheduler`` and ``n`` single-thread ``dask worker`` processes, as the README starts them."""

    def __init__(self, tmp: Path, n: int = 2, nanny: bool = True):
        self.port = free_port()
        self.address = f"tcp://127.0.0.1:{self.port}"
        env = dict(os.environ, DASK_DISTRIBUTED__WORKER__DAEMON="False")
        self.logs = tmp
        self.scheduler = subprocess.Popen(
            [DASK, "scheduler", "--host", "127.0.0.1", "--port", str(self.port), "--no-dashboard"],
            stdout=subprocess.DEVNULL, stderr=open(tmp / "scheduler.log", "w"), env=env, start_new_session=True)
        self.workers = [
            subprocess.Popen([DASK, "worker", self.address, "--nthreads", "1", "--no-dashboard",
                              "--local-directory", str(tmp / f"w{k}"), *([] if nanny else ["--no-nanny"])],
                             stdout=subprocess.DEVNULL, stderr=open(tmp / f"worker{k}.log", "w"), env=env,
                             start_new_session=True)
            for k in range(n)]
        self.wait_for_workers(n)

    def wait_for_workers(self, n: int, timeout: float = 120.0) -> None:
        from distributed import Client

        with Client(self.address, timeout=30) as client:
            client.wait_for_workers(n, timeout=timeout)

    def worker_pids(self) -> dict[str, int]:
        from distributed import Client

        with Client(self.address, timeout=30) as client:
            return client.run(os.getpid)

    def close(self) -> None:
        for p in [*self.workers, self.scheduler]:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        deadline = time.time() + 20
        for p in [*self.workers, self.scheduler]:
            try:
                p.wait(max(0.1, deadline - time.time()))
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


def tree_files(root: Path) -> dict[str, bytes]:
    """Every visible file under ``root`` (relative path -> bytes); hidden temporaries skipped."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and not any(part.startswith(".") for part in p.relative_to(root).parts)}


def strip_timings(obj):
    """A JSON value with every timing entry removed (recursively)."""
    if isinstance(obj, dict):
        return {k: strip_timings(v) for k, v in obj.items() if k not in TIMING_KEYS}
    if isinstance(obj, list):
        return [strip_timings(v) for v in obj]
    return obj


def metrics_equal_apart_from_timings(a: Path, b: Path) -> list[str]:
    """Paths of differing entries between two JSON files, timings excluded (empty = equal)."""
    diffs: list[str] = []

    def walk(x, y, path):
        if isinstance(x, dict) and isinstance(y, dict):
            for k in sorted(set(x) | set(y)):
                walk(x.get(k), y.get(k), f"{path}/{k}")
        elif isinstance(x, list) and isinstance(y, list) and len(x) == len(y):
            for i, (u, v) in enumerate(zip(x, y)):
                walk(u, v, f"{path}[{i}]")
        elif x != y and not (x != x and y != y):  # NaN == NaN here
            diffs.append(f"{path}: {str(x)[:60]} != {str(y)[:60]}")

    walk(strip_timings(json.loads(a.read_text())), strip_timings(json.loads(b.read_text())), "")
    return diffs
