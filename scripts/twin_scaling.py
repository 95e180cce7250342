"""Stage by stage cost of our SfM on contiguous sub-blocks of a rendered UAV twin (issue 34).

    python scripts/twin_scaling.py run RENDER WORK OUT_DIR --twin mappilot --lines A:B --positions C:D
    python scripts/twin_scaling.py report OUT_DIR [--twin mappilot]

``run`` cuts the block out of a full render of the twin (RENDER: read only; its images and depth
maps are copied, ``scripts/twin_subblock.py`` writes the block's scene.json and GT without
rendering anything), chooses the twin's pairs on the block's pose priors, and runs our pipeline
with an empty cache, Euclidean BA then polar BA (the polar run reads the front end from the cache
the first run wrote: its front-end stages are marked cached and left out of the fits). Each run
becomes ``OUT_DIR/runs/<block>-<ba>.json`` (a finished one is not rerun). ``report`` fits the
per-stage scaling (:mod:`polarref.compare.twins.scaling`) and writes ``twin-scaling-<ba>.json/.md``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _range(text: str) -> tuple[int, int]:
    a, b = text.split(":")
    return int(a), int(b)


def cut_block(render: Path, twin: str, lines, positions, scene: Path) -> None:
    """The block's scene folder: images and depth copied from the full render, the rest written by
    twin_subblock.py (which renders only views missing on disk: none here)."""
    from synth.config import twin as twin_cfg
    from synth.render import view_names
    from synth.subblock import SubBlock

    cfg = twin_cfg(twin)
    idx = SubBlock(twin, *lines, *positions).indices(cfg)
    names = view_names(cfg.views)
    for sub in ("images", "depth"):
        (scene / sub).mkdir(parents=True, exist_ok=True)
    for k in idx:
        stem = names[k][:-4]
        for src, dst in ((render / "images" / names[k], scene / "images" / names[k]),
                         (render / "depth" / f"{stem}.npy", scene / "depth" / f"{stem}.npy")):
            if not src.is_file():
                raise SystemExit(f"{src} is not rendered yet")
            if not dst.is_file():
                shutil.copyfile(src, dst)
    if not (scene / "mesh.ply").is_file():
        shutil.copyfile(render / "mesh.ply", scene / "mesh.ply")
    cmd = [sys.executable, str(ROOT / "scripts" / "twin_subblock.py"), twin, str(scene),
           "--lines", f"{lines[0]}:{lines[1]}", "--positions", f"{positions[0]}:{positions[1]}"]
    subprocess.run(cmd, check=True)


def run_block(scene: Path, work: Path, ba: str, label: str):
    import dataclasses

    from polarref.compare.run import ours, presets
    from polarref.compare.run.scenes import prepare
    from polarref.compare.twins.pipeline import default_pairing
    from polarref.compare.twins.scaling import BAStats, BlockRun
    from polarref.core.provenance import collect_record
    from polarref.sfm.pairing import pairs_file_name, priors_from_scene, select, write_pairs
    from polarref.sfm.pipeline import run_sfm, with_ba
    from synth.scene import load_scene

    sc = prepare(str(scene), presets.DEFAULT, 0)
    meta = load_scene(scene).meta
    pair_set = select(priors_from_scene(meta), default_pairing("mappilot", meta))
    pairs = write_pairs(work / pairs_file_name(pair_set), pair_set, {"scene_digest": meta.get("digest")})
    config = with_ba(ours.sfm_config(presets.DEFAULT.name, work / "cache", str(pairs)), ba)
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    res = run_sfm(sc.image_dir, work / f"sfm-{ba}", config, camera=sc.camera, gt=sc.gt, overwrite=True)
    wall = time.perf_counter() - t0
    rep = res.report
    bas = [b for b in (rep.ba or []) if b.summary is not None]
    glob = [b for b in bas if b.kind == "global"]
    stats = BAStats(sum(b.kind == "local" for b in bas), sum(b.wall_s for b in bas if b.kind == "local"),
                    len(glob), sum(b.wall_s for b in glob), glob[-1].wall_s if glob else 0.0,
                    glob[-1].summary.iterations if glob else 0, bas[0].wall_s if bas else None)
    m = rep.metrics
    return BlockRun(label, ba, len(sc.image_names), len(pair_set.pairs), int(rep.num_verified_pairs or 0),
                    int(rep.num_tracks or 0), int(m.reprojected_px), int(m.registered_images), int(m.tie_points),
                    None if m.gt is None else float(m.gt.rotation_error_deg_mean), tuple(res.stages), stats,
                    load0, os.getloadavg(), config.threads, wall,
                    collect_record(seeds={"verification": config.verification.seed},
                                   threads={"frontend": config.threads}))


def _matching_note(path: Path) -> str:
    """The matcher's before/after (scripts/match_speed.py) in one sentence, from its JSON."""
    if not path.is_file():
        return ""
    import json

    d = json.loads(path.read_text())
    (before, b), (after, f) = d["cpu_s_per_pair"].items()
    return (f"Matching, the bottleneck of the front end, before/after this branch's mutual check "
            f"(`scripts/match_speed.py`, {path.name}): {b:.3f} -> {f:.3f} CPU s per pair ({before} -> {after}; "
            f"x{d['speedup']:.2f}) on the {d['pairs']} pairs of {d['images']} views, {d['mean_keypoints']:.0f} keypoints per "
            f"view, identical matches: {d['identical_matches']}; commit {d['environment']['git_commit'][:10]}, load "
            f"{d['load_before'][0]:.1f} -> {d['load_after'][0]:.1f}.")


