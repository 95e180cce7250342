"""A contiguous sub-block of a UAV twin (issue 33): the twin's own world, only some of its views.

A twin such as mappilot (493 views at 1024x768) takes hours to render and adjust on a shared
two-core machine. A sub-block keeps everything that decides the aerotriangulation figures the
twin's: the same mesh (built for the whole flight), camera and GSD, the same GT poses, and the
twin's own pose priors (drawn for all of its views, AR(1) along the whole flight, then cut), so
the sub-block is a piece of the twin, not a smaller scene of its own. It is the views of flight
lines ``[line0, line1)`` at along-track positions ``[pos0, pos1)`` (positions count along +x, so
the serpentine lines line up). Views keep the twin's names (``0173.png``); ``scene.json`` records
the block and each view's index in the twin's flight (``subblock.twin_indices``), which the
priors' correlation follows (``priors.sequence``).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

from synth.config import SceneConfig
from synth.uav import flight_plan, nadir_views

FORMAT = "polarref-twin-subblock/1"


@dataclass(frozen=True)
class SubBlock:
    """Flight lines ``[line0, line1)`` x along-track positions ``[pos0, pos1)`` of twin ``twin``."""

    twin: str
    line0: int
    line1: int
    pos0: int
    pos1: int

    def indices(self, cfg: SceneConfig) -> tuple[int, ...]:
        """Indices (flight order, ascending) of the block's views in the twin ``cfg``."""
        lines, per_line, _, _ = flight_plan(cfg)
        if not (0 <= self.line0 < self.line1 <= lines and 0 <= self.pos0 < self.pos1 <= per_line):
            raise ValueError(f"sub-block lines {self.line0}:{self.line1}, positions {self.pos0}:{self.pos1} "
                             f"outside the twin's {lines} lines x {per_line} positions")
        out = []
        for line in range(self.line0, self.line1):
            for pos in range(self.pos0, self.pos1):
                k = line * per_line + (pos if line % 2 == 0 else per_line - 1 - pos)
                if k < nadir_views(cfg):  # the last line may be short
                    out.append(k)
        return tuple(sorted(out))

    def label(self) -> str:
        return f"{self.twin} lines {self.line0}-{self.line1 - 1} x positions {self.pos0}-{self.pos1 - 1}"


def cut_scene_json(meta: dict, block: SubBlock, indices: tuple[int, ...]) -> dict:
    """The twin's scene.json ``meta`` (every view) cut to ``indices``: views renumbered 1..n,
    names kept, priors cut (their draw over the whole flight kept), the block recorded."""
    out = copy.deepcopy(meta)
    n_twin = len(meta["views"])
    views = []
    for new_id, k in enumerate(indices, start=1):
        v = dict(meta["views"][k])
        v["image_id"] = new_id
        views.append(v)
    out["views"] = views
    if meta.get("priors"):
        out["priors"]["views"] = [meta["priors"]["views"][k] for k in indices]
        out["priors"]["sequence"] = list(indices)
    out["subblock"] = {"format": FORMAT, "twin": block.twin, "twin_views": n_twin,
                       "lines": [block.line0, block.line1], "positions": [block.pos0, block.pos1],
                       "twin_indices": list(indices), "label": block.label()}
    return out
