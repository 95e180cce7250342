"""Tables 1-3 of the paper beside ours on the twins: one table per twin in the paper's layout and
one README putting the three side by side.

The paper compares OpenMVG with its method; on a twin the Euclidean bundle adjuster of our own
pipeline stands in the OpenMVG column and the polar one in "ours", so the difference column is
the parameterization's alone. pycolmap's mappers are extra columns. A method that did not run (or
failed) is shown as "not run" / its status, never as 0.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from polarref.core import records
from polarref.core.atomic import atomic_write
from polarref.core.provenance import Provenance
from polarref.compare.claims import single_run
from polarref.compare.claims.thresholds import EQUIVALENT_PX, EQUIVALENT_REL
from polarref.core.status import RunStatus

TABLE_FORMAT = "polarref-paper-table/1"
BASELINE, OURS = "ours-euclidean", "ours-polar"
METHODS = (BASELINE, OURS, "pycolmap-incremental-sift", "pycolmap-global-sift")
LABELS = {BASELINE: "Euclidean BA (OpenMVG column)", OURS: "polar BA (ours)",
          "pycolmap-incremental-sift": "pycolmap incremental (its SIFT)",
          "pycolmap-global-sift": "pycolmap global (its SIFT)"}
NOT_RUN = "not run"
NOT_TESTED = "not tested"

@dataclass(frozen=True)
class PaperTable:
    """One of the paper's Tables 1-3 as printed: OpenMVG vs its method, values in ROWS order."""

    table: int
    dataset: str
    images: int
    openmvg: tuple[float, float, int, int]
    ours: tuple[float, float, int, int]


# The paper's Tables 1-3 as printed (OpenMVG vs its method), by twin.
PAPER: dict[str, PaperTable] = {
    "rosetta": PaperTable(1, "Rosetta OSIRIS, comet 67P", 631,
                          (0.482, 77.0, 200_355, 1_086_356), (0.481, 56.0, 200_708, 1_089_739)),
    "poets-park": PaperTable(2, "Poets_park_flats (UAV)", 857,
                             (0.93, 1688.9, 2_724_615, 12_026_356), (0.92, 1244.7, 2_728_281, 12_041_004)),
    "mappilot": PaperTable(3, "MapPilot (UAV)", 493,
                           (1.01, 164.1, 670_355, 1_760_356), (1.01, 125.4, 671_331, 1_765_684)),
}
ROWS = ("accuracy_px", "efficiency_min", "tie_points", "reprojected_px")
ROW_LABELS = {"accuracy_px": "Accuracy (px)", "efficiency_min": "Efficiency (min)",
              "tie_points": "#Tie point", "reprojected_px": "#Reprojected px"}


@dataclass(frozen=True)
class TwinRow:
    """The table's view of one method on one twin, built from its stages' MethodRuns
    (:func:`polarref.compare.twins.pipeline.table_row`). Values are None when not measured
    (status other than ok); a method that was not asked for is ``SKIPPED`` with no reason."""

    name: str
    status: RunStatus = RunStatus.SKIPPED
    reason: str = ""
    num_images: int = 0
    registered: int | None = None
    accuracy_px: float | None = None          # mean reprojection error over all observations
    efficiency_min: float | None = None       # whole method wall time, render excluded
    tie_points: int | None = None
    reprojected_px: int | None = None         # observations of the tie points
    rotation_error_deg: float | None = None   # GT, after Sim3 alignment (mean over images)
    center_error_rel: float | None = None     # GT, mean centre error / scene size
    stages_s: dict[str, float] = field(default_factory=dict)
    peak_rss_mb: float | None = None          # largest resident set of the method's processes
    mean_keypoints: float | None = None       # features per image the method started from (None: unknown)
    segments: int = 1                         # processes the mapping took (> 1: resumed from snapshots)


class HasCommit(Protocol):
    """A stage record or its provenance entry: the code that finished the stage."""

    git_commit: str
    git_dirty: bool | None


@dataclass(frozen=True)
class StageProvenance:
    """Which code finished one stage ("" / None: written before stages kept their commit)."""

    git_commit: str = ""
    git_dirty: bool | None = None
    finished_utc: str = ""


@dataclass
class TwinProvenance:
    """Where and with what a twin's table was made."""

    commit: str | None = None             # HEAD when the table was written
    dirty: bool | None = None
    machine: str | None = None
    seed: int = 0
    pairs_file: str = ""
    wall_s_this_call: float = 0.0         # this call's wall time (finished stages are not rerun)
    pycolmap_max_num_features: int = 0
    environment: Provenance | None = None
    stages: dict[str, StageProvenance] = field(default_factory=dict)


