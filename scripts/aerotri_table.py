"""Aerotriangulation table (issue 33): check-point errors in metres per method, BA form and variant.

Usage: python scripts/aerotri_table.py SCENE_DIR OUT_DIR [--work DIR] [--control N] [--check N]
           [--seed K] [--priors layout|scene] [--mc DRAWS] [--no-pycolmap] [--overwrite]

SCENE_DIR is a rendered UAV scene. The work folder (default OUT_DIR/work) gets a linked copy of
it with the seeded GCP layout (synth.uav.gcp_layout). Pose priors: ``layout`` (independent,
2 m / 4 m, no attitude; gcp_layout) or ``scene`` (the twin's scene.json: AR(1) drift and attitude).
Per BA form: one SfM with the priors inside the mapper, then the final adjustment in three
variants (priors off: free BA, a similarity onto the prior centres; priors on; priors + control
points). pycolmap: its plain incremental mapper (priors off, same similarity), its pose-prior
mapper (priors on) and that model moved onto the control points by a similarity (it has no GCP
adjustment). OUT_DIR gets aerotriangulation.json (with provenance) and aerotriangulation.md,
generated from the JSON (polarref.georef.table).
"""

import argparse
import copy
import json
import sys
from pathlib import Path

import numpy as np

from polarref.ba.parameterization import PARAMS
from polarref.core.atomic import atomic_write
from polarref.core.provenance import collect
from polarref.georef.adjust import align_to_datum, evaluate, georeference, triangulate_marks
from polarref.georef.formats import Georef, Role, load_georef
from polarref.core.geometry import so3_log
from polarref.georef.predict import PredictedRMSE, datum_error, predict_priors_only
from polarref.georef.scene_priors import priors_of_section, read_scene_priors, scene_prior_params
from polarref.georef.table import AerotriRow, AerotriTable, MonteCarlo, Variant
from polarref.model.colmap import from_pycolmap, read_model
from polarref.sfm.pipeline import PRESETS, run_sfm, with_ba
from synth.config import PriorParams, preset, twin
from synth.priors import draw_priors
from synth.uav import gcp_layout

VARIANTS = ((Variant.PRIORS_OFF, False, False), (Variant.PRIORS_ON, True, False), (Variant.PRIORS_GCPS, True, True))
LAYOUT_SIGMA = (2.0, 2.0, 4.0)
IMAGE_SIGMA_PX = 0.5


