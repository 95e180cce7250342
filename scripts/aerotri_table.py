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
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from polarref.ba.parameterization import PARAMS
from polarref.core.provenance import collect_record
from polarref.georef.adjust import align_to_datum, evaluate, georeference, place_by_priors, triangulate_marks
from polarref.georef.formats import Georef, Role, load_georef
from polarref.core.geometry import so3_log
from polarref.georef.predict import PredictedRMSE, datum_error, predict_priors_only
from polarref.georef.scene_priors import (pose_priors, prior_sequence, read_scene_priors, scene_prior_params,
                                          views_from_json)
from polarref.georef.table import AerotriRow, AerotriTable, MonteCarlo, Variant
from polarref.model.colmap import from_pycolmap, read_model
from polarref.sfm.pairing import PairingConfig, priors_from_scene, select, write_pairs
from polarref.sfm.pipeline import PRESETS, run_sfm, with_ba
from synth.config import PriorParams, preset, twin
from synth.priors import draw_priors
from synth.comet_landmarks import landmark_layout
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
    ap.add_argument("--tie-points", choices=("each", *PARAMS, "pycolmap"), default="each",
                    help="each: one SfM per BA form; FORM: one SfM (that form, priors inside) gives the tie "
                         "points that every form then adjusts (aerotriangulation on fixed tie points); "
                         "pycolmap: its plain incremental model (no priors, held intrinsics) gives them")
    ap.add_argument("--pairs", choices=("exhaustive", "priors"), default="exhaustive",
                    help="priors: the pairs polarref.sfm.pairing chooses from scene.json's priors, the same "
                         "for our SfM and pycolmap's")
    ap.add_argument("--forms", nargs="*", choices=PARAMS, default=list(PARAMS),
                    help="the BA forms of our rows (default: all; none: the peer's rows only); parts run side "
                         "by side are joined by scripts/aerotri_merge.py")
    ap.add_argument("--no-pycolmap", action="store_true")
    ap.add_argument("--pycolmap-threads", type=int, default=1, choices=(1, 2),
                    help="pycolmap's threads in every stage (1: the reference runs; its results are then "
                         "reproducible; 2: the machine's cores)")
    ap.add_argument("--overwrite", action="store_true")
    return ap.parse_args()


def _scene_label(scene: Path, work: Path) -> str:
    """The folder's name, or for a twin's sub-block (synth.subblock) what part of which twin it is."""
    block = json.loads((work / "scene.json").read_text()).get("subblock")
    if not block:
        return str(scene.resolve().name)
    return (f"{block['twin']} twin, sub-block of {len(block['twin_indices'])} of its {block['twin_views']} views "
            f"(flight lines {block['lines'][0]}-{block['lines'][1] - 1} x along-track positions "
            f"{block['positions'][0]}-{block['positions'][1] - 1}; the twin's mesh, camera, GT poses and priors)")


def _link_scene(scene: Path, work: Path) -> None:
    work.mkdir(parents=True, exist_ok=True)
    for name in ("images", "gt", "depth", "mesh.ply", "scene.json"):
        if not (work / name).exists():
            (work / name).symlink_to((scene / name).resolve())


def _scene_meta(work: Path) -> dict:
    return json.loads((work / "scene.json").read_text())


def _prior_params(kind: str, work: Path) -> PriorParams:
    if kind == "twin":
        scene = _scene_meta(work)["config"]["scene"]
        # only the twin's prior parameters are read: a placeholder mesh spares looking up the 67P model
        return (twin("rosetta", mesh="-") if scene == "comet" else twin("mappilot")).priors
    if kind == "scene":
        p = scene_prior_params(work / "scene.json")
        return PriorParams(position_sigma_m=p.position_sigma_m, position_sigma_rel=p.position_sigma_rel,
                           vertical_sigma_m=p.vertical_sigma_m, rotation_sigma_deg=p.rotation_sigma_deg,
                           correlation=p.correlation)
    return PriorParams(position_sigma_m=LAYOUT_SIGMA[0], vertical_sigma_m=LAYOUT_SIGMA[2], correlation=0.0)


def _layout(kind: str, work: Path, a) -> tuple[Path, Path, Path | None]:
    """(points, marks, layout priors or None): ground control (UAV) or surface landmarks (comet)."""
    if kind == "comet":
        return (*landmark_layout(work, a.control, a.check, a.mark_sigma, a.seed), None)
    return gcp_layout(work, a.control, a.check, a.mark_sigma, a.seed)


def _gsd(gt, georef: Georef) -> float:
    """Mean depth of the check points in the GT images that mark them, over the focal length (m)."""
    by_name = {im.name: im for im in gt.images.values()}
    xyz = {p.id: p.xyz for p in georef.of_role(Role.CHECK)}
    depth, focal = [], []
    for m in georef.marks:
        if m.id in xyz:
            im = by_name[m.image]
            depth.append(float(im.cam_from_world.apply(xyz[m.id][None])[0, 2]))
            focal.append(float(gt.cameras[im.camera_id].params[0]))
    return float(np.mean(depth) / np.mean(focal))


