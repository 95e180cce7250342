"""Why a photo set's images stay out of the largest model: for each one, its verified matches
with the model's images and how many of its keypoints reach the model's 3D points (what PnP
gets), next to the threshold PnP needs; its tracks seen by one model image only (new content)
or by two or more but without a point (rejected by the ray angle or the error threshold).
Runs ``polarref sfm``'s photo rules in process with the settings of scripts/eval_photo_sets.py,
once as the mapper is and once without lowering the ray angle when registration stalls
(``MapperConfig.stalled_min_angle_deg``). Writes ``<out>/<set>_unregistered.json`` with provenance.

    POLARREF_PHOTO_SETS=/work/photo-sets PYTHONPATH=. python scripts/explain_unregistered.py lund \
        --out reports/collections
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from polarref.core.provenance import collect
from polarref.io import photo_sets as PS
from polarref.sfm import budget as B
from polarref.sfm.calibration import cameras_from_exif
from polarref.sfm.config import SfMConfig
from polarref.sfm.features import FeatureConfig
from polarref.sfm.pipeline import load_images_and_features, match_and_verify, run_sfm
from polarref.sfm.tracks import build_tracks


def explain(name: str, max_image_size: int, stalled_min_angle_deg: float) -> dict:
    images = PS.image_dir(name)
    if images is None:
        raise SystemExit(f"photo set {name!r} is not laid out (docs/photo-sets.md)")
    cfg = dataclasses.replace(SfMConfig(), features=FeatureConfig(max_image_size=max_image_size))
    cfg = dataclasses.replace(cfg, mapper=dataclasses.replace(cfg.mapper, stalled_min_angle_deg=stalled_min_angle_deg))
    res = run_sfm(images, None, cfg)
    # the same features, matches and tracks as that run (cache hits); checked by the track count
    feats_cfg, _ = B.choose(cfg.features, SfMConfig().features, photos=True, full_size=False,
                            sizes=B.header_sizes(images))
    cfg = dataclasses.replace(cfg, features=feats_cfg)
    feats, _, key = load_images_and_features(images, cfg, {})
    cams, cam_idx, sources = cameras_from_exif([images / f.name for f in feats], [(f.width, f.height) for f in feats],
                                               cfg.camera_mode)
    if "default" in sources:
        raise SystemExit(f"{name}: cameras without EXIF focal are verified differently; not handled here")
    geoms = match_and_verify(feats, cams, cam_idx, cfg, key, {}).geometries
    tracks = build_tracks([len(f.keypoints) for f in feats], {k: g.inliers for k, g in geoms.items()},
                          conflicts=cfg.track_conflicts)
    assert tracks.num_tracks == res.report.num_tracks, (tracks.num_tracks, res.report.num_tracks)
    rec = res.reconstruction
    names = [f.name for f in feats]
    in_model = np.zeros(len(names), bool)
    in_model[[im.image_id - 1 for im in rec.images.values()]] = True
    has_point = np.zeros(tracks.num_tracks, bool)
    has_point[np.array(sorted(rec.points3D), np.int64) - 1] = True
    rows = []
    for i in np.flatnonzero(~in_model):
        mine = tracks.image == i
        with_model = {names[b if a == i else a]: int(len(g.inliers)) for (a, b), g in geoms.items()
                      if i in (a, b) and in_model[b if a == i else a]}
        # its tracks that reach the model: seen by >= 2 model images (could have a point) or by one
        t = np.unique(tracks.track[mine])
        seen = np.bincount(tracks.track[in_model[tracks.image]], minlength=tracks.num_tracks)[t]
        rows.append({"image": names[i], "verified_inliers_with_model": int(sum(with_model.values())),
                     "tracks_seen_by_one_model_image": int((seen == 1).sum()),
                     "tracks_seen_by_two_or_more_without_point": int(((seen >= 2) & ~has_point[t]).sum()),
                     "best_model_partner": max(with_model, key=with_model.get) if with_model else None,
                     "best_partner_inliers": max(with_model.values()) if with_model else 0,
                     "keypoints_on_model_points": int(has_point[tracks.track[mine]].sum())})
    return {"set": name, "max_image_size": max_image_size, "registered": int(in_model.sum()),
            "num_images": len(names), "pnp_min_inliers": cfg.mapper.register.min_inliers,
            "min_triangulation_angle_deg": cfg.triangulation.min_angle_deg,
            "stalled_min_angle_deg": stalled_min_angle_deg, "models": [m.num_registered for m in res.report.models],
            "unregistered": rows, "reasons": [dataclasses.asdict(u) for u in res.report.unregistered or []]}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("set", choices=[s.name for s in PS.PHOTO_SETS if s.repo])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--max-image-size", type=int, default=1600)
    args = p.parse_args(argv)
    default = SfMConfig().mapper.stalled_min_angle_deg
    # the mapper as it is, and without lowering the angle when it stalls (the triangulation's own)
    runs = {f"stalled_min_angle_{a:g}_deg": explain(args.set, args.max_image_size, a)
            for a in (default, SfMConfig().triangulation.min_angle_deg)}
    table = {"provenance": collect(seeds={"verification": 0, "registration": 0}), "runs": runs}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{args.set}_unregistered.json").write_text(json.dumps(table, indent=1, default=str) + "\n")
    for key, run in runs.items():
        print(key, run["registered"], "of", run["num_images"], "models", run["models"])
        for r in run["unregistered"][:3]:
            print(" ", json.dumps(r))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
