"""The README's run-time paragraph on the committed comparisons, generated from their metrics.json.

Run times depend on the machine and on what else ran on it, so the README quotes only what the
runs recorded: total time, commit, CPU and core count. ``python -m
polarref.compare.report.readme_runtime reports README.md`` rewrites the block; a test fails when
README and JSON differ.
"""

from __future__ import annotations

import sys
from pathlib import Path

from polarref.compare.report.readme_findings import REPORTS
from polarref.compare.schema import MetricsFile, load
from polarref.core.markers import read_block, rewrite_block

BEGIN = "<!-- compare-runtime: generated from reports/*/metrics.json, do not edit by hand -->"
END = "<!-- /compare-runtime -->"


def _line(name: str, m: MetricsFile) -> str:
    env = m.environment
    state = "dirty" if env.git_dirty else ("clean" if env.git_dirty is False else "dirty state unknown")
    budget = f", run budget {env.run_budget_s:.0f} s" if env.run_budget_s else ""
    return (f"- `reports/{name}/`: {env.total_runtime_s:.1f} s for `{_short(env.command)}` "
            f"(commit {env.git_commit[:7] or 'unknown'}, {state}; {env.cpu_count} cores, "
            f"{env.cpu_model or 'CPU not recorded'}{budget}).")


def _short(command: str) -> str:
    """The command without the regeneration flags that every committed report shares."""
    drop = {"--no-progress", "-q", "--overwrite"}
    words = command.split()
    kept, skip = [], False
    for w in words:
        if skip:
            skip = False
            continue
        if w == "--out":
            skip = True
            continue
        if w not in drop:
            kept.append(w)
    return " ".join(kept)


def runtime_block(reports: Path) -> str:
    """One line per committed comparison that has a metrics.json."""
    lines = [_line(name, load(reports / name / "metrics.json")) for name in REPORTS
             if (reports / name / "metrics.json").is_file()]
    return "\n".join(lines) + "\n"


def readme_block(text: str) -> str | None:
    return read_block(text, BEGIN, END)


def update_readme(readme: Path, reports: Path) -> Path:
    return rewrite_block(readme, BEGIN, END, runtime_block(reports))


if __name__ == "__main__":  # python -m polarref.compare.report.readme_runtime reports README.md
    print(update_readme(Path(sys.argv[2] if len(sys.argv) > 2 else "README.md"),
                        Path(sys.argv[1] if len(sys.argv) > 1 else "reports")))
