"""What changed with scale: each twin beside the committed small-scene reports of its scene class,
and issue 13's done-when checks per twin (a generated part of ``reports/paper-tables/README.md``).

Every value is read: the twin's from its ``paper-table.json``, a small scene's from its committed
``metrics.json`` (:mod:`polarref.compare.schema`). Both sides are judged by the same single-run
rules (:mod:`polarref.compare.claims.single_run`). A missing value is "not tested", never 0.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from polarref.compare.twins import tables as PT
from polarref.compare.claims import single_run
from polarref.compare.schema import MetricsFile, load
from polarref.compare.claims.thresholds import TWIN_REGISTERED_MIN, TWIN_ROSETTA_MIN_TIES, TWIN_RUNTIME_TARGET_MIN
from polarref.core.errors import PolarrefError
from polarref.core.status import RunStatus

NOT_TESTED = PT.NOT_TESTED
PYCOLMAP = "pycolmap-incremental-sift"
# The committed small-scene reports of each twin's scene class (folders under reports/).
SMALL_REPORTS = {"comet": ("comet-small", "comet-default"), "uav": ("uav-small", "uav-default")}
TWIN_CLASS = {"rosetta": "comet", "poets-park": "uav", "mappilot": "uav"}


@dataclass
class ScaleColumn:
    """One scene's figures in the "what changed with scale" table (None: not measured)."""

    label: str
    c4: str                           # single-run rule, polar vs Euclidean
    c5: str
    scorecard: str                    # the report's own C4 / C5 verdicts ("" for a twin: single run only)
    time_ratio: float | None          # whole method, ours-polar / ours-euclidean
    tie_ratio: float | None           # tie points, ours-polar / pycolmap incremental
    rot_ours: float | None            # GT rotation error (deg, mean), ours-polar
    rot_pycolmap: float | None
    reg_ours: float | None            # registered fraction of the views
    reg_pycolmap: float | None


def _frac(registered: int | None, images: int) -> float | None:
    return None if registered is None or images <= 0 else registered / images


def twin_column(table: PT.TwinTable) -> ScaleColumn:
    m = table.methods
    ok = {k: r for k, r in m.items() if r.status == RunStatus.OK}
    base, ours, col = ok.get(PT.BASELINE), ok.get(PT.OURS), ok.get(PYCOLMAP)
    v = PT.verdicts(table)
    return ScaleColumn(
        f"twin `{table.twin}` ({table.images} views)", v.c4.verdict, v.c5.verdict, "",
        single_run.ratio(ours and ours.efficiency_min, base and base.efficiency_min),
        single_run.ratio(ours and ours.tie_points, col and col.tie_points),
        ours and ours.rotation_error_deg, col and col.rotation_error_deg,
        _frac(ours and ours.registered, table.images), _frac(col and col.registered, table.images))


def metrics_column(name: str, mf: MetricsFile) -> ScaleColumn:
    def ok(n):
        r = mf.method(n)
        return r if r is not None and r.status == RunStatus.OK else None

    base, ours, col = ok(PT.BASELINE), ok(PT.OURS), ok(PYCOLMAP)
    c4 = single_run.speedup_verdict(base.runtime_s, ours.runtime_s)[0] if base and ours else NOT_TESTED
    c5 = (single_run.more_counts_verdict(ours.metric("tie_points"), base.metric("tie_points"),
                                         ours.metric("reprojected_px"), base.metric("reprojected_px"))
          if base and ours else NOT_TESTED)
    card = {c.claim_id: c.verdict for c in mf.claims}
    n = mf.scene.num_images
    return ScaleColumn(
        f"`{name}` ({n} views)", c4, c5, f"{card.get('C4', NOT_TESTED)} / {card.get('C5', NOT_TESTED)}",
        single_run.ratio(ours and ours.runtime_s, base and base.runtime_s),
        single_run.ratio(ours and ours.metric("tie_points"), col and col.metric("tie_points")),
        ours.gt.rotation_error_deg_mean if ours and ours.gt else None,
        col.gt.rotation_error_deg_mean if col and col.gt else None,
        _frac(ours and ours.metric("registered_images"), n), _frac(col and col.metric("registered_images"), n))


def small_columns(twin: str, reports_root: Path | None) -> tuple[list[ScaleColumn], list[str]]:
    """The committed small-scene reports of the twin's class; notes for absent / unreadable ones."""
    names = SMALL_REPORTS[TWIN_CLASS[twin]]
    cols, notes = [], []
    for name in names:
        f = None if reports_root is None else Path(reports_root) / name / "metrics.json"
        if f is None or not f.is_file():
            continue
        try:
            cols.append(metrics_column(name, load(f)))
        except PolarrefError as exc:
            notes.append(f"`{name}` unreadable ({exc}): not tested")
    if not cols and not notes:
        notes.append(f"no committed small-scene report of the {TWIN_CLASS[twin]} class "
                     f"({', '.join(f'reports/{n}' for n in names)}): not tested")
    return cols, notes


