"""Cost of each pipeline stage: wall and CPU seconds, peak memory, whether it came from a cache.

:class:`StageClock` brackets each stage of :func:`polarref.sfm.pipeline.run_sfm`. While a stage
runs, a sampler thread reads the resident memory of this process and of its child processes
(the local Dask workers, which extract and match with ``--workers``) every ``SAMPLE_S``, so each
stage's peak is its own, not the run's. (Resetting the kernel's peak mark instead, through
``/proc/self/clear_refs``, would also reset ``ru_maxrss``, which the callers report as the
run's peak.) CPU seconds are this process's (all threads) plus its children's. Without ``/proc``
(other systems) the peaks are None.

A stage loaded from a cache keeps ``cached`` True and, beside its load time, the time measured
when the cache entry was made (stored next to the entry), so a table can count what the stage
really cost instead of dropping it.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

STAGE_NAMES = ("features", "matching", "verification", "tracks", "mapping", "ba", "metrics", "export", "total")


@dataclass(frozen=True)
class StageCost:
    """One stage of one run (a record of :class:`StageClock`)."""

    stage: str
    wall_s: float
    cpu_s: float | None = None             # this process (all threads) + child processes
    peak_rss_mb: float | None = None       # this process's peak during the stage (MiB, sampled)
    workers_peak_rss_mb: float | None = None  # peak of the child processes' summed memory during the stage
    cached: bool = False                   # loaded from the cache instead of computed
    measured_s: float | None = None        # cached: the wall time measured when the entry was made


SAMPLE_S = 0.01   # memory sampling period while a stage runs


def _rss_mb(pid: int | str = "self") -> float | None:
    try:
        pages = int(Path(f"/proc/{pid}/statm").read_text().split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return pages * _PAGE / 2**20


try:
    _PAGE = os.sysconf("SC_PAGE_SIZE")
except (AttributeError, ValueError, OSError):  # not a POSIX system: no /proc either
    _PAGE = 4096


class _Sampler:
    """Largest resident memory of this process and of its children (summed) while running."""

    def __init__(self, children: list):
        self.pids = [c.pid for c in children]
        self.self_mb = _rss_mb()
        self.children_mb = self._children_now()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="polarref-stage-memory", daemon=True)
        self._thread.start()

    def _children_now(self) -> float | None:
        got = [m for m in (_rss_mb(p) for p in self.pids) if m is not None]
        return float(sum(got)) if got else None

    def _sample(self) -> None:
        mine, theirs = _rss_mb(), self._children_now()
        if mine is not None:
            self.self_mb = max(self.self_mb or 0.0, mine)
        if theirs is not None:
            self.children_mb = max(self.children_mb or 0.0, theirs)

    def _run(self) -> None:
        while not self._stop.wait(SAMPLE_S):
            self._sample()

    def finish(self) -> tuple[float | None, float | None]:
        self._stop.set()
        self._thread.join()
        self._sample()
        return self.self_mb, self.children_mb


def _children() -> list:
    try:
        import psutil

        return psutil.Process().children(recursive=True)
    except Exception:  # noqa: BLE001 - psutil missing or a child gone: no child figures
        return []


def _children_cpu_s(children) -> float:
    total = 0.0
    for c in children:
        try:
            t = c.cpu_times()
            total += t.user + t.system
        except Exception:  # noqa: BLE001 - exited in between
            pass
    return total


@dataclass
class _Open:
    name: str
    t0: float
    cpu0: float
    child_cpu0: float
    sampler: _Sampler


@dataclass
class StageClock:
    """Times the stages of one run, in order; :meth:`to_json` is the ``runtime_s`` of metrics.json."""

    stages: list[StageCost] = field(default_factory=list)
    _open: _Open | None = None

    def start(self, name: str) -> None:
        self.close()
        children = _children()
        self._open = _Open(name, time.perf_counter(), time.process_time(), _children_cpu_s(children),
                           _Sampler(children))

    def stop(self, cached: bool = False, measured_s: float | None = None) -> StageCost:
        o = self._open
        if o is None:
            raise RuntimeError("StageClock.stop without start")
        children = _children()
        wall = time.perf_counter() - o.t0
        cpu = time.process_time() - o.cpu0 + max(0.0, _children_cpu_s(children) - o.child_cpu0)
        mine, theirs = o.sampler.finish()
        cost = StageCost(o.name, wall, cpu, mine, theirs, cached, measured_s)
        self.stages.append(cost)
        self._open = None
        return cost

    def close(self) -> None:
        """Drop a stage left open (its stage failed): stops its memory sampler, records nothing."""
        if self._open is not None:
            self._open.sampler.finish()
            self._open = None

    def add(self, name: str, wall_s: float) -> StageCost:
        """A stage timed elsewhere (the BA inside mapping; the total)."""
        cost = StageCost(name, float(wall_s))
        self.stages = [s for s in self.stages if s.stage != name] + [cost]
        return cost

    def split(self, name: str, into: tuple[str, str], share: float) -> None:
        """Replace stage ``name`` by two stages sharing its wall and CPU time in ``share : 1 - share``
        (matching and verification run inside the same cluster tasks)."""
        s = self.get(name)
        if s is None:
            return
        a, b = into
        parts = [StageCost(a, s.wall_s * share, None if s.cpu_s is None else s.cpu_s * share, s.peak_rss_mb,
                           s.workers_peak_rss_mb, s.cached, s.measured_s),
                 StageCost(b, s.wall_s * (1 - share), None if s.cpu_s is None else s.cpu_s * (1 - share),
                           s.peak_rss_mb, s.workers_peak_rss_mb, s.cached, None)]
        k = self.stages.index(s)
        self.stages[k:k + 1] = parts

    def get(self, name: str) -> StageCost | None:
        return next((s for s in self.stages if s.stage == name), None)

    def seconds(self, name: str, default: float = 0.0) -> float:
        s = self.get(name)
        return default if s is None else s.wall_s

    def cached(self, name: str) -> bool:
        s = self.get(name)
        return bool(s is not None and s.cached)

    def to_json(self) -> dict[str, float | bool]:
        """``runtime_s`` as metrics.json has always held it: stage -> s, ``<stage>_cached`` flags for
        the cacheable stages, and ``<stage>_measured_s`` beside a cached stage (its real cost)."""
        out: dict[str, float | bool] = {}
        for s in self.stages:
            out[s.stage] = s.wall_s
            if s.stage == "features":
                out["features_cached"] = s.cached
            if s.stage == "matching":
                out["matches_cached"] = s.cached
            if s.cached and s.measured_s is not None:
                out[f"{s.stage}_measured_s"] = s.measured_s
        return out
