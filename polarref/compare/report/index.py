"""``polarref report --index DIR``: one page over every report folder below DIR.

Reads each ``*/metrics.json`` (never recomputes); a folder whose metrics.json cannot be read is
listed with the reason instead of stopping the index.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

from polarref.compare.report.build import commit_text, fmt, fmt_s, improving_runtime
from polarref.compare.report.render import Heading, Para, Table, WrittenPages, to_html, to_markdown
from polarref.compare.schema import MetricsFile, load, write_text_atomic
from polarref.core.errors import PolarrefError
from polarref.core.status import RunStatus

log = logging.getLogger(__name__)


def find_reports(root: Path) -> list[Path]:
    """Folders at most two levels below ``root`` holding a metrics.json, sorted by path."""
    found = [p.parent for pattern in ("*/metrics.json", "*/*/metrics.json") for p in root.glob(pattern)]
    return sorted(set(found))


def _main_row(m: MetricsFile) -> list[str]:
    pair = next((p for p in m.pairs if m.method(p.baseline) and m.method(p.candidate)), None)
    if pair is None:
        return ["—", "—", "—"]
    b, c = m.method(pair.baseline), m.method(pair.candidate)
    ok = b.status == RunStatus.OK and c.status == RunStatus.OK
    err = "mean_reprojection_error_px"
    acc = f"{fmt(b.metric(err))} / {fmt(c.metric(err))}" if ok else "n/a"
    return [f"{b.label} vs {c.label}", acc, improving_runtime(b.runtime_s, c.runtime_s) if ok else "n/a"]


TWIN_TABLES = "paper-tables"   # reports/paper-tables/<twin>/paper-table.json (polarref compare <twin> --tables)
TWIN_CLAIMS = {"C4": "About 1.4x faster incremental SfM (Table 1: 77 -> 56 min)",
               "C5": "More tie points and more reprojected pixels (Tables 1-3: +353 / +3,383 in Table 1)"}


def _twin_columns(root: Path) -> tuple[list[tuple[str, dict[str, str]]], list]:
    """(twin, {claim id: verdict}) for each twin whose table exists, and the index's lines about them.

    A twin without a table gets no column; an unreadable table is named with the reason."""
    from polarref.compare.twins import tables as PT

    tables = root / TWIN_TABLES
    cols, missing, bad = [], [], []
    for twin in PT.PAPER:
        f = tables / twin / "paper-table.json"
        if not f.is_file():
            missing.append(twin)
            continue
        try:
            table = PT.TwinTable.from_dict(json.loads(f.read_text()))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            log.warning("skipping %s: %s", f, exc)
            bad.append(f"`{TWIN_TABLES}/{twin}`: {type(exc).__name__}: {exc}")
            continue
        cols.append((twin, {cid: v.verdict for cid, v in PT.verdicts(table).by_claim()}))
    if not (tables / "README.md").is_file() and not cols and not bad:
        return [], []
    text = (f"The paper's Tables 1-3 redone on the synthetic twins: [{TWIN_TABLES}/README.md]({TWIN_TABLES}/README.md). "
            "A twin's column gives C4 and C5 on its one run by the scorecard's single-run rules (polar vs "
            "Euclidean BA in the same pipeline).")
    if missing:
        text += f" No table yet (no column): {', '.join(missing)}."
    if bad:
        text += " Unreadable: " + "; ".join(bad) + "."
    return cols, [Heading(2, "Twins of the paper's datasets"), Para(text)]


def build_index(root: str | Path) -> WrittenPages:
    """Write ``root/index.md`` and ``root/index.html``; returns their paths."""
    root = Path(root)
    if not root.is_dir():
        raise PolarrefError(f"index folder not found: {root}")
    folders = find_reports(root)
    if not folders:
        raise PolarrefError(f"no report folders (*/metrics.json) under {root}")
    rows, loaded, bad = [], [], []
    for d in folders:
        rel = Path(os.path.relpath(d, root)).as_posix()
        try:
            m = load(d / "metrics.json")
        except PolarrefError as exc:
            log.warning("skipping %s: %s", d, exc)
            bad.append(f"`{rel}`: {exc}")
            continue
        loaded.append((rel, m))
        ok = sum(r.status == RunStatus.OK for r in m.methods)
        page = f"{rel}/report.html" if (d / "report.html").is_file() else f"{rel}/metrics.json"
        rows.append([f"[{rel}]({page})", m.scene.name, m.scene.kind, str(m.scene.num_images),
                     f"{ok}/{len(m.methods)}", *_main_row(m), fmt_s(m.environment.total_runtime_s),
                     m.environment.created[:10], commit_text(m)])
    claim_ids = list(dict.fromkeys(c.claim_id for _, m in loaded for c in m.claims))
    claim_text = {c.claim_id: c.claim for _, m in loaded for c in m.claims}
    twins, twin_notes = _twin_columns(root)
    for cid, text in TWIN_CLAIMS.items():
        if twins and cid not in claim_ids:
            claim_ids.append(cid)
            claim_text[cid] = text
    verdicts = [[cid, claim_text[cid], *[next((c.verdict for c in m.claims if c.claim_id == cid), "—")
                                         for _, m in loaded],
                 *[v.get(cid, "—") for _, v in twins]] for cid in claim_ids]
    blocks: list = [Heading(1, "polarref reports"),
                    Para(f"{len(loaded)} report folder(s) under `{root.name or root}`; every value is read from "
                         "the folder's `metrics.json`. Main comparison: the first paper-format table of each "
                         "report (mean reprojection error, baseline / candidate, and the runtime change)."),
                    Table(["report", "scene", "kind", "images", "methods ok", "main comparison",
                           "accuracy (px)", "runtime", "total runtime", "run date", "commit"], rows)]
    if verdicts:
        blocks += [Heading(2, "Verdicts"), Table(["#", "claim", *[rel for rel, _ in loaded],
                                                  *[f"{t} twin" for t, _ in twins]], verdicts)]
    blocks += twin_notes
    if bad:
        blocks += [Heading(2, "Unreadable folders"), Para("; ".join(bad))]
    md, page = root / "index.md", root / "index.html"
    write_text_atomic(md, to_markdown(blocks))
    write_text_atomic(page, to_html(blocks, root, "polarref reports"))
    return WrittenPages(md, page)
