"""Compare two result files (or two report folders) figure by figure, runtimes and provenance aside.

    python scripts/diff_reports.py A/metrics.json B/metrics.json
    python scripts/diff_reports.py REPORTS_A REPORTS_B      # every *.json both folders hold

``--json OUT`` also writes the outcome (every difference, the counts, the commit each side's
result files name, and this run's provenance) as a record to commit beside a claim of "no change".

Exit 0 when every figure is identical, 1 when any differs (each difference printed as
``path: a != b``), 2 for a usage error (missing file, not JSON). Floats compare exactly by
default: every run is seeded and single-threaded, so a behaviour-preserving change reproduces
them bit for bit on one machine; ``--rtol`` allows last-digit differences between machines.

Left out of the comparison, because they measure the machine or the moment rather than the
method: provenance (``environment``, ``provenance``, commits, versions, timestamps, the command
line), every key naming a time (``*_s``, ``*_min``, ``*runtime*``, ``*_utc``, ``created``) or a
memory peak (``*rss*``, ``*memory*``), in a claim whose figures include a time (unit "s") every
figure but its counts (the speed-up ratios, their spread and the slack all come from the clock)
and the verdict and wording that rest on them, and, in a claim's wording, the clause naming the
commits of the pre-registration and of the run. What was left out is counted in the summary line. Job folders (``runs/``, ``stages/``, ``cache/``) are not compared.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from polarref.core import records  # noqa: E402
from polarref.core.provenance import Provenance, collect_record  # noqa: E402

PROVENANCE_KEYS = {"environment", "provenance", "created", "command", "git_commit", "git_dirty", "machine",
                   "versions", "platform", "cpu_model", "cpu_count", "threads", "finished_utc", "python"}
TIME_KEY = re.compile(r"(_s|_min|_ms|runtime|_utc|rss\w*|memory\w*|_mb)$|^(time|wall|seconds)$")
SKIP_DIRS = {"runs", "stages", "cache"}
# A claim's wording names the commit that last changed the pre-registration and the run's commit.
PROVENANCE_CLAUSE = re.compile(r"Pre-registration: .*?; this run: commit [0-9a-f]+")


def _ignored(key: str) -> bool:
    return key in PROVENANCE_KEYS or bool(TIME_KEY.search(key))


def _timing_claim(claim: dict) -> bool:
    return any(isinstance(f, dict) and f.get("unit") == "s" for f in claim.get("figures", []))


class Diff:
    def __init__(self, rtol: float = 0.0) -> None:
        self.rtol = rtol
        self.differences: list[str] = []
        self.compared = 0
        self.ignored = 0

    def value(self, path: str, a, b) -> None:
        if isinstance(a, dict) and isinstance(b, dict):
            self.mapping(path, a, b)
        elif isinstance(a, list) and isinstance(b, list):
            if len(a) != len(b):
                self.differences.append(f"{path}: {len(a)} items != {len(b)} items")
                return
            claims = path.endswith("claims")
            for i, (x, y) in enumerate(zip(a, b)):
                if claims and isinstance(x, dict) and isinstance(y, dict) and (_timing_claim(x) or _timing_claim(y)):
                    self.timing_claim(f"{path}[{i}]", x, y)
                else:
                    self.value(f"{path}[{i}]", x, y)
        else:
            if isinstance(a, str) and isinstance(b, str) and path.endswith((".rationale", ".summary")):
                a, b, n = *_masked(a, b), PROVENANCE_CLAUSE.search(a) is not None
                self.ignored += n
            self.compared += 1
            same = a == b or (isinstance(a, float) and isinstance(b, float)
                              and (math.isnan(a) and math.isnan(b) or math.isclose(a, b, rel_tol=self.rtol)))
            if not same or type(a) is not type(b) and not (isinstance(a, (int, float)) and isinstance(b, (int, float))):
                self.differences.append(f"{path}: {a!r} != {b!r}")

    def mapping(self, path: str, a: dict, b: dict) -> None:
        for key in sorted(set(a) | set(b)):
            if _ignored(key):
                self.ignored += 1
                continue
            where = f"{path}.{key}" if path else key
            if key not in a or key not in b:
                self.differences.append(f"{where}: only in {'B' if key not in a else 'A'}")
                continue
            self.value(where, a[key], b[key])

    def timing_claim(self, path: str, a: dict, b: dict) -> None:
        """A claim on runtimes: its time and ratio figures, verdict and wording are the machine's."""
        keep = {k: v for k, v in a.items() if k not in ("figures", "verdict", "rationale", "summary")}
        self.ignored += 3
        self.mapping(path, keep, {k: v for k, v in b.items() if k in keep or k not in a})
        fa, fb = a.get("figures", []), b.get("figures", [])
        if [f.get("key") for f in fa] != [f.get("key") for f in fb]:
            self.differences.append(f"{path}.figures: keys differ")
            return
        for i, (x, y) in enumerate(zip(fa, fb)):
            if x.get("unit") != "count":
                self.ignored += 1
                continue
            self.value(f"{path}.figures[{i}]", x, y)


