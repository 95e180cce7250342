"""Export a twin's final BA problem (issue 35): our Euclidean SfM as the twin campaign runs it
(compare preset "default", the twin's prior-based pairs, the campaign's seed), with
``export_final_ba`` on, so the last global BA lands in one ``.npz`` with the ground-truth poses.

    PYTHONPATH=$PWD python scripts/twin_ba_export.py SCENE_DIR TWIN OUT_DIR [--seed 0] [--threads 2]

SCENE_DIR: a rendered twin folder, or the twin's name (rendered into the cache if needed, as
the campaign does); OUT_DIR gets pairs.json + the pairs
file, sfm/ (model, metrics.json) and final-ba.npz. A finished final-ba.npz is kept (resume)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from polarref.compare.run import presets
from polarref.compare.run.scenes import prepare
from polarref.compare.twins.campaign_jobs import seeded_config
from polarref.compare.twins.pipeline import choose_pairs
from polarref.core.data import cache_root
from polarref.sfm.pipeline import run_sfm, with_ba


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene_dir", help="a rendered twin folder, or the twin's name")
    ap.add_argument("twin", help="the twin's name (its pairing rule): mappilot | rosetta | poets-park")
    ap.add_argument("out", type=Path)
    ap.add_argument("--seed", type=int, default=0, help="the campaign seed (RANSACs)")
    ap.add_argument("--threads", type=int, default=2, help="front-end threads (results do not depend on it)")
    ap.add_argument("--cache", default="", help="feature/match cache folder ('' = the default cache)")
    a = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    target = a.out / "final-ba.npz"
    if target.is_file():
        print(f"{target} exists: kept")
        return 0
    a.out.mkdir(parents=True, exist_ok=True)
    scene = prepare(str(a.scene_dir), presets.DEFAULT, a.seed)
    pairs, n = choose_pairs(a.twin, scene, a.out)
    cache = a.cache or str(cache_root() / "sfm")  # the pipeline's own default: its cached features are reused
    config = with_ba(seeded_config(presets.DEFAULT.name, cache, str(pairs), a.seed, a.threads), "euclidean")
    res = run_sfm(scene.image_dir, a.out / "sfm", config, camera=scene.camera, gt=scene.gt, overwrite=True,
                  export_final_ba=target)
    m = res.report.metrics
    print(f"{n} pairs; registered {m.registered_images}/{m.num_images}; wrote {target}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
