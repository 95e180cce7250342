"""The report's document model and its two renderers (Markdown and self-contained HTML).

One list of blocks makes both files, so they always say the same thing. HTML-only parts (the
3D view, collapsible sections) have a plain Markdown form: a note, and a heading.
"""

from __future__ import annotations

import base64
import html
import re
from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class DrawnFigure:
    """One figure a report build drew: its key (the report's ``Fig`` block) and its PNG."""

    key: str
    path: Path


@dataclass(frozen=True)
class WrittenPages:
    """What a report or index build wrote: its two pages and the figures drawn."""

    markdown: Path
    html: Path
    figures: tuple[DrawnFigure, ...] = ()


@dataclass
class Heading:
    level: int
    text: str


@dataclass
class Para:
    text: str          # may contain **bold**, *italic* and `code`


@dataclass
class Table:
    header: list[str]
    rows: list[list[str]]
    css: str = ""      # HTML class


@dataclass
class Fig:
    key: str
    caption: str


@dataclass
class Bullets:
    items: list[str]


@dataclass
class Badge:
    """One claim verdict: ``C4 [not supported] claim - one short line``."""

    claim_id: str
    verdict: str
    claim: str
    line: str


@dataclass
class Badges:
    items: list[Badge]


@dataclass
class Details:
    """Collapsible in HTML (<details>), a heading and its blocks in Markdown."""

    summary: str
    blocks: list
    level: int = 3     # Markdown heading level
    open: bool = False


@dataclass
class Section:
    """A group of blocks with an HTML id (for links and for the browser test)."""

    id: str
    blocks: list = field(default_factory=list)


@dataclass
class RawHtml:
    """HTML-only content (the 3D view); Markdown shows ``markdown`` instead."""

    html: str
    markdown: str


# ---- Markdown ---------------------------------------------------------------------------------

def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _md(blocks: list, out: list[str]) -> None:
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
        elif isinstance(b, Badges):
            out += [f"- **{x.claim_id}** `{x.verdict}` {x.claim} — {x.line}" for x in b.items]
        elif isinstance(b, Details):
            out += ["#" * b.level + " " + b.summary, ""]
            _md(b.blocks, out)
            continue
        elif isinstance(b, Section):
            _md(b.blocks, out)
            continue
        elif isinstance(b, RawHtml):
            out.append(b.markdown)
        out.append("")


def to_markdown(blocks: list) -> str:
    out: list[str] = []
    _md(blocks, out)
    return "\n".join(out)


# ---- HTML -------------------------------------------------------------------------------------

def inline_html(text: str) -> str:
    t = html.escape(text, quote=False)
    t = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", t)
    t = re.sub(r"(?<!\*)\*(?!\*)(.+?)\*", r"<em>\1</em>", t)
    t = re.sub(r"`(.+?)`", r"<code>\1</code>", t)
    return re.sub(r"\[([^\]]+)\]\(([^)\s\"]+)\)", r'<a href="\2">\1</a>', t)


# issue 30: a verdict that is neither for nor against the claim wears the inconclusive colour (its
# badge text names it), so the stylesheet, and every committed report's bytes, stay as they were
_SHARED_STYLE = {"frame-dependent": "inconclusive", "underpowered": "inconclusive"}


def verdict_class(verdict: str) -> str:
    verdict = _SHARED_STYLE.get(verdict, verdict)
    return "v-" + re.sub(r"[^a-z]+", "-", verdict.lower()).strip("-")