def _args():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--work", type=Path)
    ap.add_argument("--control", type=int, default=10)
    ap.add_argument("--check", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--mark-sigma", type=float, default=0.5)
    ap.add_argument("--priors", choices=("layout", "scene", "twin"), default="layout",
                    help="layout: independent 2 m / 4 m (gcp_layout); scene: scene.json's; twin: drawn here "
                         "as the UAV twins draw theirs (synth.priors, mappilot's parameters, seed --seed)")
    ap.add_argument("--mc", type=int, default=20, help="Monte Carlo redraws of the prior noise (0: none)")
    ap.add_argument("--no-pycolmap", action="store_true")
    ap.add_argument("--overwrite", action="store_true")
    return ap.parse_args()


def _link_scene(scene: Path, work: Path) -> None:
    work.mkdir(parents=True, exist_ok=True)
    for name in ("images", "gt", "depth", "mesh.ply", "scene.json"):
        if not (work / name).exists():
            (work / name).symlink_to((scene / name).resolve())


def _prior_params(kind: str, work: Path) -> PriorParams:
    if kind == "twin":
        return twin("mappilot").priors
    if kind == "scene":
        p = scene_prior_params(work / "scene.json")
        return PriorParams(position_sigma_m=p.position_sigma_m, vertical_sigma_m=p.vertical_sigma_m,
                           rotation_sigma_deg=p.rotation_sigma_deg, correlation=p.correlation)
    return PriorParams(position_sigma_m=LAYOUT_SIGMA[0], vertical_sigma_m=LAYOUT_SIGMA[2], correlation=0.0)


def _predicted(gt_imgs, georef: Georef, pp: PriorParams) -> PredictedRMSE:
    C = np.array([im.cam_from_world.center for im in gt_imgs])
    sig = np.tile([pp.position_sigma_m, pp.position_sigma_m, pp.vertical_sigma_m], (len(C), 1))
    G = np.array([p.xyz for p in georef.of_role(Role.CHECK)])
    R = np.array([im.cam_from_world.R for im in gt_imgs]) if pp.rotation_sigma_deg > 0 else None
    return predict_priors_only(C, sig, G, pp.correlation, R, np.radians(pp.rotation_sigma_deg))


def _monte_carlo(rec, gt_imgs, georef: Georef, pp: PriorParams, form: str, draws: int, seed: int) -> MonteCarlo:
    """Priors-only check errors pooled over ``draws`` fresh prior draws (synth.priors.draw_priors)."""
    names = [im.name for im in gt_imgs]
    poses = [im.cam_from_world for im in gt_imgs]
    C = np.array([p.center for p in poses])
    Rt = np.array([p.R for p in poses])
    checks = georef.of_role(Role.CHECK)
    G = np.array([p.xyz for p in checks])
    sq, lin = [], []
    for k in range(draws):
        cfg = preset("uav", "small", priors=pp, seed=seed + k)
        pri = priors_of_section(draw_priors(cfg, poses, np.zeros(3))["views"], names, names, "monte carlo")
        g = Georef(pri, georef.points, georef.marks)
        r = copy.deepcopy(rec)
        georeference(r, g, form, use_priors=True, use_control=False)
        est = triangulate_marks(r, georef.marks, [p.id for p in checks])
        sq += [(est[p.id] - p.xyz) ** 2 for p in checks if p.id in est]
        att = pp.rotation_sigma_deg > 0
        d_rot = np.array([so3_log(p.R @ R.T) for p, R in zip(pri, Rt)]) if att else None
        lin.append(datum_error(C, np.array([p.sigma for p in pri]), G, np.array([p.centre for p in pri]) - C,
                               Rt if att else None, np.radians(pp.rotation_sigma_deg), d_rot) ** 2)
    return MonteCarlo(draws, seed, form, _rmse(np.array(sq)), _rmse(np.concatenate(lin)))


def _rmse(sq: np.ndarray) -> PredictedRMSE:
    rx, ry, rz = np.sqrt(sq.mean(0))
    return PredictedRMSE(float(rx), float(ry), float(rz), float(np.hypot(rx, ry)))


def _ours(work: Path, gt, georef: Georef, mark_sigma: float):
    rows, registered, notes, models = [], [], [], {}
    for form in PARAMS:
        res = run_sfm(work / "images", None, with_ba(PRESETS["default"], form), gt=gt, priors=georef.priors,
                      image_sigma_px=IMAGE_SIGMA_PX)
        registered.append((f"polarref {form}", len(res.reconstruction.images)))
        models[form] = res.reconstruction
        for variant, use_p, use_c in VARIANTS:
            rec = copy.deepcopy(res.reconstruction)
            r = georeference(rec, georef, form, use_priors=use_p, use_control=use_c, mark_sigma_px=mark_sigma,
                             image_sigma_px=IMAGE_SIGMA_PX)
            rows.append(AerotriRow("polarref", variant, r))
            if variant == Variant.PRIORS_ON:
                moved = max(float(np.linalg.norm(rec.images[i].cam_from_world.center
                                                 - res.reconstruction.images[i].cam_from_world.center))
                            for i in rec.images)
                notes.append(f"polarref {form}: the mapper's model is in the priors' frame; the final "
                             f"priors-only adjustment (after a similarity) moved its centres by at most {moved:.2e} m")
            print(form, variant, r.check, flush=True)
    return rows, registered, notes, models


def _pycolmap(work: Path, gt, georef: Georef, mark_sigma: float):
    from polarref.peers.colmap_priors import run_prior_mapper, similarity_to_control
    from polarref.peers.colmap_sfm import extract_and_match_sift, run_mapper

    cam = next(iter(gt.cameras.values()))
    db = work / "pycolmap" / "database.db"
    extract_and_match_sift(work / "images", cam, db, overwrite=True)
    ev = dict(image_sigma_px=IMAGE_SIGMA_PX, mark_sigma_px=mark_sigma)
    plain = run_mapper(db, work / "images", work / "pycolmap" / "plain")
    pri = run_prior_mapper(db, work / "images", work / "pycolmap" / "priors", georef.priors)
    rows, registered = [], []
    if plain.reconstruction is not None:
        rec = from_pycolmap(plain.reconstruction)
        registered.append(("pycolmap incremental", len(rec.images)))
        align_to_datum(rec, georef, True, False)
        rows.append(AerotriRow("pycolmap", Variant.PRIORS_OFF, evaluate(
            rec, georef, "colmap", use_priors=False, gauge="pycolmap incremental mapper; similarity onto "
            "the prior centres", **ev)))
    if pri.reconstruction is not None:
        rec = from_pycolmap(pri.reconstruction)
        registered.append(("pycolmap pose-prior", len(rec.images)))
        rows.append(AerotriRow("pycolmap", Variant.PRIORS_ON, evaluate(
            rec, georef, "colmap", use_priors=True, gauge="pycolmap use_prior_position (as mapped)", **ev)))
        n = similarity_to_control(rec, georef)
        r = evaluate(rec, georef, "colmap", use_priors=True, gauge=f"similarity onto {n} control points", **ev)
        rows.append(AerotriRow("pycolmap", Variant.GCP_SIMILARITY, r))
    return rows, registered


def main() -> int:
    a = _args()
    for name in ("aerotriangulation.json", "aerotriangulation.md"):
        if (a.out / name).exists() and not a.overwrite:
            print(f"aerotri_table: {a.out / name} exists (pass --overwrite)", file=sys.stderr)
            return 1
    # the environment of the code that runs: collected before any work (a commit made while
    # this runs must not be recorded as its source)
    prov = collect(seeds={"gcp_layout": a.seed, "monte_carlo": 1000 + a.seed, "pycolmap": 0},
                   threads={"pycolmap": 1})
    work = a.work or a.out / "work"
    _link_scene(a.scene, work)
    gcps, marks, layout_priors = gcp_layout(work, a.control, a.check, a.mark_sigma, a.seed)
    gt = read_model(work / "gt")
    gt_imgs = sorted(gt.images.values(), key=lambda im: im.name)
    names = [im.name for im in gt_imgs]
    pp = _prior_params(a.priors, work)
    extra = ()
    if a.priors == "scene":
        extra = read_scene_priors(work / "scene.json", names)
    elif a.priors == "twin":
        cfg = preset("uav", "small", priors=pp, seed=a.seed)
        extra = priors_of_section(draw_priors(cfg, [im.cam_from_world for im in gt_imgs], np.zeros(3))["views"],
                                  names, names, "twin priors")
    georef = load_georef(names, layout_priors if a.priors == "layout" else None, gcps, marks, extra_priors=extra)
    rows, registered, notes, models = _ours(work, gt, georef, a.mark_sigma)
    mc = _monte_carlo(models[PARAMS[0]], gt_imgs, georef, pp, PARAMS[0], a.mc, 1000 + a.seed) if a.mc else None
    if not a.no_pycolmap:
        prow, preg = _pycolmap(work, gt, georef, a.mark_sigma)
        rows, registered = rows + prow, registered + preg
        notes.append("pycolmap takes position priors only (no attitude), in its global BA after a RANSAC "
                     "similarity; it has no GCP adjustment: its 'priors + GCP similarity' row is its "
                     "pose-prior model moved onto the control points by a 7-parameter similarity")
    notes.append("priors off: free adjustment, then the least-squares similarity onto the prior centres")
    cam = gt.cameras[gt_imgs[0].camera_id]
    G = np.array([p.xyz for p in georef.of_role(Role.CHECK)])
    alt = float(np.mean([im.cam_from_world.center[2] for im in gt_imgs]) - G[:, 2].mean())
    table = AerotriTable(
        str(a.scene.resolve().name), len(names), tuple(registered), alt / float(cam.params[0]), a.priors,
        (pp.position_sigma_m, pp.position_sigma_m, pp.vertical_sigma_m), pp.correlation,
        pp.rotation_sigma_deg or None, a.mark_sigma, IMAGE_SIGMA_PX, a.seed, _predicted(gt_imgs, georef, pp),
        mc, tuple(rows), tuple(notes), prov)
    a.out.mkdir(parents=True, exist_ok=True)
    atomic_write(a.out / "aerotriangulation.json", json.dumps(table.to_json(), indent=2) + "\n")
    atomic_write(a.out / "aerotriangulation.md", table.markdown())
    print(table.markdown())
    return 0


if __name__ == "__main__":
    sys.exit(main())
