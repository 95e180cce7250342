"""Typed results of the claim experiments (:mod:`polarref.compare.claims.experiments`) and of the
derivation evidence (:func:`polarref.compare.claims.jobs.derivation_evidence`).

The field names are the JSON keys of ``runs/claims/experiments.json`` and ``derivations.json``;
the files are written with :func:`polarref.core.records.save`. A section that raised keeps only its
``error`` (every other field at its default). Figures that are undefined (NaN, or an infinite
condition number) are ``None`` once recorded, as everywhere in polarref's JSON.
"""

from __future__ import annotations

from dataclasses import dataclass, field

# ---- C3/C4: timing --------------------------------------------------------------------------


@dataclass
class TimingSeed:
    """One form on one seed: the first (untimed-repeat) run's accuracy and the median wall time."""

    seed: int
    iterations: int
    final_rms_px: float | None
    rotation_error_deg: float | None          # mean relative-rotation error
    final_pixel_cost: float | None = None
    termination: str = ""
    wall_s: float | None = None               # median over the timed repeats


@dataclass
class TimedRun:
    wall_s: float
    seed: int


@dataclass
class TimingForm:
    per_seed: list[TimingSeed] = field(default_factory=list)
    runs: list[TimedRun] = field(default_factory=list)        # every timed run
    trace: list[list[float]] = field(default_factory=list)    # [iteration, wall_s, cost], first seed
    error: str = ""


@dataclass
class RealRun:
    """One form on one real problem: the wall time of each interleaved repeat, and the first
    repeat's outcome (the solves are deterministic: every repeat ends the same)."""

    walls: list[float] = field(default_factory=list)
    final_rms_px: float | None = None         # pixel RMS (the forms' costs differ: polar adds a residual)
    iterations: int | None = None
    termination: str = ""


@dataclass
class RealProblemTiming:
    """C4 on one problem of the reference data (issue 30); ``skipped``: why it did not run."""

    name: str
    description: str = ""
    skipped: str = ""
    forms: dict[str, RealRun] = field(default_factory=dict)     # form -> its runs


@dataclass
class Timing:
    problem: str = ""
    trace_problem: str = ""
    seeds: list[int] = field(default_factory=list)
    params: dict[str, TimingForm] = field(default_factory=dict)   # form -> its runs
    error: str = ""
    real: list[RealProblemTiming] = field(default_factory=list)   # C4's real problems


# ---- C6/C7: conditioning --------------------------------------------------------------------


@dataclass
class ConditioningRow:
    """One form at one seed's true solution (:func:`polarref.compare.claims.experiments.conditioning_one`)."""

    cond_JtJ: float | None
    cond_JtJ_scaled: float | None
    cond_schur: float | None
    cond_schur_scaled: float | None
    mean_abs_point_corr: float | None
    max_abs_point_corr: float | None
    point_params: int = 3
    error: str = ""
    # frame-invariant: parameters in the scene-anchored per-point frame, gauge by distance
    mean_abs_point_corr_ray: float | None = None
    max_abs_point_corr_ray: float | None = None
    cond_JtJ_block: float | None = None       # block-Jacobi-scaled, distance gauge: frame-invariant


@dataclass
class ConditioningForm:
    per_seed: list[ConditioningRow] = field(default_factory=list)
    per_seed_rescaled: list[ConditioningRow] = field(default_factory=list)   # lengths x unit_rescale
    error: str = ""


@dataclass
class Conditioning:
    problem: str = ""
    seeds: list[int] = field(default_factory=list)
    gauge: str = ""
    unit_rescale: float | None = None
    params: dict[str, ConditioningForm] = field(default_factory=dict)
    error: str = ""


# ---- C8 / C5: robustness --------------------------------------------------------------------