CSS = ("body{font-family:system-ui,sans-serif;max-width:1180px;margin:1em auto;padding:0 1em;color:#222;"
       "line-height:1.35}h1{font-size:1.5em;margin:0.3em 0}h2{margin-top:1.4em;border-bottom:1px solid #ddd}"
       "h3{font-size:1.05em;margin:0.8em 0 0.3em}"
       "table{border-collapse:collapse;margin:0.5em 0;font-size:0.9em}"
       "th,td{border:1px solid #ccc;padding:3px 7px;text-align:left;vertical-align:top}"
       "th{background:#f2f2f2}code{background:#f6f6f6;padding:0 3px}img{max-width:100%}"
       "figure{margin:1em 0}figcaption{font-style:italic;color:#555}"
       ".lede{color:#444;margin:0.2em 0 0.6em}"
       "#summary{background:#fafafa;border:1px solid #e3e3e3;border-radius:6px;padding:0.2em 1em 0.6em}"
       "ul.badges{list-style:none;padding:0;margin:0.4em 0}ul.badges li{margin:0.2em 0}"
       ".badge{display:inline-block;min-width:7.5em;text-align:center;border-radius:4px;padding:0 6px;"
       "font-size:0.85em;font-weight:600;color:#fff;margin-right:0.4em}"
       ".v-supported{background:#2e7d32}.v-not-supported{background:#c62828}"
       ".v-inconclusive{background:#b26a00}.v-not-tested{background:#757575}"
       "details{margin:0.3em 0;border-left:3px solid #ddd;padding-left:0.7em}"
       "summary{cursor:pointer;font-weight:600}.badges .line{color:#555;font-size:0.93em}"
       ".view3d canvas{width:100%;max-width:960px;border:1px solid #ccc;background:#fcfcfc;cursor:grab}"
       ".view3d-controls label{margin-right:0.9em;font-size:0.85em;white-space:nowrap}"
       ".view3d-controls .swatch{display:inline-block;width:0.8em;height:0.8em;margin:0 0.25em;"
       "vertical-align:middle;border:1px solid #888}")


def _html(blocks: list, fig_dir: Path, parts: list[str]) -> None:
    for b in blocks:
        if isinstance(b, Heading):
            parts.append(f"<h{b.level}>{inline_html(b.text)}</h{b.level}>")
        elif isinstance(b, Para):
            parts.append(f"<p>{inline_html(b.text)}</p>")
        elif isinstance(b, Table):
            cls = f' class="{b.css}"' if b.css else ""
            parts.append(f"<table{cls}><thead><tr>" + "".join(f"<th>{inline_html(h)}</th>" for h in b.header)
                         + "</tr></thead><tbody>")
            parts += ["<tr>" + "".join(f"<td>{inline_html(c)}</td>" for c in row) + "</tr>" for row in b.rows]
            parts.append("</tbody></table>")
        elif isinstance(b, Fig):
            data = base64.b64encode((fig_dir / f"{b.key}.png").read_bytes()).decode("ascii")
            parts.append(f'<figure id="fig-{b.key}"><img alt="{html.escape(b.caption)}" '
                         f'src="data:image/png;base64,{data}"><figcaption>{inline_html(b.caption)}</figcaption>'
                         "</figure>")
        elif isinstance(b, Bullets):
            parts.append("<ul>" + "".join(f"<li>{inline_html(i)}</li>" for i in b.items) + "</ul>")
        elif isinstance(b, Badges):
            parts.append('<ul class="badges">' + "".join(
                f'<li><span class="badge {verdict_class(x.verdict)}">{html.escape(x.verdict)}</span>'
                f"<strong>{html.escape(x.claim_id)}</strong> {inline_html(x.claim)} — "
                f'<span class="line">{inline_html(x.line)}</span></li>' for x in b.items) + "</ul>")
        elif isinstance(b, Details):
            parts.append(f"<details{' open' if b.open else ''}><summary>{inline_html(b.summary)}</summary>")
            _html(b.blocks, fig_dir, parts)
            parts.append("</details>")
        elif isinstance(b, Section):
            parts.append(f'<section id="{b.id}">')
            _html(b.blocks, fig_dir, parts)
            parts.append("</section>")
        elif isinstance(b, RawHtml):
            parts.append(b.html)


def to_html(blocks: list, fig_dir: Path, title: str, layout: int = 0) -> str:
    """The page; ``layout`` (a report layout version) goes into a <meta> tag when > 0."""
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             '<meta name="viewport" content="width=device-width, initial-scale=1">',
             *([f'<meta name="polarref-report-layout" content="{layout}">'] if layout else []),
             f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>"]
    _html(blocks, fig_dir, parts)
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"
