"""Before/after of the matcher's mutual check on real twin descriptors (issue 34).

    python scripts/match_speed.py FEATURES.npz PAIRS.txt OUT.json [--repeats 3]

Matches every pair of the pairs file (a twin's match list) with the column-argmax reference and
with the column-max path :func:`polarref.sfm.matching.match_descriptors` now takes, interleaved,
on one BLAS thread (the front end's setting for these sizes), and records the CPU seconds per
pair of each and whether every pair's matches are identical. CPU time is the figure: the machine
is shared and its wall time follows the load (recorded).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    from threadpoolctl import threadpool_limits

    from polarref.core.atomic import atomic_write
    from polarref.core.provenance import collect
    from polarref.sfm import matching as M
    from polarref.sfm.feature_cache import load_descriptors, load_without_descriptors
    from polarref.sfm.pairing import read_pairs

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("features", type=Path)
    ap.add_argument("pairs", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args(argv)
    feats = load_without_descriptors(a.features)
    load_descriptors(a.features, feats)
    pairs = read_pairs(a.pairs, [f.name for f in feats], skip_unknown=True)
    desc = [f.descriptors for f in feats]
    cfg = M.MatchConfig()
    cpu = {"column argmax (before)": [], "column max (after)": []}
    identical, fallbacks, matches = True, 0, 0
    load0 = os.getloadavg()
    with threadpool_limits(1, user_api="blas"):
        for _ in range(a.repeats):
            for i, j in pairs:
                t = time.process_time()
                ref = M._match_by_column_argmax(desc[i], desc[j], cfg)
                cpu["column argmax (before)"].append(time.process_time() - t)
                t = time.process_time()
                fast = M._match_mutual_by_column_max(desc[i], desc[j], cfg)
                cpu["column max (after)"].append(time.process_time() - t)
                fallbacks += fast is None
                got = M.match_descriptors(desc[i], desc[j], cfg)
                identical &= bool(np.array_equal(ref, got))
                matches += len(got)
    per_pair = {k: float(np.sum(v) / len(v)) for k, v in cpu.items()}
    doc = {"format": "polarref-match-speed/1", "features": a.features.name, "pairs_file": a.pairs.name,
           "pairs": len(pairs), "images": len(feats), "mean_keypoints": float(np.mean([len(d) for d in desc])),
           "repeats": a.repeats, "cpu_s_per_pair": per_pair,
           "speedup": per_pair["column argmax (before)"] / per_pair["column max (after)"],
           "identical_matches": identical, "pairs_on_the_argmax_fallback": fallbacks // a.repeats,
           "matches_per_repeat": matches // a.repeats, "blas_threads": 1,
           "load_before": list(load0), "load_after": list(os.getloadavg()), "environment": collect()}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(a.out, json.dumps(doc, indent=1) + "\n")
    print(json.dumps({k: doc[k] for k in ("pairs", "cpu_s_per_pair", "speedup", "identical_matches")}))
    return 0 if identical else 1


if __name__ == "__main__":
    sys.exit(main())