@dataclass
class RobustRun:
    """One form (or the start point) on one seed of one level, scored by the success rule."""

    seed: int
    success: bool
    rotation_error_deg: float | None
    bearing_error_deg_median: float | None = None
    bearing_error_deg_p95: float | None = None
    flipped_fraction: float | None = None
    initial_rms_px: float | None = None       # BA runs only
    final_rms_px: float | None = None
    iterations: int | None = None
    inlier_observations: int | None = None    # outlier levels only (C5's counts)
    tie_points: int | None = None
    # low-parallax levels only: points scored and those whose depth is within the pre-registered
    # tolerance (experiment_problems.depth_errors); the run's point success rate is
    # success x points_depth_ok / points_scored (claims_robustness.point_rate)
    points_scored: int | None = None
    points_depth_ok: int | None = None


@dataclass
class FormRuns:
    runs: list[RobustRun] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)   # runs that raised


@dataclass
class Robustness:
    outliers: dict[str, dict[str, FormRuns]] = field(default_factory=dict)      # fraction -> form -> runs
    low_parallax: dict[str, dict[str, FormRuns]] = field(default_factory=dict)  # baseline/depth -> form -> runs
    seeds_run: int = 0
    success_rule: str = ""
    outlier_problem: str = ""
    parallax_problem: str = ""
    error: str = ""


# ---- invariance: the experiments rerun in other frames of the world ---------------------------


@dataclass
class DrawFrame:
    """One similarity ``world' = scale R world + t`` (:class:`~polarref.compare.claims.experiment_problems.Similarity`)."""

    index: int
    kind: str                  # "similarity" (seeded random draw) or "units" (metres -> millimetres)
    scale: float
    rotation_deg: float        # angle of R
    translation: float         # |t| in the scene's units


@dataclass
class InvarianceDraw:
    """What one draw reran in its frame: every conditioning seed (C6/C7), every form on one timing
    seed (C3/C4) and every form plus the start point on one robustness cell (C5/C8)."""

    frame: DrawFrame
    conditioning: Conditioning | None = None
    timing_seed: int | None = None
    timing: dict[str, TimingSeed] = field(default_factory=dict)       # form -> its run
    robust_half: str = ""                                             # "outliers" or "low_parallax"
    robust_level: str = ""
    robust_seed: int | None = None
    robust: dict[str, FormRuns] = field(default_factory=dict)        # form (and "start") -> runs
    error: str = ""


@dataclass
class Invariance:
    seed: int                  # of the draws
    draws: list[InvarianceDraw] = field(default_factory=list)
    error: str = ""


@dataclass
class Experiments:
    """Everything :func:`polarref.compare.claims.experiments.run_all` measured."""

    seed: int
    conditioning: Conditioning | None = None
    timing: Timing | None = None
    robustness: Robustness | None = None
    invariance: Invariance | None = None
    wall_s: dict[str, float] = field(default_factory=dict)   # experiment -> seconds


# ---- C1/C2: derivation evidence -------------------------------------------------------------


@dataclass
class CaseEvidence:
    """One sampled case of ``derivations.paper.CaseEvidence`` (the same field names; runtime code
    does not import the derivations package, which imports SymPy). Max errors in rad; a figure
    that was NaN is None once recorded."""

    case: str
    samples: int | None = None
    excluded_near_pole: int | None = None
    printed_eq3_max_err: float | None = None
    printed_eq3_nan: int = 0
    printed_is_complement_max_err: float | None = None
    corrected_eq3_max_err: float | None = None
    corrected_eq3_nan: int | None = None
    corrected_eq3_max_err_all: float | None = None
    stable_max_err: float | None = None
    generated_max_err: float | None = None
    stable_vs_mpmath_max_err: float | None = None
    stable_all_vs_mpmath_max_err: float | None = None
    truth_vs_mpmath_max_err: float | None = None
    eq4_max_err: float | None = None
    eq5_sin_max_err: float | None = None
    eq5_nan: int | None = None
    eq8_max_err: float | None = None
    claim7_max_err: float | None = None


@dataclass
class DerivationEvidence:
    """``derivations.paper.all_case_evidence`` as data."""

    cases: list[CaseEvidence]
    samples_per_case: int
    seed: int | None = None
