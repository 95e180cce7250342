"""Where a second core goes in the front end (features, matching, verification): four ways to run it.

    python scripts/profile_frontend.py SCENE_DIR --out OUT.json [--modes one serial dask2 threads2] [--repeat 1]

Each mode runs in its own process on the scene's images (no cache), with GT intrinsics and
sequential pairs (overlap 10), and records per stage wall and CPU seconds (this process and its
workers) and peak memory (:mod:`polarref.sfm.stages`):

* ``one``: everything on one thread (BLAS, OpenCV, the pipeline);
* ``serial``: the pipeline's one-task-at-a-time loop with the libraries' own threads left at
  their defaults (OpenCV's parallel loops inside SIFT, multi-threaded BLAS for large pairs): what
  a "serial" run was before issue 34;
* ``dask2``: two Dask worker processes (``--workers 2``), one thread each, exchanging features
  and matches through files;
* ``threads2``: two front-end threads in this process (:mod:`polarref.sfm.frontend`, the default now).

CPU seconds over wall seconds is the number of cores a stage really kept busy; on the shared
machine wall times are indicative only (the load average before and after is stored).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

MODES = ("one", "serial", "dask2", "threads2")
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _child(scene: str, mode: str) -> None:
    import dataclasses

    import cv2
    import numpy as np

    from polarref.core import execution
    from polarref.core.records import to_dict
    from polarref.sfm.pipeline import PRESETS, cameras_for_images, load_images_and_features, match_and_verify
    from polarref.sfm.stages import StageClock
    from synth.scene import load_scene

    if mode == "one":
        cv2.setNumThreads(1)
    root = Path(scene)
    loaded = load_scene(root)
    base = PRESETS["default"]
    cfg = dataclasses.replace(base, use_cache=False, threads=2 if mode == "threads2" else 1,
                              matching=dataclasses.replace(base.matching, pairing="sequential", sequential_overlap=10))
    clock = StageClock()
    clock.start("executor")
    with execution.using(workers=2 if mode == "dask2" else None):
        clock.stop()
        feats, _, key = load_images_and_features(root / "images", cfg, clock)
        cams, idx = cameras_for_images([f.name for f in feats], [(f.width, f.height) for f in feats],
                                       loaded.polarref_camera())
        m = match_and_verify(feats, cams, idx, cfg, key, clock)
    print(json.dumps({"mode": mode, "stages": [to_dict(s) for s in clock.stages],
                      "verified_pairs": len(m.geometries),
                      "inliers": int(sum(len(g.inliers) for g in m.geometries.values())),
                      "keypoints": int(np.sum([len(f.keypoints) for f in feats]))}))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    ap.add_argument("--repeat", type=int, default=1, help="rounds over the modes (interleaved)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        _child(a.scene, a.child)
        return 0
    if a.out.exists():
        print(f"profile_frontend: error: {a.out} exists", file=sys.stderr)
        return 1
    from polarref.core.provenance import collect

    runs = []
    for r in range(a.repeat):
        for mode in a.modes:
            env = dict(os.environ, **{v: "1" for v in THREAD_VARS}) if mode in ("one", "dask2", "threads2") else \
                {k: v for k, v in os.environ.items() if k not in THREAD_VARS}
            load = os.getloadavg()
            out = subprocess.run([sys.executable, __file__, a.scene, "--out", str(a.out), "--child", mode],
                                 env=env, capture_output=True, text=True, check=False)
            if out.returncode != 0:
                print(f"profile_frontend: mode {mode} failed: {out.stderr.strip().splitlines()[-1:]}", file=sys.stderr)
                return 1
            run = json.loads(out.stdout.strip().splitlines()[-1])
            run.update(repeat=r + 1, load_average_before=list(load), load_average_after=list(os.getloadavg()))
            runs.append(run)
            busy = {s["stage"]: round(s["cpu_s"] / s["wall_s"], 2) for s in run["stages"] if s["wall_s"] > 0.05}
            print(mode, {s["stage"]: round(s["wall_s"], 1) for s in run["stages"]}, "cores busy:", busy,
                  "load", round(load[0], 1), flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"scene": a.scene, "runs": runs, "provenance": collect(seeds={"verification": 0}),
                                 "note": "shared 2-core machine: wall times indicative; CPU / wall = cores kept busy"},
                                indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
