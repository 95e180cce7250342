"""The README's finding at the paper's scale, generated from ``reports/paper-tables/*/paper-table.json``.

``python -m polarref.compare.twins.readme_scale reports/paper-tables README.md`` rewrites the block between
the README's markers; ``tests/compare/twins/test_readme_scale.py`` fails when the README and the JSON differ
(issue 30: every figure quoted in the README comes from committed JSON, checked by a test).
"""

from __future__ import annotations

import sys
from pathlib import Path

from polarref.core.status import RunStatus
from polarref.compare.twins.tables import (BASELINE, OURS, PAPER, TwinRow, TwinTable, load_tables, status_text,
                                           verdicts)
from polarref.core.markers import rewrite_block

BEGIN = "<!-- scale-findings: generated from reports/paper-tables/*/paper-table.json, do not edit by hand -->"
END = "<!-- /scale-findings -->"
PEERS = (("pycolmap-incremental-sift", "pycolmap incremental"), ("pycolmap-global-sift", "pycolmap global"))


def _ok(m: TwinRow | None) -> bool:
    return m is not None and m.status == RunStatus.OK


def _run(m: TwinRow | None, label: str, images: int) -> str:
    if not _ok(m):
        return f"{label}: {status_text(m)}" + (f" ({m.reason})" if m and m.reason else "")
    seg = f", {m.segments} resumed segments" if m.segments > 1 else ""
    return (f"{label} {m.registered}/{images} views in {m.efficiency_min:.1f} min{seg} ({m.tie_points:,} tie points, "
            f"{m.accuracy_px:.3f} px, {m.rotation_error_deg:.4f} deg)")


def twin_line(name: str, t: TwinTable, where: str) -> str:
    prov = t.provenance
    commit = (f"commit {prov.commit[:7]}{' dirty' if prov.dirty else ' (clean)'}" if prov and prov.commit
              else "commit unknown")
    base, ours = t.methods.get(BASELINE), t.methods.get(OURS)
    v = verdicts(t)
    head = f"- `{where}/{name}/` (Table {PAPER[name].table}, {t.images} views, {commit}): "
    if not (_ok(base) and _ok(ours)):
        return head + "the Euclidean / polar pair did not both finish (not tested); " + "; ".join(
            _run(t.methods.get(k), label, t.images) for k, label in PEERS) + "."
    ba = v.c4.values.get("ba_speedup")
    return (head + _run(base, "ours Euclidean", t.images) + "; " + _run(ours, "ours polar", t.images)
            + f"; BA time Euclidean/polar x{ba:.2f}" + f"; C4 {v.c4.verdict}, C5 {v.c5.verdict}; "
            + "; ".join(_run(t.methods.get(k), label, t.images) for k, label in PEERS) + ".")


def findings_block(root: Path) -> str:
    """One line per twin that has a table (the paper's order)."""
    where = root.parent.name + "/" + root.name
    lines = [twin_line(t.twin, t, where) for t in load_tables(root)]
    return "\n".join(lines or ["- no twin table committed (not tested)."]) + "\n"


def update_readme(readme: Path, root: Path) -> Path:
    return rewrite_block(readme, BEGIN, END, findings_block(root))


if __name__ == "__main__":  # python -m polarref.compare.twins.readme_scale reports/paper-tables README.md
    print(update_readme(Path(sys.argv[2] if len(sys.argv) > 2 else "README.md"),
                        Path(sys.argv[1] if len(sys.argv) > 1 else "reports/paper-tables")))
