"""``polarref render``: synthetic comet/UAV scenes with exact ground truth (Mitsuba 3)."""

from __future__ import annotations

import argparse
import dataclasses

from polarref.commands._types import MAX_IMAGE_SIDE, SEED, float_range, int_range

MAX_VIEWS = 100_000
MAX_SPP = 65_536

NAME = "render"
HELP = "render a synthetic comet or UAV scene with exact ground-truth cameras, depth and mesh"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from synth.config import PRESETS, SCENES, TWINS

    parser.add_argument("scene", choices=SCENES, help="which synthetic scene")
    parser.add_argument("--out", required=True, help="output folder (created; resumable)")
    parser.add_argument("--preset", choices=(*PRESETS, *TWINS), default="default",
                        help="small: 12 views 320x240 (tests); default: 28 views 640x480; large: 300 views; "
                             "twins of the paper's datasets: rosetta (comet, 631 views 1024x1024), "
                             "poets-park (uav, 857), mappilot (uav, 493)")
    parser.add_argument("--views", type=int_range(2, MAX_VIEWS),
                        help=f"number of images, 2..{MAX_VIEWS} (overrides the preset)")
    parser.add_argument("--width", type=int_range(8, MAX_IMAGE_SIDE), help=f"image width in pixels (8..{MAX_IMAGE_SIDE})")
    parser.add_argument("--height", type=int_range(8, MAX_IMAGE_SIDE), help=f"image height in pixels (8..{MAX_IMAGE_SIDE})")
    parser.add_argument("--spp", type=int_range(1, MAX_SPP), help=f"samples per pixel (1..{MAX_SPP})")
    parser.add_argument("--fov", type=float_range(0.0, 169.9, lo_open=True),
                        help="horizontal field of view in degrees, (0, 170) (OSIRIS NAC: 2.2, WAC: 12)")
    parser.add_argument("--seed", type=SEED, default=0, help="seed of shape, texture, orbit and renderer (0..2^32-1)")
    parser.add_argument("--mesh", help="comet only: OBJ/PLY shape model in metres instead of the procedural body")
    parser.add_argument("--oblique", type=float_range(-89.0, 89.0), help="uav only: forward camera tilt from nadir, degrees")
    parser.add_argument("--distortion", metavar="K1[,K2]",
                        help="apply a known RADIAL lens distortion (k1, k2) to every view (synth/distort.py)")
    parser.add_argument("--overwrite", action="store_true",
                        help="re-render every view, replacing a folder rendered with other parameters")


def run(args: argparse.Namespace) -> int:
    from polarref.core.errors import PolarrefError
    from synth.config import preset
    from synth.render import render_scene

    overrides = {k: getattr(args, k) for k in ("views", "width", "height", "spp") if getattr(args, k)}
    if args.fov:
        overrides["fov_deg"] = args.fov
    if args.mesh:
        if args.scene != "comet":
            raise PolarrefError("a mesh is only supported for the comet scene")
        overrides["mesh"] = args.mesh
        from polarref.core.atomic import refuse_inside_inputs

        refuse_inside_inputs(args.out, [args.mesh])  # --overwrite would render over the mesh's folder
    try:
        cfg = preset(args.scene, args.preset, seed=args.seed, **overrides)
    except ValueError as exc:  # a twin of the other scene kind
        raise PolarrefError(str(exc)) from exc
    if args.oblique is not None:
        if args.scene != "uav":
            raise PolarrefError("an oblique tilt is only supported for the uav scene")
        cfg = dataclasses.replace(cfg, uav=dataclasses.replace(cfg.uav, oblique_deg=args.oblique))
    if args.distortion:
        from synth.distort import render_distorted_scene

        try:
            ks = [float(v) for v in args.distortion.split(",")]
        except ValueError:
            ks = []
        if not 1 <= len(ks) <= 2 or not all(abs(k) < float("inf") for k in ks):
            raise PolarrefError(f"--distortion {args.distortion!r}: expected K1 or K1,K2")
        result = render_distorted_scene(args.scene, args.out, cfg, ks[0], ks[1] if len(ks) > 1 else 0.0,
                                        overwrite=args.overwrite)
    else:
        result = render_scene(args.scene, args.out, cfg, overwrite=args.overwrite)
    if result.rendered:
        print(f"rendered {result.rendered} views ({result.skipped} already done) in {result.seconds:.1f} s: "
              f"{result.images_per_s:.2f} images/s, {result.seconds / result.rendered:.3f} s/image "
              f"({result.variant}); total {result.total_seconds:.1f} s -> {result.root}")
    else:
        print(f"all {result.skipped} views already rendered in {result.root} (use --overwrite to redo)")
    return 0
