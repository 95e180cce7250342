"""Records of the bundle adjustments a mapper ran (ours and pycolmap's), as they appear in
``metrics.json``'s ``ba`` list (:class:`polarref.sfm.report.SfMReport`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from polarref.ba.export_problem import ExportedOptions, MapperResult
from polarref.ba.options import BASummary, IterationRecord
from polarref.ba.problem import BAProblem


@dataclass
class ColmapBARun:
    """pycolmap's (Ceres) bundle adjustment of one mapper step."""

    loss: str
    wall_s: float
    refine: list[str]
    initial_cost: float | None = None
    final_cost: float | None = None
    num_successful_steps: float | None = None
    num_unsuccessful_steps: float | None = None


@dataclass(frozen=True)
class ExportedBA:
    """A global BA as it entered our solver (``problem``: a copy taken before ``prepare``), the
    options it ran with and what it ended with; kept only when the export is asked for."""

    problem: BAProblem
    options: ExportedOptions
    result: MapperResult


@dataclass
class BARun:
    """One bundle adjustment inside the mapper (``polarref.sfm.bundle.adjust``)."""

    param: str                           # BA parameterization, or "colmap"
    kind: str = ""                       # global | local (set by the mapper)
    skipped: str = ""                    # why it did not run ("" when it ran)
    summary: BASummary | None = None     # polarref's adjusters
    colmap: ColmapBARun | None = None    # ba="colmap"
    num_registered: int | None = None    # global: registered images
    image: int | None = None             # local: the image just registered
    num_variable: int | None = None      # local: images with variable poses
    num_fixed: int | None = None         # local: images held fixed
    exported: ExportedBA | None = None   # adjust(export=True): the problem and result (not in to_json)

    @property
    def wall_s(self) -> float:
        run = self.summary or self.colmap
        return float(run.wall_s) if run is not None else 0.0

    @property
    def initial_cost(self) -> float | None:
        run = self.summary or self.colmap
        return None if run is None else run.initial_cost

    @property
    def refined_intrinsics(self) -> bool:
        """Whether this run refined any intrinsics group."""
        if self.colmap is not None:
            return bool(self.colmap.refine)
        return self.summary is not None and bool(self.summary.intrinsics)

    @property
    def trace(self) -> list[IterationRecord]:
        return list(self.summary.trace) if self.summary is not None else []

    def to_json(self) -> dict[str, Any]:
        """Flat JSON form: the adjuster's scalars and iteration trace, then the mapper's fields."""
        out: dict[str, Any] = {"param": self.param}
        if self.skipped:
            out["skipped"] = self.skipped
        elif self.colmap is not None:
            out.update({k: v for k, v in dataclasses.asdict(self.colmap).items() if v is not None})
        elif self.summary is not None:
            # keep scalars and the iteration trace (convergence plots); drop bulky state dumps
            info = {k: v for k, v in dataclasses.asdict(self.summary).items() if k != "points_state"
                    and (k in ("trace", "intrinsics") or not isinstance(v, (list, np.ndarray)))
                    and not (k == "first_stage_termination" and v is None)}
            if not info["intrinsics"]:
                info.pop("intrinsics")
            out.update(info)
        out.update({k: getattr(self, k) for k in ("kind", "num_registered", "image", "num_variable", "num_fixed")
                    if getattr(self, k) not in (None, "")})
        return out
