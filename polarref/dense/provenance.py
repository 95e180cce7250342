"""The dense stage's provenance record: :func:`polarref.core.provenance.collect` as a typed record."""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import metadata


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
    from polarref.core.provenance import collect as collect_env

    env = collect_env(seeds, threads)
    for dist in ("open3d-cpu", "open3d"):  # the dense stage's one extra dependency
        try:
            env["versions"][dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    names = {f for f in Provenance.__dataclass_fields__ if f != "command"}
    return Provenance(**{k: v for k, v in env.items() if k in names}, command=command)
