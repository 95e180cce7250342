"""``polarref sfm``: the reference incremental SfM (MOCI pipeline) on a folder of images."""

from __future__ import annotations

import argparse
import dataclasses
import logging
from pathlib import Path

from polarref.commands._types import MAX_IMAGE_SIDE, SEED, camera_spec, int_range, refine_groups
from polarref.core.errors import PolarrefError, UsageError

NAME = "sfm"
HELP = "incremental SfM (SIFT, MOCI triangulation, PnP, bundle adjustment) -> COLMAP model + metrics"

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from polarref.sfm.bundle import BA_NAMES
    from polarref.sfm.pipeline import PRESETS

    parser.add_argument("dir", type=Path, help="scene folder holding images/ (and optionally gt/)")
    parser.add_argument("--out", type=Path, required=True, help="output folder (model/, metrics.json)")
    parser.add_argument("--ba", choices=BA_NAMES, default="euclidean",
                        help="bundle adjuster (colmap = pycolmap's Ceres, for reference)")
    parser.add_argument("--camera", metavar="MODEL:params", type=camera_spec,
                        help="known intrinsics in COLMAP order, e.g. PINHOLE:fx,fy,cx,cy (default: from gt/)")
    parser.add_argument("--refine", metavar="GROUPS", type=refine_groups,
                        help="intrinsics refined in global BA: focal,pp,dist or none (default: focal,dist "
                             "for EXIF cameras, none for --camera / gt/)")
    cams = parser.add_mutually_exclusive_group()
    cams.add_argument("--single-camera", action="store_true",
                      help="EXIF cameras: one camera for all images (default: one per make, model, size)")
    cams.add_argument("--camera-per-image", action="store_true", help="EXIF cameras: one camera per image")
    parser.add_argument("--preset", choices=sorted(PRESETS), default="default", help="configuration preset")
    parser.add_argument("--max-features", type=int_range(8), help="SIFT keypoints per image (>= 8)")
    parser.add_argument("--max-image-size", type=_image_size,
                        help=f"detect on images downscaled to this size (32..{MAX_IMAGE_SIDE} px; 0 = full size)")
    parser.add_argument("--pairing", choices=("exhaustive", "sequential"), help="image pairs to match")
    parser.add_argument("--triangulation", choices=("moci", "dlt"), help="triangulation method")
    parser.add_argument("--track-conflicts", choices=("drop", "split"),
                        help="what to do with a track holding two keypoints of one image")
    parser.add_argument("--seed", type=SEED, help="RANSAC seed (0..2^32-1)")
    parser.add_argument("--no-cache", action="store_true", help="recompute features and matches")
    parser.add_argument("--format", dest="model_format", choices=("text", "binary", "both"), default="both",
                        help="COLMAP model format in OUT/model (default: both; binary only when an image name holds "
                             "a space, which COLMAP text cannot hold); points3D.ply is always written")
    parser.add_argument("--overwrite", action="store_true", help="write into a non-empty --out")
    parser.add_argument("--export-final-ba", type=Path, default=None, metavar="PATH.npz",
                        help="also write the mapper's last global BA (problem, options, result, GT poses) to this "
                             ".npz, a problem for `polarref ba` and `polarref bench ba --problem`")
    geo = parser.add_argument_group("georeferencing (README: Ground control and pose priors)")
    geo.add_argument("--priors", type=Path, metavar="CSV|scene",
                     help="pose priors name,x,y,z,sigma_x,sigma_y,sigma_z[,omega,phi,kappa,sigma_angle_deg]; "
                          "'scene': the priors in DIR/scene.json (a file named scene: ./scene)")
    geo.add_argument("--gcps", type=Path, metavar="CSV", help="ground points id,x,y,z,sigma_x,sigma_y,sigma_z,role")
    geo.add_argument("--gcp-observations", type=Path, metavar="CSV", help="marks id,image,u,v (COLMAP pixels)")
    geo.add_argument("--image-sigma", type=float, default=0.5, metavar="PX",
                     help="tie-point pixel sigma weighting the images against the priors (default 0.5)")
    geo.add_argument("--mark-sigma", type=float, default=0.5, metavar="PX",
                     help="GCP marking sigma (default 0.5)")


def _image_size(text: str) -> int:
    value = int_range(0, MAX_IMAGE_SIDE)(text)
    if 0 < value < 32:
        raise argparse.ArgumentTypeError(f"{value} px is too small to detect features; use 0 or >= 32")
    return value


