"""pycolmap's incremental mapper, made to survive interruption: snapshots plus a segment ledger.

On a 631-view twin COLMAP's incremental mapper runs for hours on one core, longer than a
working session lasts, and ``incremental_mapping`` keeps nothing of a run that is killed. Here
COLMAP writes a snapshot of the model every ``snapshot_every`` registered frames
(``snapshots/<epoch ms>``, its own ``snapshot_path`` option) and a rerun continues from the newest
complete one (``input_path``), on a fresh copy of the database.

Time is counted honestly, in ``segments.json``: a segment contributes the time from its start to
the last snapshot it completed (what it did after that snapshot is done again by the next
segment, so it is not counted), or to its end when it finished. A snapshot counts as complete
once the mapper has moved on to the next image (the ``next_image_callback`` runs after the
write); anything else in ``snapshots/`` at a segment's start is a partial write and is removed.

A resumed run is not bit for bit the run an uninterrupted mapper makes: COLMAP restarts its
global-BA schedule from the loaded model's size, and pays loading the database once more per
segment. Reports therefore state how many segments a model took.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

from polarref.core import records
from polarref.peers.colmap_sfm import ColmapSfMOptions, ColmapSfMRun, _pycolmap, copy_database, largest_model
from polarref.model.colmap import incremental_options

LEDGER = "segments.json"


@dataclass
class MapperSegment:
    """One process's share of a resumable incremental mapping."""

    started_utc: str
    start_epoch_s: float
    resumed_from: str = ""                    # snapshot folder it continued from; "" = fresh start
    registered_at_start: int = 0              # images in that snapshot
    last_snapshot: str = ""                   # newest snapshot this segment completed
    last_snapshot_epoch_s: float | None = None
    finished_epoch_s: float | None = None     # set when the mapper returned

    @property
    def counted_s(self) -> float:
        """Time this segment adds to the method's runtime (see the module docstring)."""
        if self.finished_epoch_s is not None:
            return self.finished_epoch_s - self.start_epoch_s
        if self.last_snapshot_epoch_s is not None:
            return max(0.0, self.last_snapshot_epoch_s - self.start_epoch_s)
        return 0.0


@dataclass
class MapperLedger:
    segments: list[MapperSegment] = field(default_factory=list)

    @property
    def counted_s(self) -> float:
        return sum(s.counted_s for s in self.segments)


def _snapshots(folder: Path) -> list[str]:
    return sorted((p.name for p in folder.iterdir() if p.is_dir() and p.name.isdigit()), key=int)


def _start_point(work: Path) -> tuple[MapperLedger, str]:
    """The ledger to continue and the snapshot to resume from ("" = start afresh)."""
    snaps, path = work / "snapshots", work / LEDGER
    ledger = records.load(MapperLedger, path) if path.is_file() else MapperLedger()
    last = ledger.segments[-1] if ledger.segments else None
    resume = "" if last is None or last.finished_epoch_s is not None else (last.last_snapshot or last.resumed_from)
    if not resume or not (snaps / resume).is_dir():
        ledger, resume = MapperLedger(), ""  # nothing usable: a finished or foreign run starts over
    snaps.mkdir(parents=True, exist_ok=True)
    for name in _snapshots(snaps):
        if name != resume:
            shutil.rmtree(snaps / name)
    return ledger, resume


def map_incremental_resumable(db_path: Path, image_dir: Path, work_dir: Path, opts: ColmapSfMOptions,
                              snapshot_every: int = 20,
                              cancel_after_images: int | None = None) -> tuple[ColmapSfMRun, MapperLedger]:
    """Run, or continue, incremental mapping of ``db_path`` in ``work_dir``.

    Args:
        snapshot_every: registered frames between snapshots (>= 1).
        cancel_after_images: fault injection for tests: cancel (as a kill would stop it) once the
            mapper has asked for this many next images in this segment. pycolmap then raises
            ``InterruptedError`` and the ledger keeps the segment as unfinished.

    Returns:
        The largest model with ``stage_runtime_s["mapping"]`` = the ledger's counted time, and the
        ledger (also in ``work_dir/segments.json``).
    """
    if snapshot_every < 1:
        raise ValueError(f"snapshot_every must be >= 1, got {snapshot_every}")
    pycolmap = _pycolmap()
    work = Path(work_dir)
    work.mkdir(parents=True, exist_ok=True)
    ledger, resume = _start_point(work)
    snaps = work / "snapshots"
    seg = MapperSegment(time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), time.time(), resume,
                        pycolmap.Reconstruction(str(snaps / resume)).num_reg_images() if resume else 0)
    ledger.segments.append(seg)
    records.save(ledger, work / LEDGER)
    db = copy_database(Path(db_path), work / "database.db")
    options = incremental_options(opts)
    options.snapshot_path, options.snapshot_frames_freq = str(snaps), int(snapshot_every)
    token = pycolmap.CancellationToken()
    asked = [0]

    def on_next_image() -> None:
        asked[0] += 1
        names = _snapshots(snaps)
        newest = names[-1] if names else ""
        if newest and newest not in (resume, seg.last_snapshot):
            seg.last_snapshot, seg.last_snapshot_epoch_s = newest, int(newest) / 1000.0
            records.save(ledger, work / LEDGER)
            for old in names[:-1]:  # one complete snapshot is all a resume needs
                shutil.rmtree(snaps / old, ignore_errors=True)
        if cancel_after_images is not None and asked[0] >= cancel_after_images:
            token.cancel()

    out = work / "sparse"
    out.mkdir(parents=True, exist_ok=True)
    recs = pycolmap.incremental_mapping(str(db), str(image_dir), str(out), options=options,
                                        input_path=str(snaps / resume) if resume else "",
                                        next_image_callback=on_next_image, cancellation_token=token)
    seg.finished_epoch_s = time.time()
    records.save(ledger, work / LEDGER)
    return largest_model(recs, db, ledger.counted_s), ledger