def _pairs_file(work: Path) -> Path:
    """The prior-based pairs of the scene (spatial + sequential, polarref.sfm.pairing defaults)."""
    meta = json.loads((work / "scene.json").read_text())
    return write_pairs(work / "pairs.txt", select(priors_from_scene(meta), PairingConfig()))


def _predicted(gt_imgs, georef: Georef, pp: PriorParams, seq: np.ndarray) -> PredictedRMSE:
    C = np.array([im.cam_from_world.center for im in gt_imgs])
    stated = {p.name: p.sigma for p in georef.priors}
    sig = np.array([stated[im.name] for im in gt_imgs])
    G = np.array([p.xyz for p in georef.of_role(Role.CHECK)])
    R = np.array([im.cam_from_world.R for im in gt_imgs]) if pp.rotation_sigma_deg > 0 else None
    return predict_priors_only(C, sig, G, pp.correlation, R, np.radians(pp.rotation_sigma_deg), seq)


def _flight_poses(poses: list, seq: np.ndarray) -> list:
    """``poses`` at their flight indices ``seq`` in a flight of max(seq) + 1 views, so that
    draw_priors' AR(1) drift runs along the whole flight as the twin's did. The views between
    are filled with the first pose: the noise of the views that are there does not depend on them."""
    flight = [poses[0]] * (int(seq.max()) + 1)
    for p, k in zip(poses, seq):
        flight[int(k)] = p
    return flight


def _monte_carlo(rec, gt_imgs, georef: Georef, pp: PriorParams, form: str, draws: int, seed: int,
                 seq: np.ndarray, scene: str, centre: np.ndarray) -> MonteCarlo:
    """Priors-only check errors pooled over ``draws`` fresh prior draws (synth.priors.draw_priors)."""
    names = [im.name for im in gt_imgs]
    poses = [im.cam_from_world for im in gt_imgs]
    flight = _flight_poses(poses, seq)
    C = np.array([p.center for p in poses])
    Rt = np.array([p.R for p in poses])
    checks = georef.of_role(Role.CHECK)
    G = np.array([p.xyz for p in checks])
    sq, lin, per = [], [], []
    for k in range(draws):
        cfg = preset(scene, "small", priors=pp, seed=seed + k)
        drawn = views_from_json(draw_priors(cfg, flight, centre)["views"])
        pri = pose_priors(tuple(drawn[int(k)] for k in seq), names, names, "monte carlo")
        g = Georef(pri, georef.points, georef.marks)
        r = copy.deepcopy(rec)
        georeference(r, g, form, use_priors=True, use_control=False)
        found, X = triangulate_marks(r, georef.marks, [p.id for p in checks]).matched(checks)
        err = (X - np.array([p.xyz for p in found]).reshape(-1, 3)) ** 2
        sq += list(err)
        per.append(_rmse(err))
        lin.append(_linear_error(pri, C, Rt, G, pp) ** 2)
    return MonteCarlo(draws, seed, form, _rmse(np.array(sq)), _rmse(np.concatenate(lin)), tuple(per))


def _realised(gt_imgs, georef: Georef, pp: PriorParams) -> PredictedRMSE:
    """The linear datum model fed this scene's own prior errors: what the drawn noise predicts
    for this one draw (``_predicted`` is its expectation over draws)."""
    by_name = {p.name: p for p in georef.priors}
    pri = [by_name[im.name] for im in gt_imgs]
    poses = [im.cam_from_world for im in gt_imgs]
    C, Rt = np.array([q.center for q in poses]), np.array([q.R for q in poses])
    G = np.array([p.xyz for p in georef.of_role(Role.CHECK)])
    return _rmse(_linear_error(pri, C, Rt, G, pp) ** 2)


def _linear_error(pri, C: np.ndarray, Rt: np.ndarray, G: np.ndarray, pp: PriorParams) -> np.ndarray:
    """(G, 3) check-point error of the linear datum model for the prior errors of ``pri``
    (true centres C, rotations Rt); attitude rows where the priors carry one."""
    att = pp.rotation_sigma_deg > 0 and all(p.R is not None for p in pri)
    d_rot = np.array([so3_log(p.R @ R.T) for p, R in zip(pri, Rt)]) if att else None
    return datum_error(C, np.array([p.sigma for p in pri]), G, np.array([p.centre for p in pri]) - C,
                       Rt if att else None, np.radians(pp.rotation_sigma_deg), d_rot)


