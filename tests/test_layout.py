"""The package layout ARCHITECTURE.md promises, checked on the sources: no import cycle between
modules (function-local and TYPE_CHECKING imports included), packages layered one way, nothing
at the package top level but its face and the CLI entry."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from _scripts import load_script

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("polarref", "synth", "derivations")

# A package imports only from packages in lower rows (ARCHITECTURE.md, "Packages").
LAYERS = (
    ("__main__",),
    ("cli",),
    ("commands",),
    ("compare", "bench"),
    ("dense", "sfm"),
    ("ba", "peers"),
    ("io", "metrics", "synth"),
    ("model",),
    ("camera", "derivations"),
    ("core",),
    ("_generated",),
)
TOP_LEVEL = {"__init__", "__main__", "cli"}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def _targets(mod: str, node: ast.AST, is_pkg: bool, mods: dict[str, Path]) -> list[str]:
    """Modules an import statement loads, not counting the parent packages Python runs first."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name in mods]
    base = node.module or ""
    if node.level:
        parts = mod.split(".") if is_pkg else mod.split(".")[:-1]
        parts = parts[: len(parts) - node.level + 1]
        base = ".".join(parts + ([base] if base else []))
    subs = [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in mods]
    return subs + ([base] if len(subs) < len(node.names) and base in mods else [])


def import_graph() -> dict[str, set[str]]:
    mods = _modules()
    graph = {m: set() for m in mods}
    for mod, path in mods.items():
        is_pkg = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                graph[mod].update(t for t in _targets(mod, node, is_pkg, mods) if t != mod)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    x = stack.pop()
                    on.discard(x)
                    comp.append(x)
                    if x == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def _package(mod: str) -> str:
    parts = mod.split(".")
    return parts[1] if parts[0] == "polarref" and len(parts) > 1 else parts[0]


def test_cycle_finder_finds_a_cycle():
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(g) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle():
    found = cycles(import_graph())
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_packages_layered_one_way():
    rank = {p: i for i, row in enumerate(LAYERS) for p in row}
    bad = []
    for mod, targets in import_graph().items():
        a = _package(mod)
        if a not in rank:
            continue
        for t in targets:
            b = _package(t)
            if b in rank and b != a and rank[b] <= rank[a]:
                bad.append(f"{mod} -> {t}")
    assert not bad, "imports against the layering: " + ", ".join(sorted(bad))


def test_nothing_at_the_top_level_but_the_face_and_the_cli():
    top = {p.stem for p in (ROOT / "polarref").glob("*.py")}
    assert top == TOP_LEVEL
    assert not (ROOT / "polarref" / "reconstruction.py").exists()


@pytest.mark.parametrize("pkg", [p.name for p in (ROOT / "polarref").iterdir()
                                 if (p / "__init__.py").is_file()])
def test_no_module_imports_its_own_package_face(pkg):
    """A package's __init__ re-exports; its modules import the defining module instead."""
    face = f"polarref.{pkg}"
    bad = [m for m, t in import_graph().items() if m.startswith(face + ".") and face in t]
    assert not bad, f"{', '.join(bad)} import {face} (its __init__)"


# ---- untyped data across boundaries (issue 29): scripts/layout_counts.py, never more than this ----------
# Counts at the merge of issues 29-35 (stop 38): the layout work brought 29/17/477 down to 19/12/318;
# the branches merged after it added the BA bench's tau/roofline code (ba.bench + bench_report hold
# 201 of the subscripts: its cells are still dicts), ground control and photo sets.
MAX_DICT_RETURNING = 1     # public functions annotated to return a dict (was 29 before issue 29; 3 before
#                            match_pairs/verify_pairs returned PairMatches/VerifiedPairs)
MAX_LOOSE_FIELDS = 0        # dataclass fields typed bare dict / object / Any (was 17)
MAX_STRING_SUBSCRIPTS = 65  # x["key"] outside JSON (de)serialisers (was 477)


def _layout_counts():
    return load_script("layout_counts")


def test_layout_counter_counts_what_it_says(tmp_path):
    counter = _layout_counts()
    pkg = tmp_path / "polarref"
    pkg.mkdir()
    (pkg / "m.py").write_text(
        "from dataclasses import dataclass\nfrom typing import Any, ClassVar\n"
        "def f() -> dict[str, int]: return {}\n"          # counted
        "def _g() -> dict: return {}\n"                    # private: not counted
        "def to_dict(x) -> dict: return {'a': x['b']}\n"   # serialiser: neither counted
        "def h(d) -> int:\n    return d['k'] + d[0]\n"     # one string subscript
        "@dataclass\nclass R:\n    a: dict\n    b: dict[str, Any]\n    c: dict[str, int]\n    d: object | None\n"
        "    V: ClassVar[dict] = {}\n")
    c = counter.count(tmp_path)
    assert c.dict_returning == ["polarref.m:f"]
    assert c.loose_fields == ["polarref.m:R.a", "polarref.m:R.b", "polarref.m:R.d"]
    assert c.string_subscripts == ["polarref.m:7"]


def test_untyped_data_does_not_grow():
    c = _layout_counts().count()
    assert len(c.dict_returning) <= MAX_DICT_RETURNING, c.dict_returning
    assert len(c.loose_fields) <= MAX_LOOSE_FIELDS, c.loose_fields
    assert len(c.string_subscripts) <= MAX_STRING_SUBSCRIPTS, len(c.string_subscripts)


# ---- compare/ split into run/ claims/ twins/ report/ (issue 29) ----
COMPARE_SUBPACKAGES = ("run", "claims", "twins", "report")


def test_compare_holds_its_face_the_schema_and_four_subpackages():
    top = ROOT / "polarref" / "compare"
    assert sorted(p.name for p in top.glob("*.py")) == ["__init__.py", "schema.py"]
    subs = sorted(p.name for p in top.iterdir() if p.is_dir() and (p / "__init__.py").is_file())
    assert subs == sorted(COMPARE_SUBPACKAGES)


# Imports between compare's subpackages (all of them read compare.schema from below). The two
# upward reads: run.pipeline writes the report at the end of a run, report.index reads the twins' tables.
COMPARE_DIRECTIONS = {("twins", "run"), ("twins", "claims"), ("run", "claims"), ("report", "claims"),
                      ("run", "report"), ("report", "twins")}


def test_compare_subpackages_import_in_the_documented_directions():
    found = set()
    for mod, targets in import_graph().items():
        parts = mod.split(".")
        if parts[:2] != ["polarref", "compare"] or len(parts) < 4:
            continue
        for t in targets:
            tp = t.split(".")
            if tp[:2] == ["polarref", "compare"] and len(tp) >= 4 and tp[2] != parts[2]:
                found.add((parts[2], tp[2]))
    assert found <= COMPARE_DIRECTIONS, sorted(found - COMPARE_DIRECTIONS)


def test_tests_mirror_the_packages():
    """Every test file sits in the folder of the package it tests (tests/<package>/...)."""
    top = sorted(p.name for p in (ROOT / "tests").glob("test_*.py"))
    assert top == ["test_layout.py"], top