def _x(v: float | None) -> str:
    return NOT_TESTED if v is None else f"x{v:.2f}"


def _deg(v: float | None) -> str:
    return NOT_TESTED if v is None else f"{v:.3f}"


def _pct(v: float | None) -> str:
    return NOT_TESTED if v is None else f"{100 * v:.1f}%"


def _with_scale(twin_value: str, small: list[str]) -> str:
    if twin_value == NOT_TESTED or not small or NOT_TESTED in small:
        return NOT_TESTED
    if all(s == twin_value for s in small):
        return "unchanged"
    return "changed (small: " + ", ".join(small) + f"; twin: {twin_value})"


def scale_table(twin: ScaleColumn, small: list[ScaleColumn]) -> list[str]:
    cols = [twin, *small]
    rows = [("C4, single-run rule (polar vs Euclidean)", [c.c4 for c in cols], True),
            ("C5, single-run rule (polar vs Euclidean)", [c.c5 for c in cols], True),
            ("C4 / C5 in the report's scorecard (controlled experiments decide where they ran)",
             ["— (one run only)"] + [c.scorecard for c in small], False),
            ("whole-method time, ours-polar / ours-euclidean", [_x(c.time_ratio) for c in cols], False),
            ("tie points, ours-polar / pycolmap incremental", [_x(c.tie_ratio) for c in cols], False),
            ("GT rotation error (deg), ours-polar vs pycolmap incremental",
             [f"{_deg(c.rot_ours)} vs {_deg(c.rot_pycolmap)}" for c in cols], False),
            ("registered views, ours-polar / pycolmap incremental",
             [f"{_pct(c.reg_ours)} / {_pct(c.reg_pycolmap)}" for c in cols], False)]
    lines = ["| | " + " | ".join(c.label for c in cols) + " | with scale |",
             "|---" * (len(cols) + 2) + "|"]
    for label, values, judged in rows:
        lines.append(f"| {label} | " + " | ".join(values) + " | "
                     + (_with_scale(values[0], values[1:]) if judged else "—") + " |")
    return lines


# ---- issue 13's done-when, per twin ------------------------------------------------------------

def _judge(parts: list[tuple[str, bool | None]]) -> str:
    """met when every part is measured and passes; not met when one fails; else not tested."""
    if any(p is False for _, p in parts):
        return "not met"
    if not parts or any(p is None for _, p in parts):
        return NOT_TESTED
    return "met"


def _measured(r: PT.TwinRow | None) -> bool | None:
    """None: not run (not tested); False: ran and failed or timed out; True: a result."""
    if PT.status_text(r) == PT.NOT_RUN:
        return None
    return r.status == RunStatus.OK


def done_when(table: PT.TwinTable) -> list[str]:
    """The checks of the issue's done-when on one twin, each "met" / "not met" / "not tested"."""
    m, n = table.methods, table.images
    ours = [(k, m.get(k)) for k in (PT.BASELINE, PT.OURS)]
    reg = []
    for k, r in ours:
        ran = _measured(r)
        ok = None if ran is None or (ran and r.registered is None) else (ran and r.registered >= TWIN_REGISTERED_MIN * n)
        reg.append((f"{k} {r.registered}/{n}" if ran and r.registered is not None else f"{k} {PT.status_text(r)}", ok))
    lines = [f"- ours registers >= {TWIN_REGISTERED_MIN:.0%} of the views: "
             + ", ".join(t for t, _ in reg) + f": **{_judge(reg)}**"]
    if table.twin == "rosetta":
        ties = []
        for k, r in ours:
            ran = _measured(r)
            ok = None if ran is None or (ran and r.tie_points is None) else (ran and r.tie_points >= TWIN_ROSETTA_MIN_TIES)
            ties.append((f"{k} {r.tie_points:,}" if ran and r.tie_points is not None
                         else f"{k} {PT.status_text(r)}", ok))
        lines.append(f"- ours yields >= {TWIN_ROSETTA_MIN_TIES:,} tie points: "
                     + ", ".join(t for t, _ in ties) + f": **{_judge(ties)}**")
    times = []
    for k in PT.METHODS:
        r = m.get(k)
        ran = _measured(r)
        ok = None if ran is None or (ran and r.efficiency_min is None) else (ran and r.efficiency_min <= TWIN_RUNTIME_TARGET_MIN)
        times.append((f"{k} {r.efficiency_min:.1f} min" if ran and r.efficiency_min is not None
                      else f"{k} {PT.status_text(r)}", ok))
    lines.append(f"- runtime per method, render excluded, <= {TWIN_RUNTIME_TARGET_MIN:.0f} min: "
                 + ", ".join(t for t, _ in times) + f": **{_judge(times)}**")
    return lines


