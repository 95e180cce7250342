"""The README's aerotriangulation findings, generated from the committed tables.

``python -m polarref.georef.readme reports README.md`` rewrites the block between the markers from
every ``reports/aerotriangulation-*/aerotriangulation.json``; a test fails when README and JSON differ.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from polarref.core.markers import read_block, rewrite_block
from polarref.georef.table import AerotriRow, AerotriTable, Variant

BEGIN = "<!-- aerotri-findings: generated from reports/aerotriangulation-*/aerotriangulation.json, do not edit by hand -->"
END = "<!-- /aerotri-findings -->"


def tables(reports: Path) -> list[tuple[str, AerotriTable]]:
    """(folder name, table) of every committed aerotriangulation table, by folder name."""
    found = sorted(Path(reports).glob("aerotriangulation-*/aerotriangulation.json"))
    return [(p.parent.name, AerotriTable.from_json(json.loads(p.read_text()))) for p in found]


def _span(values: list[float], fmt: str) -> str:
    lo, hi = min(values), max(values)
    return format(lo, fmt) if format(lo, fmt) == format(hi, fmt) else f"{format(lo, fmt)}-{format(hi, fmt)}"


def _ours(t: AerotriTable, variant: Variant) -> list[AerotriRow]:
    return [r for r in t.rows if r.method == "polarref" and r.variant == variant and r.record.check is not None]


def _gcp_part(t: AerotriTable) -> str:
    rows = _ours(t, Variant.PRIORS_GCPS)
    if not rows:
        return "no control-point rows"
    h = [r.record.check.rmse_horizontal / t.gsd_m for r in rows]
    z = [r.record.check.rmse_z / t.gsd_m for r in rows]
    r0 = rows[0].record
    return (f"{r0.num_control} control / {r0.check.count} check points: horizontal {_span(h, '.2f')} GSD, "
            f"vertical {_span(z, '.2f')} GSD over {len(rows)} forms")


def _priors_part(t: AerotriTable) -> str:
    rows = _ours(t, Variant.PRIORS_ON)
    if not rows:
        return "no priors-only rows"
    p = t.predicted
    exp_h = [r.record.check.rmse_horizontal / p.rmse_horizontal for r in rows]
    exp_z = [r.record.check.rmse_z / p.rmse_z for r in rows]
    out = f"priors only: {_span(exp_h, '.2f')}x (horizontal) and {_span(exp_z, '.2f')}x (vertical) the expectation"
    if t.realised is not None:
        rh = [r.record.check.rmse_horizontal / t.realised.rmse_horizontal for r in rows]
        rz = [r.record.check.rmse_z / t.realised.rmse_z for r in rows]
        out += f", {_span(rh, '.2f')}x and {_span(rz, '.2f')}x what the scene's own prior errors predict"
    if t.monte_carlo is not None:
        m = t.monte_carlo.rmse
        out += (f"; {t.monte_carlo.draws} redraws pooled {m.rmse_horizontal / p.rmse_horizontal:.2f}x / "
                f"{m.rmse_z / p.rmse_z:.2f}x")
    return out


def _peer_part(t: AerotriTable) -> str:
    peer = [r for r in t.rows if r.method != "polarref" and r.variant == Variant.PRIORS_ON and r.record.check]
    ours = _ours(t, Variant.PRIORS_ON)
    if not peer or not ours:
        return "pycolmap's pose-prior mapper not run"
    c, o = peer[0].record.check, ours[0].record.check
    return (f"pycolmap's pose-prior mapper: horizontal {c.rmse_horizontal:.3f} m, vertical {c.rmse_z:.3f} m "
            f"(ours, {ours[0].record.form}: {o.rmse_horizontal:.3f} m, {o.rmse_z:.3f} m)")


def _line(name: str, t: AerotriTable) -> str:
    state = "clean" if t.provenance.git_dirty is False else "dirty"
    return (f"- `reports/{name}/` ({t.views} views, priors from {t.priors_source}, GSD {t.gsd_m:.3f} m; commit "
            f"{t.provenance.git_commit[:7]}, {state}): {_gcp_part(t)}; {_priors_part(t)}; {_peer_part(t)}.")


def findings_block(reports: Path) -> str:
    return "\n".join(_line(name, t) for name, t in tables(reports)) + "\n"


def readme_block(text: str) -> str | None:
    return read_block(text, BEGIN, END)


def update_readme(readme: Path, reports: Path) -> Path:
    return rewrite_block(readme, BEGIN, END, findings_block(reports))


if __name__ == "__main__":  # python -m polarref.georef.readme reports README.md
    print(update_readme(Path(sys.argv[2] if len(sys.argv) > 2 else "README.md"),
                        Path(sys.argv[1] if len(sys.argv) > 1 else "reports")))
