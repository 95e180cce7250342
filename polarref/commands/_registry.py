"""The registry of CLI commands: every public module of :mod:`polarref.commands` is one
command (``NAME``, ``HELP``, ``add_arguments``, ``run``); read by the CLI and by ``doctor``."""

from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path
from types import ModuleType


def command_modules() -> tuple[list[ModuleType], dict[str, str]]:
    """Import every command module; return (loaded, {name: import error})."""
    loaded: list[ModuleType] = []
    failed: dict[str, str] = {}
    for info in sorted(pkgutil.iter_modules([str(Path(__file__).parent)]), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        try:
            module = importlib.import_module(f"polarref.commands.{info.name}")
        except Exception as exc:  # a broken stage must not take the whole CLI down
            failed[info.name] = f"{type(exc).__name__}: {exc}"
            continue
        loaded.append(module)
    return loaded, failed