@dataclass(frozen=True)
class VariantScores:
    """The figures of one side of a pipeline-variant record."""

    registered: int
    tie_points: int
    mean_reprojection_error_px: float


@dataclass(frozen=True)
class PipelineVariant:
    """A ``variant-*.json`` record of scripts/twin_variant.py (the part the README shows)."""

    method: str
    images: int
    variant_settings: dict[str, str]      # setting -> value as written
    baseline_settings: dict[str, str]
    variant: VariantScores
    baseline: VariantScores
    tie_point_target: int | None
    git_commit: str                   # "" when the record has no provenance


def _scores_from_json(d: dict) -> VariantScores:
    return VariantScores(int(d["registered"]), int(d["tie_points"]), float(d["mean_reprojection_error_px"]))


def variant_from_json(v: dict) -> PipelineVariant:
    """The record from its parsed JSON (KeyError / TypeError / ValueError when it is not one)."""
    target = v.get("tie_point_target")
    return PipelineVariant(str(v["method"]), int(v["images"]), {k: str(x) for k, x in v["variant_settings"].items()},
                           {k: str(x) for k, x in v["baseline_settings"].items()}, _scores_from_json(v["variant"]),
                           _scores_from_json(v["baseline"]), None if target is None else int(target),
                           str((v.get("provenance") or {}).get("git_commit") or ""))


def _variant_line(v: PipelineVariant, name: str) -> str:
    settings = ", ".join(f"{k} = {x}" for k, x in v.variant_settings.items())
    tables = ", ".join(f"{k} = {x}" for k, x in v.baseline_settings.items())
    commit = v.git_commit[:7] or "not recorded"
    var, base = v.variant, v.baseline
    line = (f"- variant of {v.method} with {settings} (`{name}`, commit {commit}): "
            f"{var.registered}/{v.images} registered, {var.tie_points:,} tie points, "
            f"{var.mean_reprojection_error_px:.3f} px (tables' {tables}: {base.tie_points:,}, "
            f"{base.mean_reprojection_error_px:.3f} px)")
    if v.tie_point_target is not None:
        met = "met" if var.tie_points >= v.tie_point_target else "not met"
        line += f"; >= {v.tie_point_target:,} tie points: **{met}**"
    return line


def variant_lines(twin_dir: str | os.PathLike) -> list[str]:
    """One line per committed pipeline variant of an ours method (``variant-*.json`` beside the
    twin's table, written by scripts/twin_variant.py): its tie points against the twin's target,
    beside the tables' own setting. The done-when line above stays on the tables' setting: a
    variant meeting the target is reported as a variant, not folded into the table."""
    lines = []
    for f in sorted(Path(twin_dir).glob("variant-*.json")):
        try:
            lines.append(_variant_line(variant_from_json(json.loads(f.read_text())), f.name))
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
            raise PolarrefError(f"{f}: not a pipeline-variant record ({type(e).__name__}: {e})") from None
    return lines


def has_results(table: PT.TwinTable | None) -> bool:
    return table is not None and any(PT.status_text(r) != PT.NOT_RUN for r in table.methods.values())


def render_scale(tables: list[PT.TwinTable], reports_root: str | os.PathLike | None,
                 tables_root: str | os.PathLike | None = None) -> list[str]:
    """Markdown lines of the README's "What changed with scale" section (``tables_root``: where
    each twin's folder may hold pipeline-variant records, see :func:`variant_lines`)."""
    lines = ["## What changed with scale", "",
             "Each twin with results beside the committed small-scene reports of its scene class, judged by "
             "the same single-run rules (C4: whole-method speed-up Euclidean/polar >= "
             f"x{single_run.SUPPORTED_AT:.2f} supported, < x{single_run.NOT_SUPPORTED_BELOW:.2f} not supported; "
             "C5: more tie points and more reprojected px than the Euclidean baseline by more than the "
             "scorecard's margin). A twin's whole-method time is the sum of its stage processes' wall times "
             "(the shared feature and matching stage counted for each method, render excluded); a small scene's "
             "is the method's runtime in its metrics.json. Timings on a shared, loaded 2-core machine: one run "
             "each.", ""]
    shown = [t for t in (PT.table_of(tables, twin) for twin in PT.PAPER) if t is not None and has_results(t)]
    if not shown:
        return lines + ["No twin has results yet: not tested.", ""]
    for table in shown:
        twin = table.twin
        small, notes = small_columns(twin, None if reports_root is None else Path(reports_root))
        lines += [f"### `{twin}`", "", *scale_table(twin_column(table), small), ""]
        if notes:
            lines += ["Small scenes: " + "; ".join(notes) + ".", ""]
        lines += ["Done-when checks of issue 13:", "", *done_when(table), ""]
        variants = variant_lines(Path(tables_root) / twin) if tables_root is not None else []
        if variants:
            lines += ["Pipeline variants of ours on this twin (not the tables' setting):", "", *variants, ""]
    return lines