def _rmse(sq: np.ndarray) -> PredictedRMSE:
    rx, ry, rz = np.sqrt(sq.mean(0))
    return PredictedRMSE(float(rx), float(ry), float(rz), float(np.hypot(rx, ry)))


def _sfm(work: Path, gt, georef: Georef, form: str, pairs: Path | None):
    """Our SfM with the priors inside, in ``form``; kept in ``work/sfm-FORM`` and read back from
    there by a later run (a long job resumes after its finished stages)."""
    out = work / f"sfm-{form}"
    if (out / "model").is_dir():
        print(f"reusing {out / 'model'}", flush=True)
        return read_model(out / "model")
    config = with_ba(PRESETS["default"], form)
    if pairs is not None:
        config = dataclasses.replace(config, matching=dataclasses.replace(config.matching, pairing="file",
                                                                          pairs_file=str(pairs)))
    return run_sfm(work / "images", out, config, gt=gt, priors=georef.priors, image_sigma_px=IMAGE_SIGMA_PX,
                   overwrite=True).reconstruction


def _peer_model(folder: Path, mapper):
    """A pycolmap model as our Reconstruction, kept in ``folder/model`` for a later run; None when
    the mapper registered nothing."""
    if (folder / "model").is_dir():
        return read_model(folder / "model")
    run = mapper()
    if run.reconstruction is None:
        return None
    rec = from_pycolmap(run.reconstruction)
    rec.write_text(folder / "model")
    return rec


def _ours(work: Path, gt, georef: Georef, mark_sigma: float, tie_points: str, pairs: Path | None, forms):
    """Per BA form, the three variants of the final adjustment: on that form's own SfM
    (``tie_points`` "each") or on the one SfM of form ``tie_points``."""
    rows, registered, notes, models = [], [], [], {}
    if tie_points == "pycolmap":
        shared = _pycolmap_plain(work, gt, pairs)
        registered.append(("pycolmap incremental (its tie points adjusted by every polarref form)",
                           len(shared.images)))
    else:
        shared = None if tie_points == "each" else _sfm(work, gt, georef, tie_points, pairs)
        if shared is not None:
            registered.append((f"polarref ({tie_points} SfM: the tie points of every form)", len(shared.images)))
    for form in forms:
        model = shared if shared is not None else _sfm(work, gt, georef, form, pairs)
        if shared is None:
            registered.append((f"polarref {form}", len(model.images)))
        models[form] = model
        for variant, use_p, use_c in VARIANTS:
            rec = copy.deepcopy(model)
            r = georeference(rec, georef, form, use_priors=use_p, use_control=use_c, mark_sigma_px=mark_sigma,
                             image_sigma_px=IMAGE_SIGMA_PX)
            rows.append(AerotriRow("polarref", variant, r))
            if variant == Variant.PRIORS_ON:
                src = ("the mapper's model (in the priors' frame)" if shared is None
                       else f"the {tie_points} mapper's model (in the priors' frame)")
                if tie_points == "pycolmap":
                    src = "pycolmap's plain model (free frame)"
                notes.append(f"polarref {form}: {src}, placed by the similarity that fits the priors as the BA "
                             f"weights them (georef/datum.py); the final priors-only adjustment in {form} then "
                             f"moved its centres by at most {_moved_from(model, rec, georef, True):.2e} m, "
                             f"{_moved_from(model, rec, georef, False):.2e} m from the centres' unweighted "
                             "similarity")
            print(form, variant, r.check, flush=True)
    return rows, registered, notes, models


def _moved_from(model, adjusted, georef: Georef, weighted: bool) -> float:
    """Largest centre distance between ``adjusted`` and ``model`` placed on the priors by their
    weighted similarity (``weighted``) or by the centres' unweighted one."""
    placed = copy.deepcopy(model)
    if weighted:
        place_by_priors(placed, georef, True, False)
    else:
        align_to_datum(placed, georef, True, True)
    return max(float(np.linalg.norm(adjusted.images[i].cam_from_world.center
                                    - placed.images[i].cam_from_world.center)) for i in adjusted.images)


def _pycolmap_db(work: Path, gt, pairs: Path | None, opts) -> Path:
    from polarref.peers.colmap_sfm import extract_and_match_sift

    cam = next(iter(gt.cameras.values()))
    db = work / "pycolmap" / "database.db"
    done = work / "pycolmap" / "matched"  # the database is complete (a run killed while matching leaves none)
    if not done.is_file():
        extract_and_match_sift(work / "images", cam, db, opts, overwrite=True, pairs_file=pairs)
        done.write_text("extraction and matching finished\n")
    return db


def _pycolmap_plain(work: Path, gt, pairs: Path | None, threads: int = 1):
    from polarref.peers.colmap_sfm import ColmapSfMOptions, run_mapper

    opts = ColmapSfMOptions(num_threads=threads)
    db = _pycolmap_db(work, gt, pairs, opts)
    return _peer_model(work / "pycolmap" / "plain",
                       lambda: run_mapper(db, work / "images", work / "pycolmap" / "plain", opts=opts))


