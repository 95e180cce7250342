"""Minimal provenance record for dense outputs (git commit and dirty flag, machine, versions).

Issue 12 adds a project-wide provenance helper; until it lands this is the dense stage's own.
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

PACKAGES = ("numpy", "scipy", "opencv-python-headless", "open3d-cpu", "open3d", "pycolmap")


@dataclass
class Provenance:
    git_commit: str | None
    git_dirty: bool | None
    machine: str
    cpu_count: int
    python: str
    versions: dict[str, str] = field(default_factory=dict)
    command: str = ""
    seeds: dict[str, int] = field(default_factory=dict)


def _git(args: list[str], cwd: Path) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def collect(command: str = "", seeds: dict[str, int] | None = None) -> Provenance:
    from polarref import __version__

    repo = Path(__file__).resolve().parents[2]
    commit = _git(["rev-parse", "HEAD"], repo)
    status = _git(["status", "--porcelain", "--untracked-files=no"], repo)
    versions = {"polarref": __version__}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return Provenance(commit, None if status is None else bool(status),
                      f"{platform.node()} {platform.machine()} {platform.platform()}",
                      int(os.cpu_count() or 0), sys.version.split()[0], versions, command, dict(seeds or {}))
