"""Rewrite imports of modules moved by the issue-29 layout (run from a checkout's root).

Temporary: it exists so that branches started before the move can be merged onto the new
layout. It rewrites dotted names (`polarref.geometry` -> `polarref.core.geometry`), `from
polarref import name` lines and file paths (`polarref/geometry.py`) in .py, .sh, .md and .toml
files under the current folder.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

# old module under polarref -> new dotted path under polarref
MOVED = {
    "geometry": "core.geometry",
    "angular": "core.angular",
    "errors": "core.errors",
    "atomic": "core.atomic",
    "records": "core.records",
    "provenance": "core.provenance",
    "progress": "core.progress",
    "execution": "core.execution",
    "heap": "core.heap",
    "data": "core.data",
    "landmarks": "core.landmarks",
    "surface_metrics": "metrics.surface",
    "bench_sfm_report": "bench.sfm_report",
    "bench_sfm": "bench.sfm",
    "bench_exec": "bench.executor",
    "scene_folder": "io.scene_folder",
    "model.scene_folder": "io.scene_folder",
    "pairing": "sfm.pairing",
    "reconstruction": "model",
}

_DOTTED = re.compile(r"\bpolarref\.(" + "|".join(map(re.escape, sorted(MOVED, key=len, reverse=True))) + r")\b(?![\w])")
_PATH = re.compile(r"\bpolarref/(" + "|".join(map(re.escape, sorted(MOVED, key=len, reverse=True))) + r")\.py\b")
_FROM = re.compile(r"^(\s*)from polarref import ([^\n(]+)$", re.M)


def _split_from(match: re.Match) -> str:
    indent, names = match.group(1), match.group(2)
    kept, moved = [], []
    for item in (n.strip() for n in names.split(",")):
        base = item.split(" as ")[0].strip()
        (moved if base in MOVED else kept).append(item)
    lines = []
    if kept:
        lines.append(f"{indent}from polarref import {', '.join(kept)}")
    for item in moved:
        base, _, alias = item.partition(" as ")
        parent, _, leaf = ("polarref." + MOVED[base.strip()]).rpartition(".")
        text = f"{indent}from {parent} import {leaf}"
        if alias or leaf != base.strip():
            text += f" as {alias.strip() or base.strip()}"
        lines.append(text)
    return "\n".join(lines)


def _path_sub(match: re.Match) -> str:
    new = MOVED[match.group(1)].replace(".", "/")
    return f"polarref/{new}.py" if new != "model" else "polarref/model/"


def rewrite(text: str) -> str:
    text = _FROM.sub(_split_from, text)
    text = _DOTTED.sub(lambda m: "polarref." + MOVED[m.group(1)], text)
    return _PATH.sub(_path_sub, text)


def main(root: Path) -> int:
    changed = 0
    for path in root.rglob("*"):
        if path.suffix not in {".py", ".sh", ".md", ".toml"} or ".venv" in path.parts or ".git" in path.parts:
            continue
        if path.name == "migrate_imports.py":
            continue
        old = path.read_text()
        new = rewrite(old)
        if new != old:
            path.write_text(new)
            changed += 1
    print(f"migrate_imports: {changed} files rewritten")
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(".")))
