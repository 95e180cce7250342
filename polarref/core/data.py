"""Locating the external reference data (never copied into the repository)."""

from __future__ import annotations

import os
from pathlib import Path

from polarref.core.errors import DataNotFoundError

REPO_ROOT = Path(__file__).resolve().parents[2]


def data_root() -> Path | None:
    """Return the reference-data folder, or None when it is absent.

    ``$POLARREF_DATA`` wins when set (even if it does not exist, so a typo is not
    silently replaced by another folder); otherwise ``../shared/data`` beside the repo root.
    """
    env = os.environ.get("POLARREF_DATA")
    if env:
        path = Path(env).expanduser()
        return path if path.is_dir() else None
    path = REPO_ROOT.parent / "shared" / "data"
    return path if path.is_dir() else None


def data_path(*parts: str) -> Path:
    """Path of an item inside the reference data; raises DataNotFoundError naming it."""
    root = data_root()
    where = os.environ.get("POLARREF_DATA") or str(REPO_ROOT.parent / "shared" / "data")
    if root is None:
        raise DataNotFoundError(f"reference data folder not found: {where} (set $POLARREF_DATA)")
    path = root.joinpath(*parts)
    if not path.exists():
        raise DataNotFoundError(f"reference data item not found: {path}")
    return path


def cache_root() -> Path:
    """Folder for reusable derived artefacts (renders, features); ``$POLARREF_CACHE`` wins."""
    env = os.environ.get("POLARREF_CACHE")
    if env:
        return Path(env).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "polarref"
