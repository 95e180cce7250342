"""``polarref doctor``: what is installed, which Mitsuba variant will be used and why."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import os
import platform
import sys
from dataclasses import dataclass, field

from polarref import __version__
from polarref.commands._registry import command_modules
from polarref.core import execution
from polarref.core.data import data_root
from polarref.core.provenance import cpu_model, git_state

NAME = "doctor"
HELP = "print versions, the Mitsuba variant that will be used and why, and where the data is"

PACKAGES = ("numpy", "scipy", "sympy", "mitsuba", "drjit", "pycolmap", "cv2", "matplotlib")


@dataclass(frozen=True)
class VariantChoice:
    """The Mitsuba variant synth will load (None when the choice failed) and why."""

    variant: str | None
    reason: str


@dataclass(frozen=True)
class DataFolder:
    """Where the shared data was found (None: not found) and how."""

    path: str | None
    reason: str


@dataclass(frozen=True)
class Doctor:
    """Everything doctor reports. ``versions``: package -> version or "missing (...)", in
    :data:`PACKAGES` order; ``broken_commands``: command module -> why it failed to import."""

    polarref: str
    python: str
    platform: str
    cpu_count: int | None
    cpu_model: str
    git_commit: str
    git_dirty: bool | None
    versions: dict[str, str]
    mitsuba: VariantChoice
    pycolmap_cuda: str
    data: DataFolder
    broken_commands: dict[str, str] = field(default_factory=dict)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")


def _version(name: str) -> str:
    try:
        module = importlib.import_module(name)
    except Exception as exc:  # doctor must report, never crash
        return f"missing ({type(exc).__name__}: {exc})"
    return str(getattr(module, "__version__", "unknown version"))


def _pycolmap_cuda() -> str:
    try:
        import pycolmap
    except Exception as exc:
        return f"unknown (pycolmap not importable: {type(exc).__name__})"
    return "yes" if getattr(pycolmap, "has_cuda", False) else "no"


def _variant() -> VariantChoice:
    try:  # synth sits beside polarref and loads Mitsuba lazily: deferred so doctor runs without it
        from synth.mitsuba_variant import selected_variant

        choice = selected_variant()
        return VariantChoice(choice.variant, choice.reason)
    except Exception as exc:
        return VariantChoice(None, f"variant selection failed: {type(exc).__name__}: {exc}")


def _data() -> DataFolder:
    root = data_root()
    env = os.environ.get("POLARREF_DATA")
    if root:
        return DataFolder(str(root), f"found at {root}" + (" ($POLARREF_DATA)" if env else ""))
    return DataFolder(None, f"not found ({'$POLARREF_DATA=' + env if env else '../shared/data beside the repo'})")


def collect() -> Doctor:
    """Everything doctor reports (also recorded in reports)."""
    commit, dirty = git_state()
    _, failed = command_modules()
    return Doctor(str(__version__), sys.version.split()[0], platform.platform(), os.cpu_count(), cpu_model(),
                  commit, dirty, {name: _version(name) for name in PACKAGES}, _variant(), _pycolmap_cuda(),
                  _data(), dict(failed))


def execution_info() -> execution.Description:
    """The execution mode in use (``--workers``/``--scheduler``) and the workers it sees.

    Kept out of :func:`collect` (recorded in reports) so that asking for versions never starts
    or contacts a cluster.
    """
    return execution.current().describe()


def to_json(doc: Doctor, ex: execution.Description) -> dict[str, object]:
    """The ``--json`` object: one flat level, the keys scripts and tests read."""
    return {"polarref": doc.polarref, "python": doc.python, "platform": doc.platform, "cpu_count": doc.cpu_count,
            "cpu_model": doc.cpu_model, "git_commit": doc.git_commit, "git_dirty": doc.git_dirty, **doc.versions,
            "mitsuba_variant": doc.mitsuba.variant, "mitsuba_variant_reason": doc.mitsuba.reason,
            "pycolmap_cuda": doc.pycolmap_cuda, "data": doc.data.path, "data_reason": doc.data.reason,
            "broken_commands": doc.broken_commands, "execution": ex.mode, "execution_detail": ex.detail,
            "workers": [dataclasses.asdict(w) for w in ex.workers]}


def _text(doc: Doctor, ex: execution.Description) -> list[tuple[str, object]]:
    workers = (f"{len(ex.workers)}: " + ", ".join(f"{w.address} (pid {w.pid}, {w.nthreads} thread)"
                                                  for w in ex.workers)) if ex.workers else "none (serial)"
    return [("polarref", doc.polarref), ("python", doc.python), ("platform", doc.platform),
            ("cpu_count", doc.cpu_count), ("cpu_model", doc.cpu_model), ("git_commit", doc.git_commit),
            ("git_dirty", doc.git_dirty), *doc.versions.items(), ("mitsuba_variant", doc.mitsuba.variant),
            ("mitsuba_variant_reason", doc.mitsuba.reason), ("pycolmap_cuda", doc.pycolmap_cuda),
            ("data", doc.data.path), ("data_reason", doc.data.reason),
            ("broken_commands", ", ".join(f"{k} ({v})" for k, v in doc.broken_commands.items()) or "none"),
            ("execution", ex.mode), ("execution_detail", ex.detail), ("workers", workers)]


def run(args: argparse.Namespace) -> int:
    doc, ex = collect(), execution_info()
    if args.json:
        print(json.dumps(to_json(doc, ex), indent=2))
        return 0
    rows = _text(doc, ex)
    width = max(len(k) for k, _ in rows)
    for key, value in rows:
        print(f"{key:<{width}}  {value}")
    return 0
