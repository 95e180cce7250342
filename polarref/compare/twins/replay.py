"""The mapper of a finished campaign cell run again with each of our BA forms, interleaved.

A campaign pin times ``ours-euclidean`` and ``ours-polar`` in cells about a quarter of an hour
apart, so its per-seed ratio of the BA inside the mapper carries whatever else the machine did in
between: at pin ee35ac1, poets-park seed 2 read x1.43 (normal equations x1.27, Schur x1.33,
arithmetic that is the same for both forms), and a replay of the same cell the same evening read
x1.20 with normal equations x1.00. A replay reads the cell's cached front end (features, matches,
verification: the same inputs for both forms), runs the mapper stage in a fresh spawned process per
form, alternating the forms over the repeats, and records the BA's time split by local and
global calls. It measures the BA of the current checkout, not the cell's: the record says which.

    python -m polarref.compare.twins.replay CELL_DIR --out replay.json [--repeats 1]
"""

from __future__ import annotations

import argparse
import logging
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path

from polarref.compare.run import jobs
from polarref.compare.twins import campaign_jobs as J
from polarref.compare.twins.campaign_records import OURS, read_stage
from polarref.core import isolated as runner
from polarref.core import records
from polarref.core.atomic import check_writable_parent
from polarref.core.errors import PolarrefError
from polarref.core.provenance import Provenance, collect_record
from polarref.core.status import RunStatus
from polarref.sfm.ba_runs import BARun
from polarref.sfm.pipeline import run_sfm, with_ba

log = logging.getLogger(__name__)
FORMAT = "polarref-mapper-replay/1"
# what the mapper's BA records put in time_in (polarref.ba.options.BASummary.time_in)
PHASES = ("evaluate", "normal_equations", "schur", "solve", "structure", "update")
TIMEOUT_S = 3600.0
MAX_REPEATS = 20


@dataclass(frozen=True)
class BASplit:
    """Seconds of one kind of mapper BA call (local or global), summed over the calls."""

    calls: int
    wall_s: float
    setup_s: float
    phases_s: tuple[float, ...]      # in the order of PHASES
    observations: int


@dataclass(frozen=True)
class ReplayRun:
    """One run of the mapper stage with one form."""

    method: str                      # ours-euclidean | ours-polar
    repeat: int
    status: RunStatus
    reason: str
    process_wall_s: float            # the spawned mapper process, start-up included
    ba_s: float | None               # "bundle adjustment" of the run's stage times
    local: BASplit | None
    whole: BASplit | None            # the global BAs


@dataclass(frozen=True)
class MapperReplay:
    format: str
    cell: str                        # the cell's (twin, seed) work folder
    cell_commit: str                 # the commit its stages ran at
    runs: tuple[ReplayRun, ...]
    provenance: Provenance           # this checkout: the code whose BA was timed

    def ratio(self, part: str = "ba") -> float | None:
        """Median polar over median Euclidean seconds: ``ba`` (all BA calls), ``local`` or ``whole``."""
        e, p = (self._median(method, part) for method in OURS)  # OURS: (Euclidean, polar)
        return p / e if e and p is not None else None

    def _median(self, method: str, part: str) -> float | None:
        vals = [v for r in self.runs if r.method == method and r.status == RunStatus.OK
                and (v := _seconds(r, part)) is not None]
        return statistics.median(vals) if vals else None


def _seconds(run: ReplayRun, part: str) -> float | None:
    """None where the run has no such part (a missing value is not 0 s)."""
    if part == "ba":
        return run.ba_s
    split = run.local if part == "local" else run.whole
    return split.wall_s if split is not None else None


def split_ba(runs: list[BARun], kind: str) -> BASplit | None:
    """The calls of ``kind`` (local | global) among a mapper's BA runs; None if none of them ran."""
    rows = [b.summary for b in runs if b.kind == kind and b.summary is not None]
    if not rows:
        return None
    phases = tuple(sum(float(s.time_in.get(k, 0.0)) for s in rows) for k in PHASES)
    return BASplit(len(rows), sum(float(s.wall_s) for s in rows), sum(float(s.setup_s or 0.0) for s in rows),
                   phases, sum(int(s.num_observations) for s in rows))


@dataclass(frozen=True)
class ReplayJob:
    """What one mapper process sends back: the BA seconds and their split."""

    ba_s: float
    local: BASplit | None
    whole: BASplit | None


