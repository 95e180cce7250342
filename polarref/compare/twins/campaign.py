"""The twin campaign (issue 34): every (twin, seed, method) cell from one pinned clean commit,
finished over as many sessions as it takes.

A cell is one method on one twin rendered with one seed (render noise, pose-prior noise and every
RANSAC draw). Its result is one small JSON, ``<cells>/<commit>/<twin>/seed<k>/<method>.json``
(:class:`CampaignCell`), committed as it lands, so a later session (which keeps nothing but git)
runs only the cells that have none. Each cell holds its stages (the shared front end, counted in
every method that reads it, then the method's own: wall, CPU and peak memory per sub-stage, a stage
read from a cache marked so), the method's settings beside the times, the scores, and the
provenance: the pinned commit, the dirty flag, the host, the load averages before and after, the
threads and the seeds.

Only a clean checkout of the pinned commit runs cells (:func:`check_checkout`); ``campaign run``
makes one (``git worktree add --detach``, :func:`ensure_worktree`, under ``--work``) and runs there,
writing the cells back into the calling repository. The table
(:mod:`polarref.compare.twins.campaign_table`) refuses cells of another commit.

    python -m polarref.compare.twins.campaign run COMMIT --twins mappilot --seeds 0 1 2 --work DIR
    python -m polarref.compare.twins.campaign table COMMIT
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from polarref.ba import kernels
from polarref.compare.run import jobs as run_jobs
from polarref.compare.run import presets
from polarref.compare.run.scenes import prepare
from polarref.compare.twins import campaign_table
from polarref.compare.twins import campaign_jobs as J
from polarref.compare.twins.campaign_records import (METHODS, OURS, PYCOLMAP, CampaignCell, CellProvenance,
                                                     CellStage, largest_stage_mb, read_cell)
from polarref.compare.twins.pipeline import PYCOLMAP_FEATURES, PYCOLMAP_SNAPSHOT_EVERY, choose_pairs, score_model
from polarref.core import isolated as runner
from polarref.core import records
from polarref.core.data import REPO_ROOT
from polarref.core.errors import PolarrefError
from polarref.core.provenance import collect_record, git_state
from polarref.core.status import RunStatus
from polarref.io.scene_folder import Scene

log = logging.getLogger(__name__)

CELLS = REPO_ROOT / "reports" / "paper-tables" / "campaign"
# Render settings by size; "twin" is the twin as the paper's dataset, the others are the same twin
# reduced for tests and dry runs (a table never mixes sizes).
SIZES: dict[str, tuple[tuple[str, int], ...]] = {
    "twin": (),
    "small": (("views", 24), ("width", 480), ("height", 360), ("spp", 4)),
    "tiny": (("views", 14), ("width", 320), ("height", 240), ("spp", 4)),
}
TIMEOUT_S = 4 * 3600.0


@dataclass(frozen=True)
class CampaignPlan:
    """What a campaign runs; ``commit`` is the one commit every cell comes from."""

    commit: str                       # 40 hex digits
    twins: tuple[str, ...]
    seeds: tuple[int, ...]
    methods: tuple[str, ...] = METHODS
    size: str = "twin"
    ours_threads: int = 2             # SfMConfig.threads of our front end (both cores)
    pycolmap_threads: int = 2         # pycolmap's num_threads in every stage (1: the older tables)
    timeout_s: float = TIMEOUT_S      # per stage process

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown or self.size not in SIZES or len(self.commit) != 40:
            raise PolarrefError(f"campaign plan: methods {unknown or 'ok'}, size {self.size!r} (choose from "
                                f"{', '.join(SIZES)}), commit {self.commit!r} (40 hex digits)")

    def cell_key(self, method: str) -> str:
        """The cell's file name: pycolmap's thread count is part of it (a 1-thread run is another cell)."""
        return f"{method}-t{self.pycolmap_threads}" if method in PYCOLMAP else method

    def twin_dir(self, twin: str) -> str:
        return twin if self.size == "twin" else f"{twin}-{self.size}"


def cell_path(root: Path, plan: CampaignPlan, twin: str, seed: int, method: str) -> Path:
    return Path(root) / plan.commit / plan.twin_dir(twin) / f"seed{seed}" / f"{plan.cell_key(method)}.json"


# ---- where a campaign may run ------------------------------------------------------------------
def check_checkout(commit: str, state: tuple[str, bool | None] | None = None) -> None:
    """PolarrefError unless this checkout is the clean ``commit``."""
    head, dirty = state if state is not None else git_state()
    if head != commit or dirty is not False:
        raise PolarrefError(f"this checkout is {head or 'not a git checkout'} (dirty: {dirty}); the campaign is "
                            f"pinned to {commit}: cells run only from a clean checkout of it (`campaign run` makes one)")


def ensure_worktree(repo: Path, commit: str, dest: Path) -> Path:
    """A detached, clean worktree of ``commit`` at ``dest`` (made once; PolarrefError when ``dest``
    holds another commit or local changes)."""
    def git(*args: str, cwd: Path = repo) -> str:
        r = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True)
        if r.returncode:
            raise PolarrefError(f"git {' '.join(args)}: {r.stderr.strip()}")
        return r.stdout.strip()

    full = git("rev-parse", "--verify", f"{commit}^{{commit}}")
    if not dest.exists():
        dest.parent.mkdir(parents=True, exist_ok=True)
        git("worktree", "add", "--detach", str(dest), full)
    head = git("rev-parse", "HEAD", cwd=dest)
    if head != full or git("status", "--porcelain", cwd=dest):
        raise PolarrefError(f"{dest} is not a clean checkout of {full} (HEAD {head}); remove it")
    return dest


# ---- running the cells -------------------------------------------------------------------------
def _utc() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def render_twin(twin: str, size: str, seed: int, root: Path) -> tuple[Path, float]:
    """The twin rendered with ``seed`` at ``size`` into ``root`` (views on disk are kept: resumable)."""
    from synth.config import twin as twin_cfg
    from synth.render import render_scene

    cfg = dataclasses.replace(twin_cfg(twin, seed=seed), **dict(SIZES[size]))
    result = render_scene(cfg.scene, root, cfg)
    return root, float(result.total_seconds if result.rendered else 0.0)


class _StageStore:
    """``stages/<job>.json`` (a CellStage) in a (twin, seed) work folder: a finished stage is reused."""

    def __init__(self, out: Path, timeout_s: float, state: tuple[str, bool | None] | None = None):
        self.dir, self.timeout_s, self.state = out / "stages", timeout_s, state
        self.dir.mkdir(parents=True, exist_ok=True)

    def run(self, job: str, shared: bool, fn, kwargs: dict) -> CellStage:
        path = self.dir / f"{job}.json"
        if path.is_file():
            old = records.load(CellStage, path)
            if old.status == RunStatus.OK:
                return dataclasses.replace(old, reused=True)
        commit, dirty = self.state or git_state()
        outcome = runner.run_isolated(fn, kwargs, self.timeout_s, self.dir, job)
        wall = outcome.wall_s
        if outcome.result is not None and outcome.result.run.counted_wall_s is not None:
            wall = float(outcome.result.run.counted_wall_s)   # a resumed mapping: its segments
        rec = CellStage(job, shared, outcome.status, outcome.reason, wall, False, _utc(), commit, dirty, outcome.result)
        records.save(rec, path)
        return rec


def _stage_jobs(plan: CampaignPlan, method: str, scene: Scene, work: Path, pairs: Path, seed: int):
    """(job name, shared, function, kwargs) of the method's two stages."""
    cam, img = run_jobs.camera_to_json(scene.camera), str(scene.image_dir)
    pre, cache = presets.DEFAULT.name, str(work / "cache")
    if method in OURS:
        return [("ours-features", True, J.ours_front,
                 dict(image_dir=img, camera=cam, preset=pre, cache_dir=cache, pairs_file=str(pairs), seed=seed,
                      threads=plan.ours_threads)),
                (method, False, J.ours_map,
                 dict(image_dir=img, camera=cam, ba=method.split("-", 1)[1], work_dir=str(work / method), preset=pre,
                      cache_dir=cache, pairs_file=str(pairs), seed=seed, threads=plan.ours_threads))]
    t = plan.pycolmap_threads
    db = str(work / f"pycolmap-t{t}" / "database.db")
    return [(f"pycolmap-features-t{t}", True, J.pycolmap_front,
             dict(image_dir=img, image_names=list(scene.image_names), camera=cam, db_path=db, seed=seed, threads=t,
                  pairs_file=str(pairs), max_num_features=PYCOLMAP_FEATURES)),
            (plan.cell_key(method), False, J.pycolmap_mapping,
             dict(db_path=db, image_dir=img, work_dir=str(work / plan.cell_key(method)), mapper=method.split("-")[1],
                  seed=seed, threads=t, snapshot_every=PYCOLMAP_SNAPSHOT_EVERY, pairing=f"file: {pairs.name}",
                  max_num_features=PYCOLMAP_FEATURES))]


