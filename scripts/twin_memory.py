"""Peak memory of our SfM on a finished twin run (issue 14: ours <= 2 GB at 631 views).

Reruns one ``ours-*`` method of a twin comparison in this process with the checked-out code,
reusing the run's feature and match caches (so only tracks, mapping and BA run, as in the twin's
``ours-<ba>`` stage), and writes its peak resident set, stage times and results beside the
stage record's, with provenance. A rerun must reproduce the stage's model: the script compares
the two points3D.txt files byte for byte.

    python scripts/twin_memory.py /root/polarref-twins/rosetta euclidean reports/bench-sfm/twin-memory-rosetta-euclidean.json
"""

import argparse
import filecmp
import json
import sys
from pathlib import Path

from polarref.compare.twins.pipeline import rerun_ours_stage
from polarref.core.errors import PolarrefError
from polarref.core.provenance import collect


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a finished twin run folder (polarref compare <twin> --out RUN)")
    ap.add_argument("ba", choices=("euclidean", "polar"))
    ap.add_argument("out", type=Path, help="JSON to write (refused if it exists)")
    ap.add_argument("--work", type=Path, default=None, help="scratch folder for the model (default: beside OUT)")
    a = ap.parse_args(argv)
    try:
        rr = rerun_ours_stage(a.run, a.ba, a.out, a.work)
    except PolarrefError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    stage, run, scene, r = rr.stage, rr.run, rr.scene, rr.result
    same = filecmp.cmp(Path(r.model_dir) / "points3D.txt", Path(stage.result.model_dir) / "points3D.txt",
                       shallow=False)
    rec = {"twin": run.twin, "method": f"ours-{a.ba}", "images": len(scene.image_names),
           "peak_rss_mb": r.peak_rss_mb, "stage_runtime_s": r.stage_runtime_s,
           "wall_s": rr.wall_s, "model_identical_to_stage": same,
           "stage_record": {"peak_rss_mb": stage.result.peak_rss_mb,
                            "stage_runtime_s": stage.result.stage_runtime_s,
                            "finished_utc": stage.finished_utc, "git_commit": stage.git_commit or None},
           "provenance": collect()}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(rec, indent=1, default=str) + "\n")
    print(f"ours-{a.ba} on {run.twin}: peak {r.peak_rss_mb:.0f} MB (stage record {stage.result.peak_rss_mb:.0f} MB), "
          f"model identical: {same}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