def _pycolmap(work: Path, gt, georef: Georef, mark_sigma: float, pairs: Path | None, threads: int):
    from polarref.peers.colmap_priors import run_prior_mapper, similarity_to_control
    from polarref.peers.colmap_sfm import ColmapSfMOptions

    opts = ColmapSfMOptions(num_threads=threads)
    db = _pycolmap_db(work, gt, pairs, opts)
    ev = dict(image_sigma_px=IMAGE_SIGMA_PX, mark_sigma_px=mark_sigma)
    img = work / "images"
    plain = _pycolmap_plain(work, gt, pairs, threads)
    pri = _peer_model(work / "pycolmap" / "priors",
                      lambda: run_prior_mapper(db, img, work / "pycolmap" / "priors", georef.priors, opts))
    rows, registered = [], []
    if plain is not None:
        rec = plain
        registered.append(("pycolmap incremental", len(rec.images)))
        align_to_datum(rec, georef, True, False)
        rows.append(AerotriRow("pycolmap", Variant.PRIORS_OFF, evaluate(
            rec, georef, "colmap", use_priors=False, gauge="pycolmap incremental mapper; similarity onto "
            "the prior centres", **ev)))
    if pri is not None:
        rec = pri
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
    prov = collect_record(seeds={"gcp_layout": a.seed, "monte_carlo": 1000 + a.seed, "pycolmap": 0},
                          threads={"pycolmap": a.pycolmap_threads})
    work = a.work or a.out / "work"
    _link_scene(a.scene, work)
    meta = _scene_meta(work)
    kind, centre = meta["config"]["scene"], np.asarray(meta["scale"]["center"], float)
    if kind == "comet" and a.priors == "layout":
        print("aerotri_table: --priors layout is for UAV scenes (comet: scene or twin)", file=sys.stderr)
        return 2
    gcps, marks, layout_priors = _layout(kind, work, a)
    gt = read_model(work / "gt")
    gt_imgs = sorted(gt.images.values(), key=lambda im: im.name)
    names = [im.name for im in gt_imgs]
    pp = _prior_params(a.priors, work)
    extra = ()
    if a.priors == "scene":
        extra = read_scene_priors(work / "scene.json", names)
    elif a.priors == "twin":
        cfg = preset(kind, "small", priors=pp, seed=a.seed)
        extra = pose_priors(views_from_json(draw_priors(cfg, [im.cam_from_world for im in gt_imgs], centre)["views"]),
                            names, names, "twin priors")
    georef = load_georef(names, layout_priors if a.priors == "layout" else None, gcps, marks, extra_priors=extra)
    seq = prior_sequence(work / "scene.json", names) if a.priors == "scene" else np.arange(len(names))
    pairs = _pairs_file(work) if a.pairs == "priors" else None
    rows, registered, notes, models = _ours(work, gt, georef, a.mark_sigma, a.tie_points, pairs, a.forms)
    mc = (_monte_carlo(models[a.forms[0]], gt_imgs, georef, pp, a.forms[0], a.mc, 1000 + a.seed, seq, kind, centre)
          if a.mc and a.forms else None)
    if not a.no_pycolmap:
        prow, preg = _pycolmap(work, gt, georef, a.mark_sigma, pairs, a.pycolmap_threads)
        rows, registered = rows + prow, registered + preg
        notes.append("pycolmap takes position priors only (no attitude), in its global BA after a RANSAC "
                     "similarity; it has no GCP adjustment: its 'priors + GCP similarity' row is its "
                     "pose-prior model moved onto the control points by a 7-parameter similarity")
    notes.append("priors off: free adjustment, then the least-squares similarity onto the prior centres")
    notes.append("GSD: the mean depth of the check points in the GT views that mark them, over the focal length")
    if kind == "comet":
        notes.append("comet: X, Y, Z are the body frame's axes; 'horizontal' is the XY part, not a local "
                     "horizontal; control and check points are surface landmarks (synth/comet_landmarks.py)")
    table = AerotriTable(
        _scene_label(a.scene, work), len(names), tuple(registered), _gsd(gt, georef), a.priors,
        (pp.position_sigma_m, pp.position_sigma_m, pp.vertical_sigma_m or pp.position_sigma_m), pp.correlation,
        pp.rotation_sigma_deg or None, a.mark_sigma, IMAGE_SIGMA_PX, a.seed, _predicted(gt_imgs, georef, pp, seq),
        mc, tuple(rows), tuple(notes), prov, pp.position_sigma_rel, _realised(gt_imgs, georef, pp))
    table.write(a.out)
    print(table.markdown())
    return 0


if __name__ == "__main__":
    sys.exit(main())
