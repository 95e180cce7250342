"""Render a contiguous sub-block of a UAV twin (synth.subblock) into a scene folder. Resumable.

Usage: python scripts/twin_subblock.py TWIN OUT --lines A:B --positions C:D [--threads N]

Builds the whole twin's geometry, writes OUT/scene.json (cut to the block, see synth.subblock),
mesh.ply (the whole twin's), gt/ (the block's views) and renders each block view not yet on disk
with the twin's own renderer (same images as a full render of the twin). --threads bounds
Dr.Jit's threads (default 1: the machine is shared).
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def _range(text: str) -> tuple[int, int]:
    a, b = text.split(":")
    return int(a), int(b)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("twin")
    ap.add_argument("out", type=Path)
    ap.add_argument("--lines", type=_range, required=True)
    ap.add_argument("--positions", type=_range, required=True)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args()

    from synth import meshes
    from synth.config import TWINS, twin
    from synth.conventions import pinhole_params
    from synth.mitsuba_variant import load_mitsuba
    from synth.render import _scene_json, _ViewRenderer, build_geometry, code_version, view_names
    from synth.scene import SCENE_JSON, PinholeCamera, atomic_write_bytes, write_gt
    from synth.subblock import SubBlock, cut_scene_json

    if TWINS.get(a.twin) != "uav":
        uav = ", ".join(t for t, s in TWINS.items() if s == "uav")
        print(f"error: {a.twin!r} is not a UAV twin (choose from {uav})", file=sys.stderr)
        return 2
    cfg = twin(a.twin)
    block = SubBlock(a.twin, *a.lines, *a.positions)
    try:
        idx = block.indices(cfg)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    import drjit  # after the checks: a refused call loads no JIT

    t0 = time.perf_counter()
    geo = build_geometry(cfg)
    print(f"geometry of {a.twin}: {len(geo.vertices)} vertices in {time.perf_counter() - t0:.1f} s; "
          f"block {block.label()}: {len(idx)} views", flush=True)
    camera = PinholeCamera(cfg.width, cfg.height, pinhole_params(cfg.width, cfg.height, cfg.fov_deg))
    _, variant = load_mitsuba()
    names = view_names(cfg.views)
    meta = cut_scene_json(_scene_json(cfg, cfg.digest(code_version()), geo, camera, variant, names), block, idx)
    out = a.out
    (out / "images").mkdir(parents=True, exist_ok=True)
    (out / "depth").mkdir(exist_ok=True)
    old = out / SCENE_JSON
    if old.is_file() and json.loads(old.read_text())["subblock"] != meta["subblock"]:
        print(f"error: {out} holds another sub-block; choose a new folder", file=sys.stderr)
        return 1
    atomic_write_bytes(old, (json.dumps(meta, indent=1) + "\n").encode())
    if not (out / "mesh.ply").is_file():
        meshes.write_ply(out / "mesh.ply", geo.vertices, geo.faces,
                         np.repeat(np.round(geo.albedo * 255).astype(np.uint8)[:, None], 3, 1))
    write_gt(out, camera, [names[k] for k in idx], [geo.poses[k] for k in idx])
    todo = [k for k in idx if not ((out / "images" / names[k]).is_file()
                                   and (out / "depth" / (names[k][:-4] + ".npy")).is_file())]
    drjit.set_thread_count(a.threads)
    renderer = _ViewRenderer(cfg, geo)
    for n, k in enumerate(todo, start=1):
        t = time.perf_counter()
        renderer.render(k, out)
        print(f"view {names[k]} ({n}/{len(todo)}) {time.perf_counter() - t:.1f} s", flush=True)
    print(f"done: {len(idx)} views, {len(todo)} rendered now, {time.perf_counter() - t0:.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