def _config(args: argparse.Namespace):
    from polarref.sfm.pipeline import PRESETS, with_ba

    cfg = with_ba(PRESETS[args.preset], args.ba)
    rep = dataclasses.replace
    if args.max_features is not None:
        cfg = rep(cfg, features=rep(cfg.features, max_num_features=args.max_features))
    if args.max_image_size is not None:
        # a photo folder's feature budget then scales with it; 0 = full size, on purpose (sfm/budget.py)
        cfg = rep(cfg, features=rep(cfg.features, max_image_size=args.max_image_size),
                  full_size=args.max_image_size == 0)
    if args.pairing:
        cfg = rep(cfg, matching=rep(cfg.matching, pairing=args.pairing))
    if args.triangulation:
        cfg = rep(cfg, triangulation=rep(cfg.triangulation, method=args.triangulation))
    if args.track_conflicts:
        cfg = rep(cfg, track_conflicts=args.track_conflicts)
    if args.seed is not None:
        cfg = rep(cfg, verification=rep(cfg.verification, seed=args.seed),
                  mapper=rep(cfg.mapper, register=rep(cfg.mapper.register, seed=args.seed)))
    if args.no_cache:
        cfg = rep(cfg, use_cache=False)
    if args.refine is not None:
        cfg = rep(cfg, mapper=rep(cfg.mapper, refine=args.refine))
    if args.single_camera or args.camera_per_image:
        cfg = rep(cfg, camera_mode="single" if args.single_camera else "per-image")
    return cfg


def run(args: argparse.Namespace) -> int:
    from polarref.core.atomic import refuse_inside_inputs
    from polarref.io.scene_folder import discover
    from polarref.sfm import features as F
    from polarref.sfm.pipeline import parse_camera, run_sfm

    root: Path = args.dir
    refuse_inside_inputs(args.out, [root])
    found = discover(root)
    image_dir = found.image_dir
    gt = found.read_ground_truth()
    mesh = None
    if found.rendered and found.mesh_path is not None:
        from synth.scene import load_scene

        mesh = load_scene(root).mesh()
    camera = None
    if args.camera:
        paths = F.list_images(image_dir)
        first = next((img for img in map(F.read_image, paths) if img is not None), None)
        # With no readable image, run_sfm reports that (and writes metrics.json).
        if first is not None:
            camera = parse_camera(args.camera, first.shape[1], first.shape[0])
    _refuse_unfitting_size(args.max_image_size, F.list_images(image_dir))
    cfg = _config(args)
    georef = _read_georef(args, root, image_dir)
    model_format = _model_format(args, [p.name for p in F.list_images(image_dir)])
    res = run_sfm(image_dir, args.out, cfg, camera=camera, gt=gt, mesh=mesh, overwrite=args.overwrite,
                  model_format=model_format, priors=georef.priors if georef is not None else (),
                  image_sigma_px=args.image_sigma, export_final_ba=args.export_final_ba)
    r = res.report
    m = r.metrics
    if r.gt_skipped:
        raise PolarrefError(f"{root / ('gt' if found.gt_kind == 'colmap' else 'gt_dense_cameras')}: metrics vs "
                            f"ground truth skipped: {r.gt_skipped}; the model "
                            f"and metrics.json were written to {args.out}")
    line = (f"registered {m.registered_images}/{m.num_images} images, {m.tie_points} tie points, "
            f"{m.reprojected_px} observations, mean reprojection error {m.mean_reprojection_error_px:.3f} px")
    if m.gt is not None:
        line += (f"; vs GT: rotation error mean {m.gt.rotation_error_deg_mean:.3f} deg, "
                 f"centre error mean {m.gt.center_error_rel_mean:.2e} of scene size")
    print(line)
    for c in r.cameras or []:
        if r.refine:
            vals = ", ".join(f"{n}={v:.6g}" for n, v in zip(c.names, c.refined))
            gt_err = (f" (focal error {100 * c.focal_error_rel:.3f} % vs GT)"
                      if c.focal_error_rel is not None else "")
            print(f"camera {c.camera_id} ({c.source}, {c.num_images} images): refined "
                  f"{c.model} {vals}{gt_err}")
    print(f"wrote {args.out / 'model'} ({model_format} + points3D.ply) and {args.out / 'metrics.json'} "
          f"in {r.runtime_s['total']:.1f} s")
    if georef is not None:
        _georeference(args, res.reconstruction, georef, model_format)
    return 0


# OpenCV SIFT holds ~11 float32 scale images of the 2x-upsampled first octave, plus the smaller
# octaves (x 4/3): ~235 bytes per detection pixel. Measured: one 6000x4000 PNG among six 320x240
# ones, `polarref sfm --preset small`: 5.92 GB peak RSS at full size.
SIFT_BYTES_PER_PX = 235


