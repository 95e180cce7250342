"""Profile our SfM on a rendered scene: stage times, CPU seconds, BA statistics, GT error.

    python scripts/profile_sfm.py SCENE_DIR [--pairing sequential] [--profile OUT.prof]
                                  [--no-cache] [mapper_field=value ...]

Features and matches come from the cache when present (mapping is what is profiled);
``--no-cache`` times every stage. CPU seconds (getrusage) are printed beside wall seconds:
on a loaded machine they are the steadier figure. Mapper fields (``local_ba_iterations=25``,
``global_ba_growth=1.25``, ...) override :class:`polarref.sfm.mapper.MapperConfig`.
Method and numbers: reports/bench-sfm/notes.md.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import pstats
import resource
from pathlib import Path

import numpy as np
from polarref.model.colmap import read_model


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main() -> None:
    from polarref.model import Reconstruction
    from polarref.sfm.pipeline import PRESETS, run_sfm
    from synth.scene import load_scene

    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("overrides", nargs="*", help="MapperConfig field=value")
    ap.add_argument("--pairing", default="sequential")
    ap.add_argument("--profile", help="write cProfile stats here and print the top functions")
    ap.add_argument("--no-cache", action="store_true")
    a = ap.parse_args()
    root = Path(a.scene)
    scene = load_scene(root)
    gt = read_model(scene.gt_dir)
    cfg = PRESETS["default"]
    over = {}
    for kv in a.overrides:
        k, v = kv.split("=", 1)
        kind = type(getattr(cfg.mapper, k))
        over[k] = v if kind is str else kind(v)
    cfg = dataclasses.replace(cfg, use_cache=not a.no_cache,
                              matching=dataclasses.replace(cfg.matching, pairing=a.pairing, sequential_overlap=10),
                              mapper=dataclasses.replace(cfg.mapper, **over))
    prof = cProfile.Profile() if a.profile else None
    cpu0 = _cpu()
    if prof:
        prof.enable()
    res = run_sfm(root / "images", None, cfg, camera=scene.polarref_camera(), gt=gt)
    if prof:
        prof.disable()
    cpu = _cpu() - cpu0
    m = res.report.to_json()  # the metrics.json form: BA runs as flat dicts
    t = res.report.runtime_s
    print(over, f"cpu {cpu:.1f} s", {k: round(v, 2) for k, v in t.items() if isinstance(v, float)})
    for kind in ("local", "global"):
        b = [x for x in m["ba"] if x.get("kind") == kind]
        if b:
            print(f"{kind} BA: {len(b)} calls, {sum(x.get('wall_s', 0) for x in b):.1f} s, "
                  f"{sum(x.get('iterations', 0) for x in b)} iterations, "
                  f"mean {np.mean([x.get('num_observations', 0) for x in b]):.0f} observations")
    q = res.report.metrics
    print(f"registered {q.registered_images}, tie points {q.tie_points}, rotation error "
          f"{q.gt.rotation_error_deg_mean:.4f} deg (rotation-aligned {q.gt.rotation_error_rotalign_deg_mean:.4f})")
    if prof:
        prof.dump_stats(a.profile)
        pstats.Stats(a.profile).sort_stats("tottime").print_stats(25)


if __name__ == "__main__":
    main()
