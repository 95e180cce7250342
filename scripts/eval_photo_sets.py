"""Evaluation over real photo sets (issue 32): ``polarref sfm`` and pycolmap with its defaults.

Each set (polarref.io.photo_sets; lay them out first, see docs/photo-sets.md) is run by

* ours: ``python -m polarref sfm <images> --out <work>/<set>/ours --max-image-size S`` out of
  process, as a user runs it (photo mode: cameras from EXIF or guessed, never from GT);
* pycolmap: :func:`polarref.peers.colmap_sfm.run_default_sfm`, its defaults with the same S.

Both models are scored by one rule (polarref.metrics.evaluate on the largest model: registered
images, tie points = 3D points, mean reprojection error over all observations) and, where the
set has ground truth, rotation / centre errors after a similarity alignment. Writes
``<out>/photo_sets.json`` (with provenance) and ``<out>/photo_sets.md``.

    PYTHONPATH=. python scripts/eval_photo_sets.py --work /tmp/eval --out reports/collections
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from polarref.core.provenance import collect
from polarref.io import photo_sets as PS
from polarref.io.strecha import read_ground_truth
from polarref.metrics import evaluate
from polarref.model.colmap import from_pycolmap, read_model
from polarref.peers.colmap_sfm import run_default_sfm

ROOT = Path(__file__).resolve().parents[1]
MAX_IMAGE_SIZE = {"fountain": 1024}  # the rest: --max-image-size
SEED = 0


def _scores(rec, gt, num_images: int) -> dict:
    m = evaluate(rec, gt, num_images=num_images)
    out = {"registered_images": m.registered_images, "num_images": num_images, "tie_points": m.tie_points,
           "mean_reprojection_error_px": m.mean_reprojection_error_px,
           "mean_track_length": m.mean_track_length}
    if m.gt is not None:
        # rotation error after the similarity fitted to the centres, and after the best rotation
        # alone (gauge-free: a bias shared by all images, e.g. the principal point held at the
        # centre, does not count)
        out.update(rotation_error_deg_mean=m.gt.rotation_error_deg_mean,
                   rotation_error_rotalign_deg_mean=m.gt.rotation_error_rotalign_deg_mean,
                   center_error_rel_mean=m.gt.center_error_rel_mean, gt_matched=m.gt.num_matched)
    return out


def _ours(name: str, images: Path, work: Path, size: int, gt, n: int, log) -> dict:
    out = work / "ours"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    t0 = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "polarref", "sfm", str(images), "--out", str(out),
                          "--max-image-size", str(size), "--overwrite"], env=env, capture_output=True, text=True)
    log.write(f"== {name} ours rc={run.returncode}\n{run.stdout}{run.stderr}\n")
    res = {"command": f"python -m polarref sfm {images} --out {out} --max-image-size {size} --overwrite",
           "wall_s": time.perf_counter() - t0, "stderr_warnings": sum("warning" in ln.lower()
                                                                      for ln in run.stderr.splitlines())}
    if run.returncode != 0:
        return {**res, "error": run.stderr.strip().splitlines()[-1:]}
    metrics = json.loads((out / "metrics.json").read_text())
    res.update(_scores(read_model(out / "model"), gt, n))
    res["models"] = [mm["num_registered"] for mm in metrics.get("models", [])]
    res["unregistered"] = [u["name"] for u in metrics.get("unregistered", [])]
    res["feature_budget"] = metrics.get("feature_budget")
    res["focal_px"] = {c["camera_id"]: round(c["refined"][0], 1) for c in metrics["cameras"]}
    # the refined intrinsics in full (principal point: held at the centre, or refined, sfm/mapper.py)
    res["cameras"] = {c["camera_id"]: dict(zip(c["names"], (round(v, 6) for v in c["refined"])))
                      for c in metrics["cameras"]}
    return res


def _pycolmap(name: str, images: Path, work: Path, size: int, gt, n: int, reuse: bool) -> dict:
    """pycolmap's scores; with ``reuse`` those of an earlier run of the same call on the same
    photos (``work/pycolmap.json``): pycolmap does not depend on our code, and it is the slow half."""
    call = f"run_default_sfm(max_image_size={size}, seed={SEED}, num_threads=1)"
    record = work / "pycolmap.json"
    photos = sorted((q.name, q.stat().st_size) for q in images.iterdir())
    if reuse and record.is_file():
        old = json.loads(record.read_text())
        models = [read_model(d) for d in (work / "pycolmap" / "sparse").glob("[0-9]*")] if (
            old.get("call") == call and old.get("photos") == [list(p) for p in photos]) else None
        if models:
            # the models of that run, rescored now by the same rule as ours
            best = max(models, key=lambda r: len(r.images))
            return {**old["result"], **_scores(best, gt, n), "reused_from": str(record)}
    res = _pycolmap_run(images, work, size, gt, n, call)
    record.write_text(json.dumps({"call": call, "photos": photos, "result": res}, default=str))
    return res


def _pycolmap_run(images: Path, work: Path, size: int, gt, n: int, call: str) -> dict:
    t0 = time.perf_counter()
    run = run_default_sfm(images, work / "pycolmap", max_image_size=size, seed=SEED, overwrite=True)
    res = {"call": call, "wall_s": time.perf_counter() - t0, "models": [r.num_reg_images() for r in run.models],
           "verified_pairs": run.verified_pairs}
    if not run.models:
        return {**res, "registered_images": 0, "num_images": n}
    res.update(_scores(from_pycolmap(run.models[0]), gt, n))
    res["focal_px"] = {int(k): round(c.mean_focal_length(), 1) for k, c in run.models[0].cameras.items()}
    return res


def _verdict(o: dict, p: dict) -> dict:
    v = {"registered_at_least_pycolmap": o.get("registered_images", 0) >= p.get("registered_images", 0),
         "reprojection_below_1px": o.get("mean_reprojection_error_px", 99) < 1.0}
    for k in ("rotation_error_deg_mean", "rotation_error_rotalign_deg_mean"):
        if k in o and k in p:
            v[f"{k}_within_1.2x_pycolmap"] = o[k] <= 1.2 * p[k]
    return v


def _markdown(table: dict) -> str:
    rows = ["| set | images | ours reg. | pycolmap reg. | ours tie pts | pycolmap tie pts | ours reproj. px | "
            "pycolmap reproj. px | ours rot. deg | pycolmap rot. deg | ours rot. deg (rot.-aligned) | "
            "pycolmap rot. deg (rot.-aligned) | done-when |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

    def f(v, fmt):
        return format(v, fmt) if isinstance(v, (int, float)) else "-"
    for name, r in table["sets"].items():
        o, p = r["ours"], r["pycolmap"]
        ok = "met" if all(r["verdict"].values()) else "NOT met: " + ", ".join(k for k, v in r["verdict"].items() if not v)
        rows.append(f"| {name} | {r['num_images']} | {f(o.get('registered_images'), 'd')} | "
                    f"{f(p.get('registered_images'), 'd')} | {f(o.get('tie_points'), 'd')} | "
                    f"{f(p.get('tie_points'), 'd')} | {f(o.get('mean_reprojection_error_px'), '.3f')} | "
                    f"{f(p.get('mean_reprojection_error_px'), '.3f')} | {f(o.get('rotation_error_deg_mean'), '.3f')} | "
                    f"{f(p.get('rotation_error_deg_mean'), '.3f')} | "
                    f"{f(o.get('rotation_error_rotalign_deg_mean'), '.3f')} | "
                    f"{f(p.get('rotation_error_rotalign_deg_mean'), '.3f')} | {ok} |")
    prov = table["provenance"]
    return ("# Real photo sets: polarref sfm vs pycolmap with its defaults\n\n"
            f"Generated by `scripts/eval_photo_sets.py` from `photo_sets.json` (commit {prov.get('git_commit', '?')[:10]}"
            f"{', dirty' if prov.get('git_dirty') else ''}). Largest model of each; tie points = 3D points; "
            "reprojection error = mean over all observations (one rule for both); rotation error = mean "
            "after a similarity alignment of the centres to the ground truth, and after the best rotation "
            "alone (fountain only). Sources and licences: "
            "docs/photo-sets.md.\n\n" + "\n".join(rows) + "\n")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", type=Path, required=True, help="scratch folder (models, databases, log)")
    p.add_argument("--out", type=Path, required=True, help="folder for photo_sets.json and photo_sets.md")
    p.add_argument("--max-image-size", type=int, default=1600)
    p.add_argument("--reuse-pycolmap", action="store_true",
                   help="take pycolmap's scores from an earlier run of the same call in --work")
    p.add_argument("sets", nargs="*", help=f"default: every set laid out ({', '.join(PS.BY_NAME)})")
    args = p.parse_args(argv)
    table = {"provenance": collect(seeds={"pycolmap": SEED, "polarref_verification": 0, "polarref_registration": 0},
                                     threads={"pycolmap": 1, "polarref_omp": 1}), "sets": {}, "absent": []}
    args.work.mkdir(parents=True, exist_ok=True)
    with open(args.work / "eval.log", "a") as log:
        for s in PS.PHOTO_SETS:
            if args.sets and s.name not in args.sets:
                continue
            images = PS.image_dir(s.name)
            if images is None:
                table["absent"].append(s.name)
                continue
            g = PS.gt_dir(s.name)
            names = sorted(q.name for q in images.iterdir() if q.suffix.lower() in PS.IMAGE_SUFFIXES)
            gt = read_ground_truth(g, names) if g is not None else None
            size = MAX_IMAGE_SIZE.get(s.name, args.max_image_size)
            work = args.work / s.name
            o = _ours(s.name, images, work, size, gt, len(names), log)
            q = _pycolmap(s.name, images, work, size, gt, len(names), args.reuse_pycolmap)
            table["sets"][s.name] = {"source": s.repo or "reference data", "licence": s.licence,
                                     "max_image_size": size, "num_images": len(names),
                                     "ours": o, "pycolmap": q, "verdict": _verdict(o, q)}
            log.write(json.dumps(table["sets"][s.name], default=str) + "\n")
            log.flush()
            print(s.name, json.dumps(table["sets"][s.name]["verdict"]), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "photo_sets.json").write_text(json.dumps(table, indent=1, default=str) + "\n")
    (args.out / "photo_sets.md").write_text(_markdown(table))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
