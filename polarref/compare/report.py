"""``report.md`` and ``report.html`` from ``metrics.json`` alone (no recomputation).

Both files come from one list of blocks, so Markdown and HTML always say the same thing.
Every number is formatted from the :class:`~polarref.compare.schema.MetricsFile`; the only
date shown is the one stored in it. Figures are redrawn from the same data, written beside
the reports in ``figures/`` and embedded in the HTML as base64 so the page is self-contained.
"""

from __future__ import annotations

import base64
import html
import logging
import re
from dataclasses import dataclass
from pathlib import Path

from polarref.compare import figures as figs
from polarref.compare.dense_section import dense_blocks, draw_dense_figure
from polarref.compare.schema import (STATUS_OK, ClaimResult, MethodPair, MethodResult,
                                     MetricsFile, load, write_text_atomic)

# "Equivalent" accuracy in the paper's table: 0.482 vs 0.481 px. We call two mean reprojection
# errors equivalent when they differ by at most this many px or this fraction, whichever is larger.
EQUIVALENT_PX = 0.01
EQUIVALENT_REL = 0.02


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


# ---- document model -------------------------------------------------------------------------

@dataclass
class Heading:
    level: int
    text: str


@dataclass
class Para:
    text: str          # may contain **bold** and `code`


@dataclass
class Table:
    header: list[str]
    rows: list[list[str]]


@dataclass
class Fig:
    key: str
    caption: str


@dataclass
class Bullets:
    items: list[str]


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
    return value if m.status == STATUS_OK else f"{m.status}"


def pair_table(pair: MethodPair, base: MethodResult, cand: MethodResult) -> Table:
    ok = base.status == STATUS_OK and cand.status == STATUS_OK
    rows = [
        ["Accuracy (px)", _cell(base, fmt(base.mean_reprojection_error_px)),
         _cell(cand, fmt(cand.mean_reprojection_error_px)),
         improving_accuracy(base.mean_reprojection_error_px, cand.mean_reprojection_error_px) if ok else "n/a"],
        ["Efficiency (s)", _cell(base, fmt(base.runtime_s, 2)), _cell(cand, fmt(cand.runtime_s, 2)),
         improving_runtime(base.runtime_s, cand.runtime_s) if ok else "n/a"],
        ["#Tie point", _cell(base, fmt(base.tie_points)), _cell(cand, fmt(cand.tie_points)),
         improving_count(base.tie_points, cand.tie_points) if ok else "n/a"],
        ["#Reprojected px", _cell(base, fmt(base.reprojected_px)), _cell(cand, fmt(cand.reprojected_px)),
         improving_count(base.reprojected_px, cand.reprojected_px) if ok else "n/a"],
        ["Registered images", _cell(base, f"{fmt(base.registered_images)} / {base.num_images}"),
         _cell(cand, f"{fmt(cand.registered_images)} / {cand.num_images}"),
         improving_count(base.registered_images, cand.registered_images) if ok else "n/a"],
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
                     f"{fmt(r.registered_images)} / {r.num_images}", fmt(r.tie_points), fmt(r.reprojected_px),
                     fmt(r.mean_reprojection_error_px), fmt(r.mean_reprojection_error_per_point_px),
                     fmt_s(r.runtime_s), fmt_s(r.timeout_s), reason or "—"])
    return [Heading(2, "Methods"),
            Para("All methods run on the same images with the same fixed intrinsics, one after another "
                 "(never in parallel, so runtimes are comparable), each in its own process with a "
                 f"time limit of at most {fmt(m.environment.method_timeout_s, 0)} s (less when the run's "
                 "time budget runs short; see the limit column). "
                 "`features`: who detected and matched; `mapper`: who built the reconstruction. "
                 "Mean reprojection error is per observation; COLMAP's own figure averages per point."),
            Table(["key", "method", "status", "registered", "#tie points", "#reprojected px",
                   "mean reproj. (px)", "per-point mean (px)", "runtime", "limit", "failure reason"], rows),
            Table(["key", "features", "mapper", "BA"],
                  [[f"`{r.name}`", r.features, r.mapper, r.ba] for r in m.methods])]


