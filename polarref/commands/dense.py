"""``polarref dense``: dense point cloud and mesh from a model's poses (multi-view stereo on CPU)."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

NAME = "dense"
HELP = "plane-sweep stereo -> fused coloured cloud (fused.ply) + Poisson mesh (mesh.ply), scored vs GT"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from polarref.commands._types import SEED, float_range, int_range

    parser.add_argument("dir", type=Path, help="scene folder holding images/ (and gt/, mesh.ply, depth/ if synthetic)")
    parser.add_argument("--model", required=True,
                        help="'gt' (the scene's exact cameras) or a COLMAP model folder (e.g. OUT/model of polarref sfm)")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--scale", type=float_range(0.05, 1.0), default=None,
                        help="working resolution / image resolution, in [0.05, 1] (default: images ~320 px wide)")
    parser.add_argument("--sources", type=int_range(2, 16), default=4, help="neighbouring views per depth map (default 4)")
    parser.add_argument("--tau", type=float_range(0.0, 1.0, lo_open=True), default=0.005,
                        help="F-score tolerance / GT scene diameter (default 0.005)")
    parser.add_argument("--poisson-depth", type=int_range(5, 12), default=8,
                        help="octree depth of the Poisson mesh (default 8)")
    parser.add_argument("--seed", type=SEED, default=0, help="seed of the GT surface sampling")
    parser.add_argument("--overwrite", action="store_true", help="write into a non-empty --out")


def run(args: argparse.Namespace) -> int:
    from polarref.compare.run.pipeline import command_line
    from polarref.dense.pipeline import DenseConfig, run_dense

    base = DenseConfig()
    cfg = dataclasses.replace(base, scale=args.scale, num_sources=args.sources, tau_rel=args.tau, seed=args.seed,
                              mesh=dataclasses.replace(base.mesh, depth=args.poisson_depth))
    m = run_dense(args.dir, args.model, args.out, cfg, overwrite=args.overwrite, command=command_line())
    rt = m.runtime_s
    print(f"{m.num_views_with_depth}/{m.num_views} views with depth, {m.num_fused_points} fused points, "
          f"mesh {m.mesh_vertices} vertices; dense stage {rt.get('dense_total', 0):.1f} s, "
          f"peak memory {m.peak_memory_mb:.0f} MB")
    if m.gt is not None and m.gt.cloud is not None:
        c, me = m.gt.cloud, m.gt.mesh
        print(f"vs GT (tau = {m.gt.tau:.4g} = {100 * m.gt.tau_rel:g}% of diameter {m.gt.diameter:.4g}): "
              f"cloud F {c.fscore:.3f} (precision {c.precision:.3f}, recall {c.recall:.3f}); "
              + (f"mesh F {me.fscore:.3f}; " if me else "")
              + f"depth median error {m.gt.depth_median_abs:.4g}")
    for w in m.warnings:
        print(f"warning: {w}")
    print(f"wrote {args.out}/fused.ply, mesh.ply, metrics.json")
    return 0