@dataclass
class TwinTable:
    """Everything of one twin's table (``paper-table.json``)."""

    twin: str
    images: int
    pairs: int | None
    methods: dict[str, TwinRow]           # name -> its row
    provenance: TwinProvenance | None = None

    def to_dict(self) -> dict:
        return {**records.to_dict(self), "format": TABLE_FORMAT}

    @staticmethod
    def from_dict(d: dict, label: str = "paper-table.json") -> "TwinTable":
        """The table from its JSON, strictly (a table written without provenance reads with None)."""
        if isinstance(d, dict):
            d = {k: v for k, v in d.items() if k != "format"}
            if not d.get("provenance"):
                d.pop("provenance", None)
            if isinstance(d.get("methods"), dict):   # tables before RunStatus wrote "not run"
                d["methods"] = {k: dict(v, status=RunStatus.SKIPPED.value)
                                if isinstance(v, dict) and v.get("status") == NOT_RUN else v
                                for k, v in d["methods"].items()}
        return records.from_dict(TwinTable, d, label=label)


def _fmt(row: str, v) -> str:
    if v is None:
        return NOT_RUN
    if row == "accuracy_px":
        return f"{v:.3f}"
    if row == "efficiency_min":
        return f"{v:.1f}"
    return f"{int(v):,}"


def status_text(m: TwinRow | None) -> str:
    """The status as the tables print it: "not run" for a method not asked for."""
    return NOT_RUN if m is None or (m.status == RunStatus.SKIPPED and not m.reason) else m.status.value


def table_cell(m: TwinRow | None, row: str) -> str:
    if m is None or m.status != RunStatus.OK:
        return status_text(m)
    return _fmt(row, getattr(m, row))


def difference(row: str, base: TwinRow | None, ours: TwinRow | None) -> str:
    """The paper's "Improving" column: ours vs the Euclidean baseline."""
    if base is None or ours is None or base.status != RunStatus.OK or ours.status != RunStatus.OK:
        return "not tested"
    a, b = getattr(base, row), getattr(ours, row)
    if a is None or b is None:
        return "not tested"
    if row == "accuracy_px":  # the report's paper-format "Equivalent" (thresholds.EQUIVALENT_*)
        margin = max(EQUIVALENT_PX, EQUIVALENT_REL * max(abs(a), abs(b)))
        return "equivalent" if abs(b - a) <= margin else f"{b - a:+.3f} px"
    if row == "efficiency_min":
        return f"{b - a:+.1f} min (x{a / b:.2f})" if b > 0 else "not tested"
    return f"{int(b) - int(a):+,}"


@dataclass(frozen=True)
class TwinVerdict:
    """One claim on one twin: the verdict word and the figures it rests on."""

    verdict: str                      # one of schema.VERDICTS
    figures: str = ""                 # "" when not tested
    values: dict[str, float | None] = field(default_factory=dict)   # the figures as numbers (None: not measured)

    def __str__(self) -> str:
        return f"{self.verdict} ({self.figures})" if self.figures else self.verdict


@dataclass(frozen=True)
class TwinVerdicts:
    """C4 (faster) and C5 (more tie points) on one twin."""

    c4: TwinVerdict
    c5: TwinVerdict

    def by_claim(self) -> tuple[tuple[str, TwinVerdict], ...]:
        """(claim id, verdict) pairs, C4 first (the scorecard's ids)."""
        return (("C4", self.c4), ("C5", self.c5))


def _x(v: float | None) -> str:
    return "not measured" if v is None else f"x{v:.2f}"


def verdicts(table: TwinTable | None) -> TwinVerdicts:
    """C4 (faster) and C5 (more tie points) on this twin with the scorecard's single-run rules
    (:mod:`polarref.compare.claims.single_run`): polar vs the Euclidean baseline of the same pipeline, one
    run, so a direction with the scorecard's margins, not a test over seeds; "not tested" when
    either side (or a value) is missing."""
    base = table.methods.get(BASELINE) if table else None
    ours = table.methods.get(OURS) if table else None
    if not (base and ours and base.status == ours.status == RunStatus.OK):
        return TwinVerdicts(TwinVerdict(NOT_TESTED), TwinVerdict(NOT_TESTED))
    word4, speedup = single_run.speedup_verdict(base.efficiency_min, ours.efficiency_min)
    ba = single_run.ratio(base.stages_s.get("bundle adjustment"), ours.stages_s.get("bundle adjustment"))
    fig4 = "" if speedup is None else (
        f"whole-method speed-up Euclidean/polar {_x(speedup)}: supported at >= x{single_run.SUPPORTED_AT:.2f}, "
        f"not supported below x{single_run.NOT_SUPPORTED_BELOW:.2f}; BA time Euclidean/polar {_x(ba)}; one run")
    c4 = TwinVerdict(word4, fig4, {"speedup": speedup, "ba_speedup": ba})
    ta, tb, ra, rb = base.tie_points, ours.tie_points, base.reprojected_px, ours.reprojected_px
    word5 = single_run.more_counts_verdict(tb, ta, rb, ra)
    fig5 = "" if word5 == NOT_TESTED else (
        f"{tb - ta:+,} tie points (margin {single_run.tie_margin(ta):,.0f}), {rb - ra:+,} reprojected px "
        f"(margin {single_run.tie_margin(ra):,.0f}); one run")
    c5 = TwinVerdict(word5, fig5, {"tie_points": None if word5 == NOT_TESTED else tb - ta,
                                   "reprojected_px": None if word5 == NOT_TESTED else rb - ra})
    return TwinVerdicts(c4, c5)


