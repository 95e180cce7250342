"""polarref.sfm.stages: each stage's own peak memory and CPU time, the run's peak left intact."""

from __future__ import annotations

import resource
import time

import numpy as np
import pytest

from polarref.sfm.stages import StageClock


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def test_each_stage_has_its_own_peak_and_the_run_peak_survives():
    clock = StageClock()
    clock.start("big")
    a = np.ones(40_000_000)  # 305 MiB, touched
    time.sleep(0.05)
    del a
    clock.stop()
    after_big = _maxrss_mb()
    clock.start("small")
    b = np.ones(2_000_000)  # 15 MiB
    time.sleep(0.05)
    del b
    clock.stop()
    big, small = clock.get("big"), clock.get("small")
    # the big stage saw the 305 MiB array on top of what the small one peaks at
    assert 250 < big.peak_rss_mb - small.peak_rss_mb < 360
    assert small.peak_rss_mb < big.peak_rss_mb
    assert _maxrss_mb() == pytest.approx(after_big, abs=1.0)  # the process's peak was not reset
    assert _maxrss_mb() >= big.peak_rss_mb - 1.0


def test_cpu_seconds_follow_the_work_and_split_keeps_the_sum():
    clock = StageClock()
    clock.start("busy")
    t0 = time.process_time()  # a fixed amount of work, however loaded the machine is
    while time.process_time() - t0 < 0.2:
        pass
    clock.stop()
    clock.start("idle")
    time.sleep(0.3)
    clock.stop()
    busy, idle = clock.get("busy"), clock.get("idle")
    assert 0.2 <= busy.cpu_s < 0.3 and idle.cpu_s < 0.05 and idle.wall_s >= 0.29
    clock.split("busy", ("one", "two"), 0.25)
    one, two = clock.get("one"), clock.get("two")
    assert one.wall_s + two.wall_s == pytest.approx(busy.wall_s)
    assert one.cpu_s == pytest.approx(0.25 * busy.cpu_s)
    assert [s.stage for s in clock.stages] == ["one", "two", "idle"]


def test_cached_stage_json_and_a_stage_left_open():
    clock = StageClock()
    clock.start("features")
    clock.stop(cached=True, measured_s=12.5)
    clock.start("matching")
    clock.stop()
    clock.add("total", 3.0)
    got = clock.to_json()
    assert got["features_cached"] is True and got["features_measured_s"] == 12.5
    assert got["matches_cached"] is False and got["total"] == 3.0 and "matching_measured_s" not in got
    clock.start("mapping")  # fails half-way: closed, nothing recorded, its sampler stopped
    sampler = clock._open.sampler
    clock.close()
    assert clock.get("mapping") is None and not sampler._thread.is_alive()
    with pytest.raises(RuntimeError):
        clock.stop()
