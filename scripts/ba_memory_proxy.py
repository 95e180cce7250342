"""Peak memory of one bundle adjustment on a synthetic problem shaped like a twin's final global BA.

The rosetta twin's last global BA (631 cameras, 99,325 points, 1,220,315 observations, mean
track 12.3) takes ~20 min to reach through the whole mapper (scripts/twin_memory.py); this
builds a problem of the same shape directly (cameras on a ring looking inwards, each point seen
by a run of consecutive cameras) and reports the peak resident set the solve adds over the
process's resident set just before it (``ru_maxrss`` minus ``/proc/self/statm``), plus the
result's checksum so two code versions can be compared for identical results.

    python scripts/ba_memory_proxy.py polar --cameras 631 --points 99325 --track 12.3

With ``--model DIR`` (a COLMAP model folder, e.g. a finished twin's ours-polar/sfm/model, read
only) the problem is that model's full BA instead, ``--fixed-image`` held fixed as the
mapper's gauge: the real geometry and observations of the twin's last global BA.
"""

from __future__ import annotations

import argparse
import gc
import hashlib
import json
import resource
import sys
import time

import numpy as np
from polarref.model.colmap import read_model


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("param")
    ap.add_argument("--cameras", type=int, default=631)
    ap.add_argument("--points", type=int, default=99325)
    ap.add_argument("--track", type=float, default=12.3)
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--kernels", default="auto")
    ap.add_argument("--model", default=None, help="COLMAP model folder: its full BA instead of a ring")
    ap.add_argument("--fixed-image", type=int, default=None, help="with --model: image id held fixed")
    a = ap.parse_args(argv)
    from polarref.ba import BAOptions, prepare, solve
    from polarref.ba import kernels
    from polarref.ba.synthetic import ring_problem

    kernels.warm_up()
    if a.model:
        from polarref.ba.adapter import problem_from_reconstruction
        from polarref.model.reconstruction import Reconstruction

        rec = read_model(a.model)
        p = problem_from_reconstruction(rec, fixed_image_ids=[a.fixed_image] if a.fixed_image else None)
        del rec
    else:
        p = ring_problem(a.cameras, a.points, a.track)
    prepare(p)
    gc.collect()
    before = rss_mb()
    t0 = time.process_time()
    s = solve(p, BAOptions(param=a.param, max_iterations=a.iterations, kernels=a.kernels), prepared=True)
    cpu = time.process_time() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    digest = hashlib.sha256(np.ascontiguousarray(p.X).tobytes() + p.R.tobytes() + p.C.tobytes()).hexdigest()[:16]
    print(json.dumps({"param": a.param, "observations": p.num_observations, "points": p.num_points,
                      "cameras": p.num_cameras, "rss_before_mb": round(before, 1),
                      "peak_rss_mb": round(peak, 1), "peak_extra_mb": round(peak - before, 1),
                      "iterations": s.iterations, "accepted": s.accepted_iterations,
                      "final_cost": s.final_cost, "cpu_s": round(cpu, 1), "result_sha": digest,
                      "linear_solver": s.linear_solver}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
