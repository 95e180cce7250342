"""Focal-length bias of self-calibrating BA per form and pixel noise, before and after issue 32's
fix (the angular/polar whitening follows the refined intrinsics).

Usage: python scripts/angular_focal_bias.py OUT_STEM --base COMMIT [--work DIR] [--seeds 1,2,3]
       [--noise 0.25,0.5,1] [--no-comet]

Runs every measurement twice, in a child process each: once on this checkout ("after") and once
on ``git archive COMMIT`` unpacked under the work folder ("before"; the same script, the old
library on PYTHONPATH). Measurements:

* bias: ``synthetic_reconstruction(12, 300, seed, noise_px)``, every focal length started 5 %
  long, ``adjust(refine="focal")`` four times in a row (held whitening made repeated solves a
  fixed point, not a minimum); refined focal / truth - 1 after each solve, per form.
* fixed: the same scene (seed 3, 1 px) with the intrinsics held, per form: a SHA-256 of the
  solved poses and points and the final cost, so before and after can be compared bit for bit.
* comet: the slow test ``tests/sfm/test_sfm_collections.py::test_unknown_focal_every_form``'s
  scenario (its own helpers): 12 EXIF-less rendered views whose focal length is 30 % below the
  default guess, ``polarref sfm`` per form; registered views and refined focal / truth.

Each child's rows are kept in the work folder and reused on a rerun (delete them to remeasure).
OUT_STEM.json gets the rows with the provenance of this process (the "after" checkout, which
must be a clean commit for a committed table) and the base commit; OUT_STEM.md is generated
from the JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FORMS = ("euclidean", "parallax", "polar", "angular")
START = 1.05  # every focal length starts 5 % long
SOLVES = 4
THREADS = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
           "NUMBA_NUM_THREADS": "1"}


@dataclass(frozen=True)
class BiasRow:
    form: str
    noise_px: float
    seed: int
    focal_error_pct: tuple[float, ...]  # refined / truth - 1, in %, after each solve


@dataclass(frozen=True)
class FixedRow:
    form: str
    final_cost: float
    solution_sha256: str  # of the solved rotations, translations and points, in id order


@dataclass(frozen=True)
class CometRow:
    form: str
    registered: int
    of: int
    refined_over_truth: float


@dataclass(frozen=True)
class Measured:
    library: str  # the polarref package the child imported
    bias: tuple[BiasRow, ...]
    fixed: tuple[FixedRow, ...]
    comet: tuple[CometRow, ...]


# ---- the child: measure with whatever polarref is on the path --------------------------------

def _started_long(init):
    from polarref.camera import Camera

    for cid, c in init.cameras.items():
        init.cameras[cid] = Camera(c.model, c.width, c.height, [START * c.fx, *c.params[1:]])
    return init


def _bias(form: str, noise: float, seed: int) -> BiasRow:
    from polarref.ba import BAOptions, adjust
    from polarref.ba.synthetic import synthetic_reconstruction

    init, truth = synthetic_reconstruction(12, 300, seed=seed, noise_px=noise, rot_deg=0.5)
    rec = _started_long(init)
    f_true = truth.cameras[1].fx
    errs = []
    for _ in range(SOLVES):
        adjust(rec, BAOptions(param=form, refine="focal"))
        errs.append(100.0 * (rec.cameras[1].fx / f_true - 1.0))
    return BiasRow(form, noise, seed, tuple(errs))


def _fixed(form: str) -> FixedRow:
    import numpy as np

    from polarref.ba import BAOptions, adjust
    from polarref.ba.synthetic import synthetic_reconstruction

    rec, _ = synthetic_reconstruction(12, 300, seed=3, noise_px=1.0, rot_deg=0.5)
    s = adjust(rec, BAOptions(param=form))
    h = hashlib.sha256()
    for i in sorted(rec.images):
        pose = rec.images[i].cam_from_world
        h.update(np.ascontiguousarray(pose.R).tobytes() + np.ascontiguousarray(pose.t).tobytes())
    for p in sorted(rec.points3D):
        h.update(np.ascontiguousarray(rec.points3D[p].xyz).tobytes())
    return FixedRow(form, float(s.final_cost), h.hexdigest())


def _comet(form: str, tree: Path) -> CometRow:
    sys.path[:0] = [str(tree / "tests"), str(tree / "tests" / "sfm")]
    from conftest import _cached_scene
    from test_sfm_collections import _unknown_focal

    from polarref.model.colmap import read_model

    src = _cached_scene("comet", "small")
    with tempfile.TemporaryDirectory() as tmp:
        res, f_true, cam = _unknown_focal((src, read_model(src / "gt")), Path(tmp), form, 12)
    return CometRow(form, int(res.report.metrics.registered_images), 12, cam.refined[0] / f_true)


def measure(tree: Path, seeds, noises, comet: bool) -> Measured:
    import polarref

    bias = tuple(_bias(f, n, s) for n in noises for s in seeds for f in FORMS)
    fixed = tuple(_fixed(f) for f in FORMS)
    rows = tuple(_comet(f, tree) for f in FORMS) if comet else ()
    return Measured(polarref.__file__, bias, fixed, rows)


def _load_measured(path: Path) -> Measured:
    d = json.loads(path.read_text())
    return Measured(d["library"], tuple(BiasRow(**{**r, "focal_error_pct": tuple(r["focal_error_pct"])})
                                        for r in d["bias"]),
                    tuple(FixedRow(**r) for r in d["fixed"]), tuple(CometRow(**r) for r in d["comet"]))


# ---- the parent: two trees, one table ---------------------------------------------------------

def _tree_of(base: str, work: Path) -> Path:
    tree = work / f"src-{base[:12]}"
    if not tree.exists():
        tree.mkdir(parents=True)
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", base], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    return tree


def _run_child(label: str, tree: Path, work: Path, args) -> Measured:
    out = work / f"{label}.json"
    if not out.exists():
        env = {**os.environ, **THREADS, "PYTHONPATH": str(tree)}
        cmd = [sys.executable, str(Path(__file__).resolve()), str(out), "--measure", str(tree),
               "--seeds", args.seeds, "--noise", args.noise] + (["--no-comet"] if args.no_comet else [])
        subprocess.run(cmd, check=True, env=env, cwd=str(tree))
    measured = _load_measured(out)
    if not Path(measured.library).resolve().is_relative_to(tree.resolve()):
        raise RuntimeError(f"{label}: the child imported {measured.library}, not {tree}")
    return measured


def _mean(values) -> float:
    values = list(values)
    return sum(values) / len(values)


def _markdown(record: dict) -> str:
    lines = ["# Focal-length bias of self-calibrating BA (issue 32)", "",
             f"Generated by scripts/angular_focal_bias.py from angular-focal-bias.json (after: "
             f"{record['environment']['git_commit'][:12]}, dirty={record['environment']['git_dirty']}; "
             f"before: {record['base_commit'][:12]}). Synthetic scene: 12 cameras, 300 points, every "
             f"focal length started {round(100 * (START - 1))} % long, refine=focal, seeds "
             f"{record['seeds']}; focal error = refined / truth - 1 after the last of {SOLVES} "
             "solves, mean over the seeds; 'vs euclidean' = the same minus the Euclidean form's on "
             "the same data (its error is this draw's noise).", "",
             "| noise px | form | before % | after % | before vs euclidean % | after vs euclidean % |",
             "|---:|---|---:|---:|---:|---:|"]
    for noise in record["noise_px"]:
        for form in FORMS:
            cells = []
            for key in ("before", "after"):
                cells.append(record["summary"][key][str(noise)][form])
            lines.append(f"| {noise} | {form} | {cells[0]['mean_pct']:+.4f} | {cells[1]['mean_pct']:+.4f} | "
                         f"{cells[0]['vs_euclidean_pct']:+.4f} | {cells[1]['vs_euclidean_pct']:+.4f} |")
    lines += ["", "Fixed intrinsics (seed 3, 1 px), before and after: "
              + ", ".join(f"{f}: {'identical' if ok else 'DIFFERENT'}"
                          for f, ok in record["fixed_identical"].items()), ""]
    if record["comet"]["after"]:
        lines += ["Rendered comet scene, no EXIF, focal 30 % below the default guess "
                  "(test_unknown_focal_every_form):", "",
                  "| form | before registered | before focal / truth | after registered | after focal / truth |",
                  "|---|---:|---:|---:|---:|"]
        for b, a in zip(record["comet"]["before"], record["comet"]["after"]):
            lines.append(f"| {a['form']} | {b['registered']}/{b['of']} | {b['refined_over_truth']:.5f} | "
                         f"{a['registered']}/{a['of']} | {a['refined_over_truth']:.5f} |")
    return "\n".join(lines) + "\n"


def _summary(m: Measured, noises) -> dict:
    out = {}
    for noise in noises:
        rows = [r for r in m.bias if r.noise_px == noise]
        ref = {r.seed: r.focal_error_pct[-1] for r in rows if r.form == "euclidean"}
        out[str(noise)] = {f: {"mean_pct": _mean(r.focal_error_pct[-1] for r in rows if r.form == f),
                               "vs_euclidean_pct": _mean(r.focal_error_pct[-1] - ref[r.seed]
                                                         for r in rows if r.form == f)}
                           for f in FORMS}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", type=Path, help="OUT_STEM (.json and .md are added)")
    ap.add_argument("--base", help="the commit before the fix")
    ap.add_argument("--work", type=Path, default=Path("/work/scratch/i32/bias"))
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--noise", default="0.25,0.5,1.0")
    ap.add_argument("--no-comet", action="store_true")
    ap.add_argument("--measure", type=Path, help=argparse.SUPPRESS)  # child mode: the tree
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    noises = [float(n) for n in args.noise.split(",")]
    if args.measure:
        args.out.write_text(json.dumps(dataclasses.asdict(measure(args.measure, seeds, noises,
                                                                  not args.no_comet))))
        return
    from polarref.core.provenance import collect

    args.work.mkdir(parents=True, exist_ok=True)
    base = subprocess.run(["git", "-C", str(ROOT), "rev-parse", args.base], check=True,
                          capture_output=True, text=True).stdout.strip()
    env = collect(seeds={f"synthetic_{s}": s for s in seeds} | {"comet_render": 0},
                  threads={k: int(v) for k, v in THREADS.items()})
    before = _run_child("before", _tree_of(base, args.work), args.work, args)
    after = _run_child(f"after-{env['git_commit'][:12]}", ROOT, args.work, args)
    record = {"environment": env, "base_commit": base, "seeds": seeds, "noise_px": noises,
              "start_focal_factor": START, "solves": SOLVES,
              "summary": {"before": _summary(before, noises), "after": _summary(after, noises)},
              "fixed_identical": {b.form: b == a for b, a in zip(before.fixed, after.fixed)},
              "comet": {"before": [dataclasses.asdict(r) for r in before.comet],
                        "after": [dataclasses.asdict(r) for r in after.comet]},
              "before": dataclasses.asdict(before), "after": dataclasses.asdict(after)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(record, indent=1) + "\n")
    args.out.with_suffix(".md").write_text(_markdown(record))
    print(_markdown(record))


if __name__ == "__main__":
    main()