def run_cell(plan: CampaignPlan, twin: str, seed: int, method: str, scene: Scene, render_s: float,
             work: Path, pairs: tuple[Path, int], state: tuple[str, bool | None] | None = None) -> CampaignCell:
    """Run (or reuse the finished stages of) one cell in ``work`` and return its record (``state``:
    this checkout's git state, a stand-in in tests)."""
    load0, started = os.getloadavg(), _utc()
    store = _StageStore(work, plan.timeout_s, state)
    stages: list[CellStage] = []
    for job, shared, fn, kwargs in _stage_jobs(plan, method, scene, work, pairs[0], seed):
        stages.append(store.run(job, shared, fn, kwargs))
        if stages[-1].status != RunStatus.OK:
            break
    bad = next((s for s in stages if s.status != RunStatus.OK), None)
    metrics = ba_s = None
    if bad is None:
        own = stages[-1].result.run
        metrics = score_model(own.model_dir, scene.gt)
        ba_s = own.stage_runtime_s.get("bundle adjustment") if method in OURS else None
    env = collect_record(seeds={"scene": seed, "ransac": seed}, threads={"ours_frontend": plan.ours_threads,
                                                                         "pycolmap": plan.pycolmap_threads})
    commit, dirty = state or (env.git_commit, env.git_dirty)
    prov = CellProvenance(commit, dirty, socket.gethostname(), started, _utc(), load0,
                          os.getloadavg(), dict(env.threads), dict(env.seeds), env)
    return CampaignCell(twin, plan.size, seed, method, plan.cell_key(method), len(scene.image_names), pairs[1],
                        RunStatus.OK if bad is None else bad.status, "" if bad is None else f"{bad.job}: {bad.reason}"[:300],
                        float(sum(s.wall_s for s in stages)), largest_stage_mb(stages), ba_s, render_s,
                        tuple(stages), metrics, prov)


