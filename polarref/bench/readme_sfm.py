"""The README's SfM-speed finding, generated from ``reports/bench-sfm/bench.json`` and its rechecks.

``python -m polarref.bench.readme_sfm reports/bench-sfm README.md`` rewrites the block between the
README's markers; ``tests/test_readme_sfm.py`` fails when the README and the JSON differ (issue 30:
the hand-written bullet kept quoting a sweep that a clean recheck had superseded).
"""

from __future__ import annotations

import sys
from pathlib import Path

from polarref.bench.records import SfMBench, SfMCell
from polarref.core import records
from polarref.core.atomic import atomic_write
from polarref.core.markers import replace_block

BEGIN = "<!-- sfm-findings: generated from reports/bench-sfm/*bench.json, do not edit by hand -->"
END = "<!-- /sfm-findings -->"
HEADLINE_VIEWS = 168


def _cell(bench: SfMBench, method: str, views: int) -> SfMCell | None:
    return next((c for c in bench.cells if c.method == method and c.views == views and c.status == "ok"), None)


def _commit(bench: SfMBench) -> str:
    env = bench.environment
    return f"commit {env.git_commit[:7] or 'unknown'}{' dirty' if env.git_dirty else ' (clean)'}"


def _ratio(bench: SfMBench, views: int) -> float | None:
    ours, ref = _cell(bench, "ours", views), _cell(bench, "pycolmap", views)
    return ours.total_s / ref.total_s if ours and ref and ref.total_s else None


def sweep_line(bench: SfMBench, where: str) -> str:
    views = sorted({c.views for c in bench.cells})
    ours, ref = _cell(bench, "ours", HEADLINE_VIEWS), _cell(bench, "pycolmap", HEADLINE_VIEWS)
    head = (f"- **SfM speed** (`{where}/`, `polarref bench sfm --scene {bench.settings.scene} --views "
            f"{' '.join(map(str, views))}`, {_commit(bench)}, {bench.settings.threads} thread per method, each cell in "
            f"its own process; this bullet is generated from the JSON by `python -m polarref.bench.readme_sfm "
            f"{where} README.md`): on the same rendered {bench.settings.scene} images and the same "
            f"{bench.settings.pairing} pairs (pycolmap imports ours), ")
    if ours is None or ref is None:
        return head + f"the {HEADLINE_VIEWS}-view cells did not both finish (not tested)."
    ratios = [r for r in (_ratio(bench, v) for v in views) if r is not None]
    rot = "lower" if ours.rotation_error_deg_mean < ref.rotation_error_deg_mean else "higher"
    k = bench.growth_exponents
    mem_v = max(views)
    mo, mr = _cell(bench, "ours", mem_v), _cell(bench, "pycolmap", mem_v)
    return (head + f"ours takes **{ours.total_s / ref.total_s:.2f}x** pycolmap incremental's time at {HEADLINE_VIEWS} "
            f"views ({ours.total_s:.1f} vs {ref.total_s:.1f} s, sum of the stages) with "
            f"{ours.tie_points / ref.tie_points:.2f}x its tie points ({ours.tie_points:,} vs {ref.tie_points:,}) and a "
            f"{rot} GT rotation error ({ours.rotation_error_deg_mean:.3f} vs {ref.rotation_error_deg_mean:.3f} deg); "
            f"{min(ratios):.2f}-{max(ratios):.2f}x at {views[0]}-{views[-1]} views. Growth exponent of our total time "
            f"from 84 to {mem_v} views {_exp(k, 'ours')} (pycolmap {_exp(k, 'pycolmap')}); peak memory "
            f"{_mem(mo)} MiB at {mem_v} views (pycolmap {_mem(mr)}).")


def _exp(k: dict[str, dict[str, float | None]], method: str) -> str:
    v = k.get(method, {}).get("total_84_336")
    return "n/a" if v is None else f"{v:.2f}"


def _mem(c: SfMCell | None) -> str:
    return "n/a" if c is None else f"{c.peak_memory_mb.ru_maxrss_mb:.0f}"


def recheck_line(bench: SfMBench, where: str) -> str:
    views = sorted({c.views for c in bench.cells})
    parts = []
    for v in views:
        ours, ref = _cell(bench, "ours", v), _cell(bench, "pycolmap", v)
        if ours is None or ref is None:
            parts.append(f"{v} views not tested")
            continue
        cpu = (f", CPU time {ours.cpu_s / ref.cpu_s:.2f}x" if ours.cpu_s and ref.cpu_s else "")
        parts.append(f"**{ours.total_s / ref.total_s:.2f}x** at {v} views ({ours.total_s:.1f} vs {ref.total_s:.1f} s{cpu}; "
                     f"tie points {ours.tie_points:,} vs {ref.tie_points:,})")
    return f"  Recheck (`{where}/`, {_commit(bench)}): " + "; ".join(parts) + ". It supersedes the sweep's figure there."


def findings_block(bench_dir: Path) -> str:
    """The sweep's line, then one line per recheck folder (``recheck-*``, in name order)."""
    root = bench_dir.parent.name + "/" + bench_dir.name
    lines = [sweep_line(records.load(SfMBench, bench_dir / "bench.json"), root)]
    for sub in sorted(bench_dir.glob("recheck-*/bench.json")):
        lines.append(recheck_line(records.load(SfMBench, sub), f"{root}/{sub.parent.name}"))
    return "\n".join(lines) + "\n"


def update_readme(readme: Path, bench_dir: Path) -> Path:
    try:
        text = replace_block(readme.read_text(), BEGIN, END, findings_block(bench_dir))
    except ValueError as exc:
        raise SystemExit(f"{readme}: {exc}") from exc
    return atomic_write(readme, text)


if __name__ == "__main__":  # python -m polarref.bench.readme_sfm reports/bench-sfm README.md
    print(update_readme(Path(sys.argv[2] if len(sys.argv) > 2 else "README.md"),
                        Path(sys.argv[1] if len(sys.argv) > 1 else "reports/bench-sfm")))
