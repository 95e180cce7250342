"""One ``ours-*`` method of a finished twin run, rerun with a pipeline variant, scored beside the run's.

Reuses the run's feature and match caches (the variants here change only tracks and mapping, so
the caches stay valid), reruns the method in this process with the checked-out code, and scores
the variant's model and the stage's model with the twin tables' scoring (registered views, tie
points, reprojected pixels, mean reprojection error, GT rotation and centre errors after a Sim3
alignment). Writes one JSON with both, the variant's settings, stage times, peak memory and
provenance. Used for the rosetta tie-point target of issue 13 (track conflicts "split" against
the tables' "drop").

    python scripts/twin_variant.py /root/polarref-twins/rosetta euclidean --track-conflicts split \\
        reports/paper-tables/rosetta/variant-track-conflicts-split-euclidean.json
"""

import argparse
import json
import sys
from pathlib import Path

from polarref.compare.claims.thresholds import TWIN_ROSETTA_MIN_TIES
from polarref.compare.twins.pipeline import rerun_ours_stage, score_model
from polarref.core.errors import PolarrefError
from polarref.core.provenance import collect
from polarref.sfm.pipeline import PRESETS

TIE_POINT_TARGET = {"rosetta": TWIN_ROSETTA_MIN_TIES}  # issue 13's done-when (the other twins have none)


def _scores(m) -> dict:
    """The figures of the tables (a ReconstructionMetrics) under this file's keys."""
    return {"registered": m.registered_images, "tie_points": m.tie_points, "reprojected_px": m.reprojected_px,
            "mean_reprojection_error_px": m.mean_reprojection_error_px,
            "rotation_error_deg": None if m.gt is None else m.gt.rotation_error_deg_mean,
            "centre_error_rel": None if m.gt is None else m.gt.center_error_rel_mean}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a finished twin run folder (polarref compare <twin> --out RUN)")
    ap.add_argument("ba", choices=("euclidean", "polar"))
    ap.add_argument("out", type=Path, help="JSON to write (refused if it exists)")
    ap.add_argument("--track-conflicts", choices=("drop", "split"), required=True)
    ap.add_argument("--work", type=Path, default=None, help="scratch folder for the model (default: beside OUT)")
    a = ap.parse_args(argv)
    try:
        rr = rerun_ours_stage(a.run, a.ba, a.out, a.work, track_conflicts=a.track_conflicts)
    except PolarrefError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    stage, run, scene, r, wall = rr.stage, rr.run, rr.scene, rr.result, rr.wall_s
    variant = {**_scores(score_model(r.model_dir, scene.gt)), "peak_rss_mb": r.peak_rss_mb,
               "stage_runtime_s": r.stage_runtime_s, "wall_s": wall}
    baseline = {**_scores(score_model(stage.result.model_dir, scene.gt)),
                "peak_rss_mb": stage.result.peak_rss_mb,
                "stage_runtime_s": stage.result.stage_runtime_s, "wall_s": stage.wall_s,
                "finished_utc": stage.finished_utc, "git_commit": stage.git_commit or None}
    target = TIE_POINT_TARGET.get(run.twin)
    rec = {"twin": run.twin, "method": f"ours-{a.ba}", "images": len(scene.image_names),
           "variant_settings": {"track_conflicts": a.track_conflicts},
           "baseline_settings": {"track_conflicts": PRESETS["default"].track_conflicts},
           "variant": variant, "baseline": baseline,
           "tie_point_target": target,
           "target_met": None if target is None else {"variant": variant["tie_points"] >= target,
                                                      "baseline": baseline["tie_points"] >= target},
           "provenance": collect()}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(rec, indent=1, default=str) + "\n")
    print(f"ours-{a.ba} on {run.twin}, track conflicts {a.track_conflicts}: {variant['tie_points']:,} tie points "
          f"(stage: {baseline['tie_points']:,}), {variant['mean_reprojection_error_px']:.3f} px "
          f"({baseline['mean_reprojection_error_px']:.3f}), rotation {variant['rotation_error_deg']:.4f} deg "
          f"({baseline['rotation_error_deg']:.4f}), {wall / 60:.1f} min, peak {r.peak_rss_mb:.0f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