def todo(plan: CampaignPlan, cells: Path, retry_failed: bool = False) -> list[tuple[str, int, str]]:
    """The (twin, seed, method) cells without a result under ``cells`` (failed ones too with ``retry_failed``)."""
    out = []
    for twin in plan.twins:
        for seed in plan.seeds:
            for m in plan.methods:
                p = cell_path(cells, plan, twin, seed, m)
                if not p.is_file() or (retry_failed and read_cell(p).status != RunStatus.OK):
                    out.append((twin, seed, m))
    return out


def run_campaign(plan: CampaignPlan, cells: Path, work: Path, retry_failed: bool = False,
                 state: tuple[str, bool | None] | None = None) -> list[Path]:
    """Run every missing cell of ``plan`` here (a clean checkout of ``plan.commit``); returns the
    cells written. ``state`` stands in for this checkout's git state (tests)."""
    check_checkout(plan.commit, state)
    written = []
    pending = list(todo(plan, cells, retry_failed))
    if any(method in OURS for _, _, method in pending):
        # compile into this worktree's kernel cache now, or the first cell's BA times include it
        log.info("compiled kernels ready in %.1f s", kernels.warm_up())
    for twin, seed, method in pending:
        twin_work = work / plan.commit[:12] / plan.twin_dir(twin) / f"seed{seed}"
        twin_work.mkdir(parents=True, exist_ok=True)
        root, render_s = render_twin(twin, plan.size, seed, work / "renders" / f"{plan.twin_dir(twin)}-seed{seed}")
        scene = prepare(str(root), presets.DEFAULT, seed)
        pairs = choose_pairs(twin, scene, twin_work)
        log.info("cell %s seed %d %s: started", twin, seed, method)
        cell = run_cell(plan, twin, seed, method, scene, render_s, twin_work, pairs, state)
        path = cell_path(cells, plan, twin, seed, method)
        path.parent.mkdir(parents=True, exist_ok=True)
        records.save(cell, path)
        log.info("cell %s seed %d %s: %s in %.1f min -> %s", twin, seed, method, cell.status, cell.minutes, path)
        written.append(path)
    return written