def _pairs_section(m: MetricsFile) -> list:
    out: list = [Heading(2, "Paper-format comparisons (Tables 1-3 layout)"),
                 Para(f"Accuracy is the mean reprojection error over all observations of all tie points; "
                      f"\"Equivalent\" means the two differ by at most {EQUIVALENT_PX} px or "
                      f"{EQUIVALENT_REL:.0%}. Efficiency is the wall time of the whole method "
                      "(features to final bundle adjustment); ×r is baseline/candidate.")]
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
        if r.status != STATUS_OK or g is None:
            continue
        rows.append([r.label, f"{g.aligned_images}", fmt(g.rotation_error_deg_mean, 4),
                     fmt(g.rotation_error_deg_median, 4), fmt(g.rotation_error_deg_max, 4),
                     fmt(g.center_error_mean, 4), fmt(100 * g.center_error_rel_mean, 3) + " %",
                     fmt(g.point_to_surface_median, 4), fmt(g.point_to_surface_p90, 4),
                     fmt(g.points_scored)])
    if not rows:
        return [Heading(2, "Ground-truth accuracy"), Para("No ground truth for this scene, or no method succeeded.")]
    return [Heading(2, "Ground-truth accuracy"),
            Para(f"Each estimate is aligned to the ground truth by a Sim3 (`polarref.metrics`: Umeyama on camera "
                 f"centres, rotations first when they are near-collinear), then scored. Scene size (RMS "
                 f"distance of GT camera centres from their centroid): {fmt(m.scene.scene_extent, 4)} scene "
                 "units; centre errors and point-to-surface distances are in scene units."),
            Table(["method", "aligned images", "rot. mean (deg)", "rot. median", "rot. max",
                   "centre mean", "centre / scene size", "pt-to-surface median", "pt-to-surface p90",
                   "points scored"], rows)]


def _claims_section(m: MetricsFile) -> list:
    if not m.claims:
        return [Heading(2, "Claims scorecard"), Para("No claim experiments were run.")]
    rows = [[c.claim_id, c.claim, f"**{c.verdict}**", render_rationale(c), c.sample_size] for c in m.claims]
    out: list = [Heading(2, "Claims scorecard"),
                 Para("Each claim of the paper (Tables 1-3 and Discussion 4.1), the test we ran, what we "
                      "measured and our verdict. Verdicts are *supported*, *not supported* or *inconclusive*; "
                      "*not tested* means the experiment could not run here (reason given)."),
                 Table(["#", "claim", "verdict", "measured (the verdict rests on these)", "sample size"], rows)]
    for c in m.claims:
        out += [Heading(3, f"{c.claim_id}. {c.claim}"),
                Para(f"Source: {c.source}. Test: {c.test}"),
                Table(["figure", "value"], [[f.label, fmt_figure(f.value, f.unit)] for f in c.figures])
                if c.figures else Para("No figures measured."),
                Para(f"Verdict: **{c.verdict}** ({c.sample_size}). {render_rationale(c)}")]
    return out


class _Figures(dict):
    def __missing__(self, key):  # an unknown placeholder stays visible instead of crashing
        return "{" + key + "}"


def render_rationale(c: ClaimResult) -> str:
    values = _Figures({f.key: fmt_figure(f.value, f.unit) for f in c.figures})
    try:
        return c.rationale.format_map(values)
    except (ValueError, IndexError):
        return c.rationale


def _env_section(m: MetricsFile) -> list:
    e = m.environment
    rows = [["command", f"`{e.command}`"], ["run date (stored)", e.created],
            ["CPU count", str(e.cpu_count)], ["Mitsuba variant", e.mitsuba_variant or "n/a"],
            ["preset", e.preset or "—"], ["seeds", ", ".join(f"{k}={v}" for k, v in sorted(e.seeds.items()))],
            ["per-method timeout", fmt_s(e.method_timeout_s)],
            ["run budget", "none" if e.run_budget_s is None else fmt_s(e.run_budget_s)],
            ["total runtime (rendering included)", fmt_s(e.total_runtime_s)]]
    rows += [[k, str(v)] for k, v in sorted(e.versions.items())]
    return [Heading(2, "Environment"), Table(["item", "value"], rows)]


def build_blocks(m: MetricsFile, figure_keys: set[str]) -> list:
    s = m.scene
    cam = ", ".join(fmt(p, 3) for p in s.camera_params)
    blocks: list = [
        Heading(1, f"polarref compare: {s.name}"),
        Para(f"{s.kind} scene, {s.num_images} images of {s.width}×{s.height} px"
             + (f" (downscaled ×{fmt(s.downscale, 2)} from the originals)" if s.downscale != 1.0 else "")
             + f"; camera {s.camera_model} ({cam}) held fixed for every method; "
             + ("ground truth: yes" if s.has_gt else "ground truth: none")
             + ("; GT mesh for point-to-surface errors: yes" if s.has_mesh else "")
             + f". Source: `{s.source}`" + (f", preset `{s.preset}`, seed {s.seed}" if s.preset else "") + "."),
        Para("Generated by `polarref compare`; rebuild with `polarref report DIR` "
             "(every number below is read from `metrics.json`)."),
    ]
    blocks += _claims_section(m)
    blocks += _pairs_section(m)
    blocks += _methods_section(m)
    blocks += _gt_section(m)
    blocks += dense_blocks(m, figure_keys)
    blocks.append(Heading(2, "Figures"))
    for key, caption, _ in figs.FIGURES:
        if key in figure_keys:
            blocks.append(Fig(key, caption))
    if m.notes:
        blocks += [Heading(2, "Notes"), Bullets(list(m.notes))]
    blocks += _env_section(m)
    return blocks