def render_table(table: TwinTable) -> str:
    """Markdown: the paper's layout, then the GT/extra rows, pycolmap, stages and memory."""
    p = PAPER.get(table.twin)
    m = table.methods
    lines = [f"# {table.twin}: twin of the paper's Table {p.table if p else '?'}", ""]
    if p:
        lines += [f"Twin of {p.dataset} ({p.images} images); {table.images} rendered views with exact "
                  f"ground truth; {table.pairs if table.pairs is not None else 'unknown'} image pairs, the "
                  "same for every method.", ""]
    lines += ["| Indicators | " + " | ".join(LABELS[k] for k in (BASELINE, OURS)) + " | Improving |",
              "|---|---|---|---|"]
    for row in ROWS:
        lines.append(f"| {ROW_LABELS[row]} | {table_cell(m.get(BASELINE), row)} | {table_cell(m.get(OURS), row)} | "
                     f"{difference(row, m.get(BASELINE), m.get(OURS))} |")
    lines += ["", "All methods, same images and pairs (accuracy: mean reprojection error over all "
              "observations; efficiency: wall time of the whole method, render excluded; GT errors after a "
              "Sim3 alignment):", "",
              "| method | status | registered | accuracy (px) | efficiency (min) | tie points | reprojected px "
              "| rotation error (deg) | centre error (% of scene) | peak memory (MB) | keypoints / image |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in METHODS:
        r = m.get(name) or TwinRow(name)
        ok = r.status == RunStatus.OK
        reg = f"{r.registered}/{table.images}" if ok and r.registered is not None else "-"
        rot = f"{r.rotation_error_deg:.4f}" if ok and r.rotation_error_deg is not None else "-"
        cen = f"{100 * r.center_error_rel:.4f}" if ok and r.center_error_rel is not None else "-"
        mem = f"{r.peak_rss_mb:,.0f}" if r.peak_rss_mb is not None else "-"
        kp = f"{r.mean_keypoints:,.0f}" if r.mean_keypoints is not None else "not recorded"
        status = status_text(r) + (f" ({r.reason})" if r.reason else "")
        if ok and r.segments > 1:
            status += f" (resumed: {r.segments} segments)"
        lines.append(f"| {LABELS[name]} | {status} | {reg} | {table_cell(r, 'accuracy_px')} | {table_cell(r, 'efficiency_min')} "
                     f"| {table_cell(r, 'tie_points')} | {table_cell(r, 'reprojected_px')} | {rot} | {cen} | {mem} | {kp} |")
    lines += ["", "Stage runtimes (s):", ""]
    for name in METHODS:
        r = m.get(name)
        if r and r.stages_s:
            lines.append(f"- {LABELS[name]}: " + ", ".join(f"{k} {v:.1f}" for k, v in r.stages_s.items()))
    v = verdicts(table)
    lines += ["", f"Scorecard on this twin (single-run rules, polar vs Euclidean BA): C4 (faster): {v.c4}; "
              f"C5 (more tie points and reprojected px): {v.c5}.", ""]
    prov = records.to_dict(table.provenance) if table.provenance is not None else {}
    if prov:
        lines += ["Provenance: " + ", ".join(f"{k} {v}" for k, v in sorted(prov.items())
                                            if k not in ("environment", "stages")), ""]
    stages = table.provenance.stages if table.provenance is not None else {}
    if stages:
        lines += ["Code per stage (git commit of the run that finished it): "
                  + "; ".join(f"{k} {stage_commit(v)}" for k, v in sorted(stages.items())) + ".", ""]
    return "\n".join(lines)


def stage_commit(rec: HasCommit) -> str:
    """``abc1234567`` / ``... (dirty)`` from a stage record (or its provenance entry); "not recorded"
    for records written before stages kept their commit."""
    commit = rec.git_commit or ""
    if not commit:
        return "not recorded"
    dirty = rec.git_dirty
    return commit[:10] + (" (dirty)" if dirty else " (dirty: unknown)" if dirty is None else "")


def write_table(out_dir: str | os.PathLike, table: TwinTable) -> None:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write(out / "paper-table.json", json.dumps(table.to_dict(), indent=1) + "\n")
    atomic_write(out / "paper-table.md", render_table(table) + "\n")


def paper_cell(v, row: str) -> str:
    return f"{v:g}" if row in ("accuracy_px", "efficiency_min") else _fmt(row, v)  # as printed


def load_tables(root: str | os.PathLike) -> list[TwinTable]:
    """The tables of the twins under ``root`` (``root/<twin>/paper-table.json``), in PAPER order;
    a twin without a table is left out."""
    files = [Path(root) / twin / "paper-table.json" for twin in PAPER]
    return [TwinTable.from_dict(json.loads(f.read_text())) for f in files if f.is_file()]


def table_of(tables: list[TwinTable], twin: str) -> TwinTable | None:
    """The table of ``twin`` among ``tables`` (None: not there)."""
    return next((t for t in tables if t.twin == twin), None)