def _ba_notes(out: Path) -> str:
    """The polar vs Euclidean global BAs of a block (``ba-detail`` JSON), in one sentence each."""
    import json

    notes = []
    for path in sorted(out.glob("global-ba-*.json")):
        d = json.loads(path.read_text())
        eu, po = d["forms"]["euclidean"]["global"], d["forms"]["polar"]["global"]
        eu_s, po_s = sum(g["wall_s"] for g in eu), sum(g["wall_s"] for g in po)
        ratio = po_s / max(eu_s, 1e-9)
        verdict = ("within" if ratio <= 1.3 else "over") + " issue 34's <= 1.3x"
        slow = max(po, key=lambda g: g["wall_s"])
        same = [g["wall_s"] for g in eu if g["num_cameras"] == slow["num_cameras"]]
        notes.append(
            f"Global BAs in the mapper on {d['block']} ({path.name}, wall s): Euclidean {eu_s:.1f} s over {len(eu)}, "
            f"polar {po_s:.1f} s over {len(po)} (x{ratio:.2f}, {verdict}); the final one {eu[-1]['wall_s']:.1f} vs "
            f"{po[-1]['wall_s']:.1f} s (normal equations {eu[-1]['time_in']['normal_equations']:.1f} vs "
            f"{po[-1]['time_in']['normal_equations']:.1f} s); the slowest polar one {slow['wall_s']:.1f} s at "
            f"{slow['num_cameras']} cameras against {same[0] if same else float('nan'):.1f} s Euclidean.")
    return " ".join(notes)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("render", type=Path)
    r.add_argument("work", type=Path)
    r.add_argument("out", type=Path)
    r.add_argument("--twin", default="mappilot")
    r.add_argument("--lines", type=_range, required=True)
    r.add_argument("--positions", type=_range, required=True)
    r.add_argument("--ba", nargs="+", default=["euclidean", "polar"])
    n = sub.add_parser("annotate", help="add each run's first BA time from its metrics.json (runs made before it was recorded)")
    n.add_argument("work", type=Path)
    n.add_argument("out", type=Path)
    d = sub.add_parser("ba-detail", help="the global BAs of one block's runs (from their metrics.json) as one JSON")
    d.add_argument("work", type=Path)
    d.add_argument("block")
    d.add_argument("out", type=Path)
    p = sub.add_parser("report")
    p.add_argument("out", type=Path)
    p.add_argument("--twin", default="mappilot")
    p.add_argument("--note", default="")
    a = ap.parse_args(argv)

    from polarref.compare.twins import scaling as S
    from polarref.core import records

    if a.cmd == "annotate":
        import dataclasses
        import json

        for f in sorted((a.out / "runs").glob("*.json")):
            run = records.load(S.BlockRun, f)
            metrics = json.loads((a.work / run.label / f"sfm-{run.ba}" / "metrics.json").read_text())
            first = float(metrics["ba"][0]["wall_s"])
            records.save(dataclasses.replace(run, ba_stats=dataclasses.replace(run.ba_stats, first_s=first)), f)
        return 0
    if a.cmd == "ba-detail":
        import json

        from polarref.core.atomic import atomic_write

        doc = {"format": "polarref-twin-scaling-ba/1", "block": a.block, "forms": {}}
        for ba in ("euclidean", "polar"):
            m = json.loads((a.work / a.block / f"sfm-{ba}" / "metrics.json").read_text())
            doc["forms"][ba] = {"environment": m["environment"], "global": [
                {k: b.get(k) for k in ("num_registered", "num_cameras", "num_points", "num_observations", "iterations",
                                       "wall_s", "setup_s", "time_in", "linear_solver")}
                for b in m["ba"] if b.get("kind") == "global"]}
        atomic_write(a.out, json.dumps(doc, indent=1) + "\n")
        return 0
    if a.cmd == "report":
        runs = [records.load(S.BlockRun, f) for f in sorted((a.out / "runs").glob("*.json"))]
        note = " ".join(x for x in (a.note, _matching_note(a.out / "matching-before-after.json"), _ba_notes(a.out)) if x)
        for ba in sorted({x.ba for x in runs}):
            S.write(S.build(a.twin, ba, runs, note), a.out)
        return 0
    block = f"{a.twin}-l{a.lines[0]}-{a.lines[1] - 1}-p{a.positions[0]}-{a.positions[1] - 1}"
    scene = a.work / block / "scene"
    cut_block(a.render, a.twin, a.lines, a.positions, scene)
    for ba in a.ba:
        out = a.out / "runs" / f"{block}-{ba}.json"
        if out.is_file():
            print(f"{out} exists: skipped", flush=True)
            continue
        run = run_block(scene, a.work / block, ba, block)
        out.parent.mkdir(parents=True, exist_ok=True)
        records.save(run, out)
        print(f"{out}: {run.views} views, {run.wall_s:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