# ---- renderers -------------------------------------------------------------------------------

def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def to_markdown(blocks: list) -> str:
    out: list[str] = []
    for b in blocks:
        if isinstance(b, Heading):
            out.append("#" * b.level + " " + b.text)
        elif isinstance(b, Para):
            out.append(b.text)
        elif isinstance(b, Table):
            out.append("| " + " | ".join(_md_cell(h) for h in b.header) + " |")
            out.append("|" + "---|" * len(b.header))
            out += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in b.rows]
        elif isinstance(b, Fig):
            out.append(f"![{b.caption}](figures/{b.key}.png)\n\n*{b.caption}*")
        elif isinstance(b, Bullets):
            out += [f"- {i}" for i in b.items]
        out.append("")
    return "\n".join(out)


def _inline_html(text: str) -> str:
    t = html.escape(text, quote=False)
    t = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", t)
    t = re.sub(r"(?<!\*)\*(?!\*)(.+?)\*", r"<em>\1</em>", t)
    return re.sub(r"`(.+?)`", r"<code>\1</code>", t)


_CSS = ("body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}"
        "table{border-collapse:collapse;margin:0.6em 0;font-size:0.9em}"
        "th,td{border:1px solid #ccc;padding:3px 7px;text-align:left;vertical-align:top}"
        "th{background:#f2f2f2}code{background:#f6f6f6;padding:0 3px}img{max-width:100%}"
        "figure{margin:1em 0}figcaption{font-style:italic;color:#555}")


def to_html(blocks: list, fig_dir: Path, title: str) -> str:
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>"]
    for b in blocks:
        if isinstance(b, Heading):
            parts.append(f"<h{b.level}>{_inline_html(b.text)}</h{b.level}>")
        elif isinstance(b, Para):
            parts.append(f"<p>{_inline_html(b.text)}</p>")
        elif isinstance(b, Table):
            parts.append("<table><thead><tr>" + "".join(f"<th>{_inline_html(h)}</th>" for h in b.header)
                         + "</tr></thead><tbody>")
            parts += ["<tr>" + "".join(f"<td>{_inline_html(c)}</td>" for c in row) + "</tr>" for row in b.rows]
            parts.append("</tbody></table>")
        elif isinstance(b, Fig):
            data = base64.b64encode((fig_dir / f"{b.key}.png").read_bytes()).decode("ascii")
            parts.append(f'<figure><img alt="{html.escape(b.caption)}" src="data:image/png;base64,{data}">'
                         f"<figcaption>{_inline_html(b.caption)}</figcaption></figure>")
        elif isinstance(b, Bullets):
            parts.append("<ul>" + "".join(f"<li>{_inline_html(i)}</li>" for i in b.items) + "</ul>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def build_report(out_dir: str | Path, metrics: MetricsFile | None = None) -> dict[str, Path]:
    """(Re)draw figures and write report.md / report.html in ``out_dir`` from its metrics.json.

    Files other than these (models, logs, user notes) are left alone.
    """
    out_dir = Path(out_dir)
    if metrics is None:
        metrics = load(out_dir / "metrics.json")
    fig_dir = out_dir / "figures"
    drawn = figs.draw_all(metrics, fig_dir)
    try:
        drawn.update(draw_dense_figure(metrics, out_dir, fig_dir))
    except Exception as exc:  # a broken plot must not lose the tables
        logging.getLogger(__name__).warning("figure dense failed: %s: %s", type(exc).__name__, exc)
    blocks = build_blocks(metrics, set(drawn))
    md, page = out_dir / "report.md", out_dir / "report.html"
    write_text_atomic(md, to_markdown(blocks))
    write_text_atomic(page, to_html(blocks, fig_dir, f"polarref compare: {metrics.scene.name}"))
    return {"markdown": md, "html": page, **{f"figure:{k}": p for k, p in drawn.items()}}
