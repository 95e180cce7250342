"""``polarref doctor``: what is installed, which Mitsuba variant will be used and why."""

from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import sys

NAME = "doctor"
HELP = "print versions, the Mitsuba variant that will be used and why, and where the data is"

PACKAGES = ("numpy", "scipy", "sympy", "mitsuba", "drjit", "pycolmap", "cv2", "matplotlib")


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


def collect() -> dict[str, object]:
    """Everything doctor reports, as plain data (also recorded in reports)."""
    from polarref import __version__
    from polarref.commands._registry import command_modules
    from polarref.core.data import data_root

    report: dict[str, object] = {
        "polarref": __version__,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
    }
    from polarref.core.provenance import cpu_model, git_state

    report["cpu_model"] = cpu_model()
    report["git_commit"], report["git_dirty"] = git_state()
    report.update({name: _version(name) for name in PACKAGES})
    try:
        from synth.mitsuba_variant import selected_variant

        choice = selected_variant()
        report["mitsuba_variant"] = choice.variant
        report["mitsuba_variant_reason"] = choice.reason
    except Exception as exc:
        report["mitsuba_variant"] = None
        report["mitsuba_variant_reason"] = f"variant selection failed: {type(exc).__name__}: {exc}"
    report["pycolmap_cuda"] = _pycolmap_cuda()
    root = data_root()
    env = os.environ.get("POLARREF_DATA")
    report["data"] = str(root) if root else None
    report["data_reason"] = (
        f"found at {root}" + (" ($POLARREF_DATA)" if env else "")
        if root else f"not found ({'$POLARREF_DATA=' + env if env else '../shared/data beside the repo'})"
    )
    _, failed = command_modules()
    report["broken_commands"] = failed
    return report


def execution_info() -> dict[str, object]:
    """The execution mode in use (``--workers``/``--scheduler``) and the workers it sees.

    Kept out of :func:`collect` (recorded in reports) so that asking for versions never starts
    or contacts a cluster.
    """
    import dataclasses

    from polarref.core import execution

    desc = execution.current().describe()
    return {"execution": desc.mode, "execution_detail": desc.detail,
            "workers": [dataclasses.asdict(w) for w in desc.workers]}


def run(args: argparse.Namespace) -> int:
    report = collect()
    report.update(execution_info())
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    width = max(len(k) for k in report)
    for key, value in report.items():
        if key == "broken_commands":
            value = ", ".join(f"{k} ({v})" for k, v in value.items()) or "none"
        if key == "workers":
            value = f"{len(value)}: " + ", ".join(f"{w['address']} (pid {w['pid']}, {w['nthreads']} thread)"
                                                 for w in value) if value else "none (serial)"
        print(f"{key:<{width}}  {value}")
    return 0