# ---- command line ------------------------------------------------------------------------------
def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m polarref.compare.twins.campaign", description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run the missing cells (from a worktree of COMMIT)")
    r.add_argument("commit")
    r.add_argument("--twins", nargs="+", default=["mappilot", "rosetta", "poets-park"])
    r.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    r.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    r.add_argument("--size", default="twin", choices=list(SIZES))
    r.add_argument("--pycolmap-threads", type=int, default=2)
    r.add_argument("--work", type=Path, required=True, help="renders, caches, models, the worktree (not for git)")
    r.add_argument("--cells", type=Path, default=CELLS)
    r.add_argument("--retry-failed", action="store_true")
    r.add_argument("--in-worktree", action="store_true", help=argparse.SUPPRESS)   # set for the child
    t = sub.add_parser("table", help="C4/C5 over the seeds from the cells of COMMIT")
    t.add_argument("commit")
    t.add_argument("--cells", type=Path, default=CELLS)
    return ap


def _full_commit(commit: str) -> str:
    r = subprocess.run(["git", "rev-parse", "--verify", f"{commit}^{{commit}}"], cwd=REPO_ROOT, capture_output=True,
                       text=True)
    if r.returncode:
        raise PolarrefError(f"unknown commit {commit!r}")
    return r.stdout.strip()


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    a = _parser().parse_args(argv)
    try:
        commit = _full_commit(a.commit)
        if a.cmd == "table":
            campaign_table.write(campaign_table.build(Path(a.cells) / commit), Path(a.cells) / commit)
            return 0
        plan = CampaignPlan(commit, tuple(a.twins), tuple(a.seeds), tuple(a.methods), a.size,
                            pycolmap_threads=a.pycolmap_threads)
        work, cells = a.work.resolve(), a.cells.resolve()
        if a.in_worktree:
            run_campaign(plan, cells, work, a.retry_failed)
            return 0
        # Always the campaign's own worktree, never the calling checkout: a checkout someone edits
        # while the cells run would change the code under them.
        tree = ensure_worktree(REPO_ROOT, commit, work / f"src-{commit[:12]}")
        env = dict(os.environ, PYTHONPATH=str(tree), POLARREF_CACHE=str(work / "cache"))
        argv2 = [sys.executable, "-m", "polarref.compare.twins.campaign", *(argv or sys.argv[1:])]
        argv2 += ["--work", str(work), "--cells", str(cells), "--in-worktree"]   # absolute paths
        return subprocess.run(argv2, cwd=tree, env=env).returncode
    except PolarrefError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
