"""``report.md`` and ``report.html`` from ``metrics.json`` alone (no recomputation).

Answer first: a summary (scene, the main paper-format table, one badge and one short line per
claim, runtime, commit), then figures and the 3D view, then the details (collapsible in HTML):
claims, all comparisons, methods, ground-truth accuracy, notes, environment. Both files come
from one list of blocks (:mod:`polarref.compare.report.render`). Every number is formatted from
the :class:`~polarref.compare.schema.MetricsFile`; the only date shown is the one stored in it.
Figures are redrawn from the same data, written to ``figures/`` and embedded in the HTML as
base64, and the 3D view's data and script are inlined, so the page works offline from one file.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

from polarref.compare.report import figures as figs
from polarref.compare.report import view3d
from polarref.compare.report.dense_section import dense_blocks, draw_dense_figure
from polarref.compare.report.render import (Badge, Badges, Bullets, Details, Fig, Heading, Para, RawHtml,
                                            Section, Table, WrittenPages, to_html, to_markdown)
from polarref.compare.schema import (ClaimResult, MethodPair, MethodResult, MetricsFile, load, write_text_atomic)
from polarref.compare.claims.thresholds import EQUIVALENT_PX, EQUIVALENT_REL
from polarref.core.status import RunStatus

# Bumped when the page's structure changes, so a committed example built by an older layout is
# recognised (and regenerated) instead of being diffed against the new one.
REPORT_LAYOUT = 2



# ---- number formatting (the one place numbers become text) -------------------------------

def fmt(value, digits: int = 3, unit: str = "") -> str:
    if value is None:
        return "n/a"
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, int):
        s = f"{value:,}"
    else:
        v = float(value)
        if v != 0 and (abs(v) < 10 ** -(digits) or abs(v) >= 1e6):
            s = f"{v:.{digits}g}" if abs(v) >= 1e6 else f"{v:.2e}"
        else:
            s = f"{v:.{digits}f}"
    return f"{s} {unit}".strip() if unit else s


def fmt_figure(value, unit: str) -> str:
    """A scorecard figure: counts as integers, 0 as 0, tiny values in e-notation."""
    if value is None:
        return "n/a"
    if unit == "count":
        return f"{int(round(value)):,}"
    if value == 0:
        return f"0 {unit}".strip()
    return fmt(value, 4, unit)


def fmt_s(value) -> str:
    return "n/a" if value is None else f"{float(value):.2f} s"


# ---- paper-format tables ----------------------------------------------------------------------

def improving_accuracy(base: float | None, cand: float | None) -> str:
    if base is None or cand is None:
        return "n/a"
    diff = base - cand
    if abs(diff) <= max(EQUIVALENT_PX, EQUIVALENT_REL * max(abs(base), abs(cand))):
        return "Equivalent"
    return f"↑ {fmt(diff)} px better" if diff > 0 else f"↓ {fmt(-diff)} px worse"


def improving_runtime(base: float | None, cand: float | None) -> str:
    if base is None or cand is None or base <= 0 or cand <= 0:
        return "n/a"
    diff = base - cand
    ratio = base / cand
    if diff >= 0:
        return f"↑ {fmt(diff, 2)} s (×{ratio:.2f})"
    return f"↓ {fmt(-diff, 2)} s slower (×{ratio:.2f})"


def improving_count(base: int | None, cand: int | None) -> str:
    if base is None or cand is None:
        return "n/a"
    diff = cand - base
    if diff == 0:
        return "equal"
    return f"↑ {diff:,}" if diff > 0 else f"↓ {-diff:,}"


def _cell(m: MethodResult, value: str) -> str:
    return value if m.status == RunStatus.OK else f"{m.status}"


def pair_table(pair: MethodPair, base: MethodResult, cand: MethodResult) -> Table:
    ok = base.status == RunStatus.OK and cand.status == RunStatus.OK
    b, c = base.metric, cand.metric
    err, tp, rp, reg = ("mean_reprojection_error_px", "tie_points", "reprojected_px", "registered_images")
    rows = [
        ["Accuracy (px)", _cell(base, fmt(b(err))), _cell(cand, fmt(c(err))),
         improving_accuracy(b(err), c(err)) if ok else "n/a"],
        ["Efficiency (s)", _cell(base, fmt(base.runtime_s, 2)), _cell(cand, fmt(cand.runtime_s, 2)),
         improving_runtime(base.runtime_s, cand.runtime_s) if ok else "n/a"],
        ["#Tie point", _cell(base, fmt(b(tp))), _cell(cand, fmt(c(tp))), improving_count(b(tp), c(tp)) if ok else "n/a"],
        ["#Reprojected px", _cell(base, fmt(b(rp))), _cell(cand, fmt(c(rp))),
         improving_count(b(rp), c(rp)) if ok else "n/a"],
        ["Registered images", _cell(base, f"{fmt(b(reg))} / {base.num_images}"),
         _cell(cand, f"{fmt(c(reg))} / {cand.num_images}"), improving_count(b(reg), c(reg)) if ok else "n/a"],
    ]
    if base.gt is not None or cand.gt is not None:
        rb = base.gt.rotation_error_deg_mean if base.gt else None
        rc = cand.gt.rotation_error_deg_mean if cand.gt else None
        imp = "n/a" if (rb is None or rc is None or not ok) else (
            f"↑ {fmt(rb - rc, 4)}°" if rc < rb else (f"↓ {fmt(rc - rb, 4)}°" if rc > rb else "equal"))
        rows.append(["GT rotation error, mean (deg)", _cell(base, fmt(rb, 4)), _cell(cand, fmt(rc, 4)), imp])
    return Table(["Indicators", base.label, cand.label, "Improving"], rows)


# ---- sections -----------------------------------------------------------------------------------

def _methods_section(m: MetricsFile) -> list:
    rows = []
    for r in m.methods:
        reason = r.reason.replace("|", "/").replace("\n", " ") if r.reason else ""
        rows.append([f"`{r.name}`", r.label, r.status,
                     f"{fmt(r.metric('registered_images'))} / {r.num_images}", fmt(r.metric("tie_points")),
                     fmt(r.metric("reprojected_px")), fmt(r.metric("mean_reprojection_error_px")),
                     fmt(r.metric("mean_reprojection_error_px_per_point")),
                     fmt_s(r.runtime_s), fmt_s(r.timeout_s), reason or "—"])
    return [Para("All methods run on the same images with the same fixed intrinsics, one after another "
                 "(never in parallel, so runtimes are comparable), each in its own process with a "
                 f"time limit of at most {fmt(m.environment.method_timeout_s, 0)} s (less when the run's "
                 "time budget runs short; see the limit column). "
                 "`features`: who detected and matched; `mapper`: who built the reconstruction. "
                 "Mean reprojection error is per observation; COLMAP's own figure averages per point."),
            Table(["key", "method", "status", "registered", "#tie points", "#reprojected px",
                   "mean reproj. (px)", "per-point mean (px)", "runtime", "limit", "failure reason"], rows),
            Table(["key", "features", "mapper", "BA"],
                  [[f"`{r.name}`", r.features, r.mapper, r.ba] for r in m.methods])]


_PAIRS_NOTE = (f"Accuracy is the mean reprojection error over all observations of all tie points; "
               f"\"Equivalent\" means the two differ by at most {EQUIVALENT_PX} px or {EQUIVALENT_REL:.0%}. "
               "Efficiency is the wall time of the whole method (features to final bundle adjustment); "
               "×r is baseline/candidate.")


def _pairs_blocks(m: MetricsFile) -> list:
    out: list = [Para(_PAIRS_NOTE)]
    for pair in m.pairs:
        base, cand = m.method(pair.baseline), m.method(pair.candidate)
        if base is None or cand is None:
            continue
        out.append(Heading(3, pair.title))
        if pair.note:
            out.append(Para(pair.note))
        out.append(pair_table(pair, base, cand))
    return out


def _gt_section(m: MetricsFile) -> list:
    rows = []
    for r in m.methods:
        g = r.gt
        if r.status != RunStatus.OK or g is None:
            continue
        rows.append([r.label, f"{g.aligned_images}", fmt(g.rotation_error_deg_mean, 4),
                     fmt(g.rotation_error_deg_median, 4), fmt(g.rotation_error_deg_max, 4),
                     fmt(g.center_error_mean, 4), fmt(100 * g.center_error_rel_mean, 3) + " %",
                     fmt(g.point_to_surface_median, 4), fmt(g.point_to_surface_p90, 4),
                     fmt(g.points_scored)])
    if not rows:
        return [Para("No ground truth for this scene, or no method succeeded.")]
    return [Para(f"Each estimate is aligned to the ground truth by a Sim3 (`polarref.metrics`: Umeyama on camera "
                 f"centres, rotations first when they are near-collinear), then scored. Scene size (RMS "
                 f"distance of GT camera centres from their centroid): {fmt(m.scene.scene_extent, 4)} scene "
                 "units; centre errors and point-to-surface distances are in scene units."),
            Table(["method", "aligned images", "rot. mean (deg)", "rot. median", "rot. max",
                   "centre mean", "centre / scene size", "pt-to-surface median", "pt-to-surface p90",
                   "points scored"], rows)]


class _Figures(dict):
    def __missing__(self, key):  # an unknown placeholder stays visible instead of crashing
        return "{" + key + "}"


def _fill(template: str, c: ClaimResult) -> str:
    values = _Figures({f.key: fmt_figure(f.value, f.unit) for f in c.figures})
    try:
        return template.format_map(values)
    except (ValueError, IndexError):
        return template


def render_rationale(c: ClaimResult) -> str:
    return _fill(c.rationale, c)


SHORT_LINE_CHARS = 120


def first_clause(text: str, limit: int = SHORT_LINE_CHARS) -> str:
    """Text up to the first top-level ';' or sentence end, cut at a word to ``limit`` chars with '…'."""
    depth, end = 0, len(text)
    for i, ch in enumerate(text):
        if ch in "([":
            depth += 1
        elif ch in ")]":
            depth = max(0, depth - 1)
        elif depth == 0 and (ch == ";" or (ch == "." and text[i + 1:i + 2] == " "
                                          and text[i + 2:i + 3][:1].isupper())):
            end = i
            break
    line = text[:end].strip().rstrip(":,")
    if len(line) > limit:
        cut = line.rfind(" ", 0, limit - 1)
        line = line[:cut if cut > limit // 2 else limit - 1].rstrip(" ,;:(") + "…"
    return line


def short_line(c: ClaimResult) -> str:
    """One line for the summary and the scorecard: the claim's own summary, else its rationale's first clause."""
    summary = getattr(c, "summary", "")
    return first_clause(_fill(summary, c) if summary else render_rationale(c))


def _claims_blocks(m: MetricsFile) -> list:
    if not m.claims:
        return [Para("No claim experiments were run.")]
    out: list = [Para("Each claim of the paper (Tables 1-3 and Discussion 4.1), the test we ran and our verdict "
                      "(*supported*, *not supported*, *inconclusive*; *not tested* means the experiment could not "
                      "run here). Open a claim for its test, every measured figure and the full reasoning."),
                 Table(["#", "claim", "verdict", "measured (short; details below)", "sample size"],
                       [[c.claim_id, c.claim, f"**{c.verdict}**", short_line(c), c.sample_size] for c in m.claims])]
    for c in m.claims:
        out.append(Details(f"{c.claim_id}. {c.claim} — {c.verdict}", [
            Para(f"Source: {c.source}. Test: {c.test}"),
            Table(["figure", "value"], [[f.label, fmt_figure(f.value, f.unit)] for f in c.figures])
            if c.figures else Para("No figures measured."),
            Para(f"Verdict: **{c.verdict}** ({c.sample_size}). {render_rationale(c)}")]))
    return out


def _flat(prefix: str, value) -> list[tuple[str, str]]:
    if dataclasses.is_dataclass(value):
        value = dataclasses.asdict(value)
    if isinstance(value, dict):
        return [kv for k, v in sorted(value.items()) for kv in _flat(f"{prefix}.{k}" if prefix else str(k), v)]
    if isinstance(value, (list, tuple)):
        return [(prefix, ", ".join(map(str, value)))]
    return [(prefix, "n/a" if value is None else str(value))]


def environment_items(m: MetricsFile) -> list[tuple[str, str]]:
    """Every field of the stored environment, nested records flattened to ``a.b`` keys, in field order."""
    e = m.environment
    return [kv for f in dataclasses.fields(e) for kv in _flat(f.name, getattr(e, f.name))]


def commit_text(m: MetricsFile) -> str:
    """``abc1234`` / ``abc1234 (dirty)`` from any stored ``git_commit`` / ``git_dirty`` field, else n/a."""
    items = dict(environment_items(m))
    key = next((k for k, v in items.items() if k.split(".")[-1] == "git_commit" and v not in ("", "n/a")), None)
    if key is None:
        return "n/a"
    dirty = items.get(key[:-len("git_commit")] + "git_dirty", "False")   # the flag beside that commit
    return items[key][:10] + (" (dirty)" if dirty == "True" else "")


def _env_section(m: MetricsFile) -> list:
    rows = []
    for key, value in environment_items(m):
        if key in ("method_timeout_s", "total_runtime_s", "run_budget_s") and value != "n/a":
            value = fmt_s(float(value))
        rows.append([key, f"`{value}`" if key == "command" else value])
    return [Table(["item", "value"], rows)]


def _scene_line(m: MetricsFile) -> str:
    s = m.scene
    cam = ", ".join(fmt(p, 3) for p in s.camera_params)
    return (f"{s.kind} scene, {s.num_images} images of {s.width}×{s.height} px"
            + (f" (downscaled ×{fmt(s.downscale, 2)} from the originals)" if s.downscale != 1.0 else "")
            + f"; camera {s.camera_model} ({cam}) held fixed for every method; "
            + ("ground truth: yes" if s.has_gt else "ground truth: none")
            + ("; GT mesh for point-to-surface errors: yes" if s.has_mesh else "")
            + f". Source: `{s.source}`" + (f", preset `{s.preset}`, seed {s.seed}" if s.preset else "") + ".")


def _summary(m: MetricsFile) -> Section:
    e = m.environment
    ok = sum(r.status == RunStatus.OK for r in m.methods)
    blocks: list = [Para(f"**{m.scene.name}**: {m.scene.num_images} images · {ok}/{len(m.methods)} methods "
                         f"succeeded · total runtime {fmt_s(e.total_runtime_s)} · commit `{commit_text(m)}` · "
                         f"run {e.created[:10]}")]
    main = next((p for p in m.pairs if m.method(p.baseline) and m.method(p.candidate)), None)
    if main is not None:
        blocks += [Heading(3, f"Main comparison: {main.title}"),
                   pair_table(main, m.method(main.baseline), m.method(main.candidate))]
    if m.claims:
        blocks += [Heading(3, "Verdicts on the paper's claims"),
                   Badges([Badge(c.claim_id, c.verdict, c.claim, short_line(c)) for c in m.claims])]
    return Section("summary", blocks)


def _view_blocks(m: MetricsFile) -> list:
    v = m.view3d
    if v is None or not (v.clouds or len(v.cameras) > 1):
        return []
    main = next(iter(m.pairs), None)
    on = {"gt", "gt-surface"} | ({main.baseline, main.candidate} if main else {r.name for r in m.methods[:2]})
    on |= {c.key for c in v.clouds if c.kind == "dense"}
    colors = {"gt": "#000000", "gt-surface": "#b0b0b0"}
    colors.update({r.name: figs.COLORS[k % len(figs.COLORS)] for k, r in enumerate(m.methods)})
    data_note = view3d.describe(v)
    return [Heading(3, "3D view (drag: orbit, wheel: zoom, shift-drag: pan, double-click: reset)"),
            RawHtml(view3d.to_html(v, colors, sorted(on)), "*Interactive 3D view of the sparse points and camera "
                    "frusta (GT vs each method, Sim3-aligned): open `report.html`.*"),
            Para("Estimates are mapped into the ground-truth frame by the same Sim3 as the scores; frusta are "
                 "the fixed camera's field of view. " + data_note)]


def build_blocks(m: MetricsFile, figure_keys: set[str]) -> list:
    blocks: list = [Heading(1, f"polarref compare: {m.scene.name}"), Para(_scene_line(m)), _summary(m),
                    Heading(2, "Figures")]
    blocks += _view_blocks(m)
    for key, caption, _ in figs.FIGURES:
        if key in figure_keys:
            blocks.append(Fig(key, caption))
    blocks += dense_blocks(m, figure_keys)
    blocks += [Heading(2, "Claims in detail"), *_claims_blocks(m),
               Heading(2, "Details"),
               Details("All paper-format comparisons (Tables 1-3 layout)", _pairs_blocks(m)),
               Details("Methods: status, counts, runtimes, failures", _methods_section(m)),
               Details("Ground-truth accuracy", _gt_section(m))]
    if m.notes:
        blocks.append(Details("Notes", [Bullets(list(m.notes))]))
    blocks.append(Details("Environment (provenance)", _env_section(m)))
    blocks.append(Para("Generated by `polarref compare`; rebuild with `polarref report DIR` "
                       "(every number is read from `metrics.json`)."))
    return blocks


def build_report(out_dir: str | Path, metrics: MetricsFile | None = None) -> WrittenPages:
    """(Re)draw figures and write report.md / report.html in ``out_dir`` from its metrics.json.

    Files other than these (models, logs, user notes) are left alone.
    """
    out_dir = Path(out_dir)
    if metrics is None:
        metrics = load(out_dir / "metrics.json")
    fig_dir = out_dir / "figures"
    drawn = figs.draw_all(metrics, fig_dir)
    try:
        dense = draw_dense_figure(metrics, out_dir, fig_dir)
    except Exception as exc:  # a broken plot must not lose the tables
        logging.getLogger(__name__).warning("figure dense failed: %s: %s", type(exc).__name__, exc)
        dense = None
    drawn += [dense] if dense is not None else []
    blocks = build_blocks(metrics, {f.key for f in drawn})
    md, page = out_dir / "report.md", out_dir / "report.html"
    write_text_atomic(md, to_markdown(blocks))
    write_text_atomic(page, to_html(blocks, fig_dir, f"polarref compare: {metrics.scene.name}", REPORT_LAYOUT))
    return WrittenPages(md, page, tuple(drawn))
