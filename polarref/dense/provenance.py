"""The dense stage's provenance record: :func:`polarref.core.provenance.collect` as a typed record."""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import metadata

from polarref.core.provenance import collect_record


@dataclass
class Provenance:
    git_commit: str | None
    git_dirty: bool | None
    cpu_count: int
    cpu_model: str | None
    machine: str
    platform: str
    python: str
    versions: dict[str, str] = field(default_factory=dict)
    threads: dict[str, int] = field(default_factory=dict)
    seeds: dict[str, int] = field(default_factory=dict)
    command: str = ""


def collect(command: str = "", seeds: dict[str, int] | None = None, threads: dict[str, int] | None = None) -> Provenance:
    env = collect_record(seeds, threads)
    versions = dict(env.versions)
    for dist in ("open3d-cpu", "open3d"):  # the dense stage's one extra dependency
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return Provenance(env.git_commit, env.git_dirty, env.cpu_count, env.cpu_model, env.machine, env.platform,
                      env.python, versions, dict(env.threads), dict(env.seeds), command)