def _masked(a: str, b: str) -> tuple[str, str]:
    return PROVENANCE_CLAUSE.sub("Pre-registration: (provenance)", a), \
        PROVENANCE_CLAUSE.sub("Pre-registration: (provenance)", b)


def _load(path: Path):
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise SystemExit(f"error: cannot read {path}: {exc}") from None


def _files(root: Path) -> set[Path]:
    return {p.relative_to(root) for p in root.rglob("*.json")
            if not SKIP_DIRS & set(p.relative_to(root).parts[:-1])}


def compare(a: Path, b: Path, rtol: float = 0.0) -> Diff:
    diff = Diff(rtol)
    if a.is_dir() and b.is_dir():
        fa, fb = _files(a), _files(b)
        for rel in sorted(fa ^ fb):
            diff.differences.append(f"{rel}: only in {'A' if rel in fa else 'B'}")
        for rel in sorted(fa & fb):
            diff.value(str(rel), _load(a / rel), _load(b / rel))
    else:
        diff.value("", _load(a), _load(b))
    return diff


@dataclass(frozen=True)
class SideCommit:
    """The code a result file says made it (``environment.git_commit`` / ``git_dirty``)."""

    file: str
    git_commit: str
    git_dirty: bool | None


@dataclass(frozen=True)
class DiffRecord:
    """``--json``: the outcome of one comparison and where it was made."""

    a: str
    b: str
    differences: list[str]
    compared: int
    ignored: int
    a_commits: list[SideCommit]
    b_commits: list[SideCommit]
    environment: Provenance


def _commits(root: Path) -> list[SideCommit]:
    """Every result file's recorded commit under ``root`` (a file: itself)."""
    files = [root] if root.is_file() else sorted(root / rel for rel in _files(root))
    out = []
    for f in files:
        data = _load(f)
        env = data.get("environment") if isinstance(data, dict) else None
        if isinstance(env, dict) and "git_commit" in env:
            out.append(SideCommit(str(f), str(env["git_commit"] or ""), env.get("git_dirty")))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("a", type=Path, help="metrics.json (or any result JSON) or a report folder")
    ap.add_argument("b", type=Path, help="the same kind as A")
    ap.add_argument("--rtol", type=float, default=0.0,
                    help="relative tolerance for floats (default 0: bit for bit; e.g. 1e-9 across machines)")
    ap.add_argument("--json", type=Path, default=None, metavar="OUT",
                    help="also write the outcome with both sides' commits and this run's provenance to OUT")
    args = ap.parse_args(argv)
    for p in (args.a, args.b):
        if not p.exists():
            print(f"error: {p} does not exist", file=sys.stderr)
            return 2
    if args.a.is_dir() != args.b.is_dir():
        print("error: compare a file with a file or a folder with a folder", file=sys.stderr)
        return 2
    try:
        diff = compare(args.a, args.b, args.rtol)
    except SystemExit as exc:
        print(exc, file=sys.stderr)
        return 2
    for line in diff.differences:
        print(line)
    print(f"{len(diff.differences)} difference(s) in {diff.compared} figures compared "
          f"({diff.ignored} runtime/provenance entries left out)")
    if args.json is not None:
        records.save(DiffRecord(str(args.a), str(args.b), diff.differences, diff.compared, diff.ignored,
                                _commits(args.a), _commits(args.b), collect_record()), args.json)
    return 1 if diff.differences else 0


if __name__ == "__main__":
    raise SystemExit(main())
