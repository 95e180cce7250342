"""``polarref compare --preset``: every setting a preset decides, in one typed record.

A preset name is resolved once (:func:`get`, at the command line or in :class:`CompareConfig`)
and the record travels from there; the CLI's choices are :data:`NAMES`. The synthetic scene's
size comes from ``synth.config.preset`` under the same name.
"""

from __future__ import annotations

from dataclasses import dataclass

from polarref.core.errors import PolarrefError


@dataclass(frozen=True)
class ComparePreset:
    name: str                     # small | default | large (also the synthetic render preset)
    method_timeout_s: float       # per-method wall-clock limit
    # claim experiments' budget: inf runs every seed (no deadline, so reruns repeat exactly)
    claims_budget_s: float
    # whole-run budget (rendering included); None = unlimited. The default run must finish in
    # 5 minutes on 2 cores: methods run in RUN_ORDER, each may use what is left after keeping
    # MIN_METHOD_S for every later method and REPORT_RESERVE_S for claims and the report
    run_budget_s: float | None
    max_width: int                # real images wider than this are downscaled (SIFT on 3072 px is too slow)
    sfm_preset: str               # polarref.sfm.config.PRESETS key of our pipeline


SMALL = ComparePreset("small", method_timeout_s=120.0, claims_budget_s=float("inf"), run_budget_s=None,
                      max_width=768, sfm_preset="small")
# the default run's claims must fit its 290 s budget (10 + 5 seeds need ~40 s on 2 idle cores)
DEFAULT = ComparePreset("default", method_timeout_s=90.0, claims_budget_s=60.0, run_budget_s=290.0,
                        max_width=1024, sfm_preset="default")
LARGE = ComparePreset("large", method_timeout_s=1800.0, claims_budget_s=300.0, run_budget_s=None,
                      max_width=1536, sfm_preset="default")
PRESETS: dict[str, ComparePreset] = {p.name: p for p in (SMALL, DEFAULT, LARGE)}
NAMES = tuple(PRESETS)


def get(name: str) -> ComparePreset:
    """The preset ``name``; PolarrefError naming the choices for any other name."""
    if name not in PRESETS:
        raise PolarrefError(f"unknown preset {name!r} (choose from {', '.join(NAMES)})")
    return PRESETS[name]
