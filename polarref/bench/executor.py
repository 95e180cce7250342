"""Benchmark of :mod:`polarref.core.execution`: render + feature extraction of an N-view comet with
1 and 2 local Dask workers (and serial, in-process), and the scheduler's overhead per task.

    python -m polarref.bench.executor --views 168 --out reports/bench-exec [--modes serial 1 2]

Writes ``OUT/bench.json``: per mode the wall time of cluster start, rendering (per-worker scene
build included) and feature extraction (per-image tasks, files in and out), the per-task
overhead of many no-op tasks, and provenance (git commit and dirty flag, machine, versions, load
average before and after: the numbers are only comparable side by side within one run).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

from polarref.bench.records import ExecutorMode, TaskOverhead
from polarref.core import records
from polarref.core.atomic import atomic_write
from polarref.core import execution
from polarref.core.data import REPO_ROOT
from polarref.core.provenance import collect
from polarref.sfm.stages import StageClock


def _noop(x: int) -> int:
    return x


def overhead_per_task(ex, n: int) -> TaskOverhead:
    """Wall time per no-op task through ``ex.map`` (the scheduler round trip and bookkeeping)."""
    ex.map(_noop, list(range(min(n, 20))), desc="warm-up")
    t0 = time.perf_counter()
    out = ex.map(_noop, list(range(n)), desc="noop")
    wall = time.perf_counter() - t0
    assert out == list(range(n))
    return TaskOverhead(n, wall, 1e3 * wall / n)


def run_mode(mode: str, views: int, noop_tasks: int, work: Path) -> ExecutorMode:
    from polarref.sfm.pipeline import SfMConfig, load_images_and_features
    from synth.config import preset
    from synth.render import render_scene

    workers = None if mode == "serial" else int(mode)
    t0 = time.perf_counter()
    with execution.using(workers=workers) as ex:
        started = time.perf_counter() - t0
        out = work / f"comet-{mode}"
        cfg = preset("comet", "default", views=views)
        t1 = time.perf_counter()
        render_scene("comet", out, cfg)
        render_s = time.perf_counter() - t1
        t2 = time.perf_counter()
        feats, _, _ = load_images_and_features(out / "images", SfMConfig(use_cache=False,
                                                                         cache_dir=str(work / f"cache-{mode}")),
                                               StageClock())
        features_s = time.perf_counter() - t2
        overhead = overhead_per_task(ex, noop_tasks)
        desc = ex.describe()
    return ExecutorMode(mode, len(desc.workers) if workers else 0, desc.detail, started, render_s, views,
                        render_s / views, features_s, int(sum(len(f.keypoints) for f in feats)), overhead, cfg)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m polarref.bench.executor", description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=168, help="comet views (default preset otherwise: 640x480, 16 spp)")
    parser.add_argument("--modes", nargs="+", default=["serial", "1", "2"],
                        help="serial and/or numbers of local workers (default: serial 1 2)")
    parser.add_argument("--noop-tasks", type=int, default=500, help="tasks of the overhead measurement")
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "reports" / "bench-exec")
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args(argv)
    target = args.out / "bench.json"
    if target.exists() and not args.overwrite:
        print(f"bench_exec: error: {target} exists; pass --overwrite", file=sys.stderr)
        return 1
    load_before = os.getloadavg()
    work = Path(tempfile.mkdtemp(prefix="polarref-bench-exec-"))
    started = datetime.now(timezone.utc).isoformat(timespec="seconds")
    try:
        results = [run_mode(m, args.views, args.noop_tasks, work) for m in args.modes]
    finally:
        shutil.rmtree(work, ignore_errors=True)
    one = next((r for r in results if r.mode == "1"), None)
    two = next((r for r in results if r.mode == "2"), None)
    speedup = {}
    if one is not None and two is not None:
        speedup = {"render_s": one.render_s / two.render_s, "features_s": one.features_s / two.features_s}
    report = {
        "benchmark": "polarref.core.execution: render + features of a comet scene, per-task overhead",
        "command": " ".join(["python -m polarref.bench.executor", *(argv if argv is not None else sys.argv[1:])]),
        "created": started, "results": [records.to_dict(r) for r in results], "speedup_2_vs_1_worker": speedup,
        "provenance": {**collect(seeds={"render": 0}),
                       "load_average_before": list(load_before), "load_average_after": list(os.getloadavg()),
                       "note": "shared machine loaded by other jobs: compare modes within this file only"},
    }
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write(target, json.dumps(report, indent=1) + "\n")
    for r in results:
        print(f"{r.mode:>6}: start {r.cluster_start_s:.1f} s, render {r.render_s:.1f} s "
              f"({r.render_s_per_view:.3f} s/view), features {r.features_s:.1f} s, "
              f"overhead {r.overhead.per_task_ms:.2f} ms/task")
    if one is not None and two is not None:
        print(f"speed-up 2 vs 1 worker: render x{one.render_s / two.render_s:.2f}, "
              f"features x{one.features_s / two.features_s:.2f}")
    print(f"wrote {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