def map_and_split(image_dir: str, camera: dict, ba: str, work_dir: str, preset: str, cache_dir: str, pairs_file: str,
                  seed: int, threads: int) -> ReplayJob:
    """The cell's mapper stage (campaign_jobs.ours_map's settings) and its BA runs split by kind."""
    config = J.seeded_config(preset, cache_dir, pairs_file, seed, threads)
    result = run_sfm(Path(image_dir), Path(work_dir) / "sfm", with_ba(config, ba), camera=jobs.camera_from_json(camera),
                     overwrite=True)
    bas = list(result.report.ba or [])
    return ReplayJob(float(result.report.runtime_s.get("ba", 0.0)), split_ba(bas, "local"), split_ba(bas, "global"))


def _cell_kwargs(cell: Path, method: str) -> tuple[dict, str]:
    path = cell / "stages" / f"{method}.result.json"
    items = runner.finished_kwargs(path)
    if items is None:
        raise PolarrefError(f"{cell}: no finished {method} stage in {path.name}; replay needs a finished cell")
    stage = cell / "stages" / f"{method}.json"
    return dict(items), read_stage(stage).git_commit if stage.is_file() else ""


def replay(cell: Path, work: Path, repeats: int = 1) -> MapperReplay:
    """Run the mapper stage of both forms ``repeats`` times each, alternating (E, P, P, E, ...)."""
    if not 1 <= repeats <= MAX_REPEATS:
        raise PolarrefError(f"--repeats {repeats}: choose 1 to {MAX_REPEATS}")
    jobs = {m: _cell_kwargs(cell, m) for m in OURS}
    for kwargs, _ in jobs.values():
        if not Path(kwargs.get("cache_dir", "")).is_dir():
            raise PolarrefError(f"{cell}: the cell's front-end cache {kwargs.get('cache_dir')!r} is gone")
    runs = []
    for k in range(repeats):
        order = OURS if k % 2 == 0 else OURS[::-1]
        for method in order:
            kwargs = dict(jobs[method][0], work_dir=str(work / f"{method}-r{k}"))
            log.info("replay %s repeat %d", method, k)
            runs.append(_run_one(method, k, kwargs, work))
    kwargs, commit = jobs[OURS[1]]
    env = collect_record(seeds={"ransac": int(kwargs.get("seed", 0))},
                         threads={"ours_frontend": int(kwargs.get("threads", 0))})
    return MapperReplay(FORMAT, str(cell), commit, tuple(runs), env)


def _run_one(method: str, repeat: int, kwargs: dict, work: Path) -> ReplayRun:
    out = runner.run_isolated(map_and_split, kwargs, TIMEOUT_S, work / "stages", f"{method}-r{repeat}")
    if out.status != RunStatus.OK:
        return ReplayRun(method, repeat, out.status, out.reason, out.wall_s, None, None, None)
    job = out.result
    return ReplayRun(method, repeat, RunStatus.OK, "", out.wall_s, job.ba_s, job.local, job.whole)


def summary_lines(rep: MapperReplay) -> list[str]:
    """One line per run and the three ratios (what the CLI prints)."""
    lines = [f"{r.method} r{r.repeat}: {r.status.value} BA {r.ba_s if r.ba_s is None else round(r.ba_s, 1)} s"
             + (f" (local {r.local.wall_s:.1f} s)" if r.local else "") for r in rep.runs]
    for part in ("ba", "local", "whole"):
        v = rep.ratio(part)
        lines.append(f"polar / Euclidean {part}: " + ("not tested" if v is None else f"x{v:.3f}"))
    return lines


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    ap = argparse.ArgumentParser(prog="python -m polarref.compare.twins.replay", description=__doc__.split("\n")[0])
    ap.add_argument("cell", type=Path, help="a campaign cell's work folder (<work>/<pin>/<twin>/seed<k>)")
    ap.add_argument("--out", type=Path, required=True, help="the replay record (JSON)")
    ap.add_argument("--work", type=Path, default=None,
                    help="models and logs, not for git (default: polarref-out/replay/<name of --out>)")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--overwrite", action="store_true")
    a = ap.parse_args(argv)
    try:
        if a.out.exists() and not a.overwrite:
            raise PolarrefError(f"{a.out} exists; pass --overwrite to replace it")
        check_writable_parent(a.out)
        work = a.work or Path("polarref-out") / "replay" / a.out.stem
        rep = replay(a.cell.resolve(), work.resolve(), a.repeats)
        records.save(rep, a.out)
        print("\n".join(summary_lines(rep)))
        return 0 if all(r.status == RunStatus.OK for r in rep.runs) else 1
    except PolarrefError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted; finished outputs were kept", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