def _refuse_unfitting_size(asked: int | None, paths: list[Path]) -> None:
    """An image size asked for (0 = full size) at which SIFT on the largest image does not fit in
    the memory available: refused with the size that fits. Without --max-image-size the size
    comes from sfm/budget.py's rule, which bounds it."""
    from polarref.sfm.budget import header_size

    if asked is None:
        return
    sizes = [(p, wh) for p, wh in ((p, header_size(p)) for p in paths) if wh is not None]
    if not sizes:
        return
    p, (w, h) = max(sizes, key=lambda item: item[1][0] * item[1][1])
    scale = min(1.0, asked / max(w, h)) if asked else 1.0
    need, avail = SIFT_BYTES_PER_PX * w * h * scale ** 2, _available_bytes()
    if avail is not None and need > 0.8 * avail:
        fits = int(scale * max(w, h) * (0.8 * avail / need) ** 0.5)
        at = f"at {asked} px" if asked else "at full size"
        raise PolarrefError(f"{p}: a {w}x{h} image needs about {need / 1e9:.1f} GB for SIFT {at}, more "
                            f"than the {avail / 1e9:.1f} GB of memory available; use --max-image-size {fits} "
                            "or less")


def _available_bytes() -> int | None:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _model_format(args: argparse.Namespace, names: list[str]) -> str:
    """The format written: COLMAP text cannot hold a name with whitespace (COLMAP reads it up to
    the first space), so such folders get the binary model only: refused before any work when
    text alone was asked for, with a warning under the default ``both``."""
    from polarref.model.colmap_text import names_text_cannot_hold

    bad = names_text_cannot_hold(names)
    if not bad or args.model_format == "binary":
        return args.model_format
    if args.model_format == "text":
        raise UsageError(f"{args.dir}: image name {bad[0]!r} holds whitespace, which COLMAP's text format "
                         "cannot hold (COLMAP reads only up to the first space); use --format binary "
                         "or rename the images")
    log.warning("%d image names hold whitespace (e.g. %r), which COLMAP's text format cannot hold: "
                "writing the binary model only", len(bad), bad[0])
    return "binary"


def _read_georef(args: argparse.Namespace, root: Path, image_dir: Path):
    """The priors / GCP files, checked against the folder's images before any work.

    ``--priors scene`` is explicit rather than automatic for scenes with priors: an SfM of a twin
    without the flag keeps its output and timings, and the priors used are named on the command line."""
    if args.priors is None and args.gcps is None and args.gcp_observations is None:
        return None
    if not (args.image_sigma > 0 and args.mark_sigma > 0):
        raise PolarrefError("--image-sigma and --mark-sigma must be > 0")
    if args.ba == "colmap":
        raise PolarrefError("georeferencing needs one of our BA forms (--ba euclidean|parallax|polar|angular)")
    if args.refine:
        raise PolarrefError("georeferencing needs fixed intrinsics: --refine none (or leave it out for "
                            "given / GT cameras)")
    from polarref.georef.formats import load_georef
    from polarref.georef.scene_priors import SCENE_KEYWORD, read_scene_priors
    from polarref.sfm import features as F

    names = [p.name for p in F.list_images(image_dir)]
    if args.priors is not None and str(args.priors) == SCENE_KEYWORD:
        return load_georef(names, None, args.gcps, args.gcp_observations,
                           extra_priors=read_scene_priors(root / "scene.json", names))
    return load_georef(names, args.priors, args.gcps, args.gcp_observations)


def _georeference(args: argparse.Namespace, rec, georef, model_format: str) -> None:
    """Georeferenced BA of the finished model: OUT/model-georef/ and OUT/aerotriangulation.json."""
    from polarref import metrics as M
    from polarref.georef.adjust import georeference
    from polarref.core.provenance import collect
    from polarref.sfm.model_files import write_model

    r = georeference(rec, georef, args.ba, image_sigma_px=args.image_sigma,
                     mark_sigma_px=args.mark_sigma)
    write_model(rec, args.out / "model-georef", model_format)
    M.write_json(args.out / "aerotriangulation.json",
                 {"record": dataclasses.asdict(r), "provenance": collect()})
    line = f"georeferenced ({r.num_priors} priors, {r.num_control} control points): sigma0 {r.sigma0:.3f}"
    if r.check is not None:
        line += (f"; {r.check.count} check points: RMSE horizontal {r.check.rmse_horizontal:.3f} m, "
                 f"Z {r.check.rmse_z:.3f} m")
    print(line)
