"""Bundle-adjustment options and the summary every solve returns."""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass, field

import numpy as np

from polarref.ba.losses import LOSSES
from polarref.ba.parameterization import PARAMS  # the one registry of form names (re-exported)
from polarref.ba.reduced_solve import ReducedSolver
from polarref.ba.refine import parse_refine

SOLVERS = ("lm", "gn")  # Levenberg-Marquardt | Gauss-Newton (every step taken, no damping)
DAMPINGS = ("ceres", "nielsen")
VIEW_ANGLE_ROWS = ("mapped", "explicit")
REDUCED_SOLVERS = tuple(s.value for s in ReducedSolver)
# LM strategy per form where BAOptions leaves it None, measured (reports/bench-ba/
# parallaxba-parity.md, iterations to the common optimum): Ceres' Jacobi-scaled trust region with
# the gauge held for every form. Nielsen's (H + mu I) ties it on the fake pile in the free gauge
# (14) but needs 2-3x the iterations on a forward rig at baseline/depth 3e-4 (parallax 189 vs 80,
# polar 153 vs 45), where unscaled damping suits the tiny parallax angles badly; the free gauge
# saves 40 % on the fake pile (14 vs 23) and 0-1 on synthetic problems but costs 1.1-1.5x on that
# rig, and the Euclidean form keeps Ceres (Ladybug-49: 7 vs 24-27 with Nielsen).
DEFAULT_DAMPING = {"euclidean": "ceres", "parallax": "ceres", "polar": "ceres", "angular": "ceres"}
DEFAULT_LM_GAUGE = {"euclidean": "fixed", "parallax": "fixed", "polar": "fixed", "angular": "fixed"}


@dataclass(frozen=True)
class BAOptions:
    """Options of :func:`polarref.ba.adjust` / :func:`polarref.ba.solver.solve`.

    Change with ``dataclasses.replace``. Tolerances follow Ceres' definitions.
    """

    param: str = "euclidean"  # landmark/residual parameterization, one of PARAMS
    loss: str = "trivial"  # robust loss on each residual block: trivial | huber | cauchy
    loss_scale: float = 1.0  # loss scale a [px-equivalent]: Huber/Cauchy knee at |r| = a
    max_iterations: int = 100  # LM iterations, accepted and rejected steps both count (Ceres)
    solver: str = "lm"  # "lm" or "gn" (Gauss-Newton: undamped, every finite step taken)
    # LM damping: "ceres" = trust region, (H + diag(H) / radius); "nielsen" = ParallaxBA's
    # (H + mu I), mu0 = nielsen_tau * max diag(H), Nielsen's update; None = the form's default
    damping: str | None = None
    nielsen_tau: float = 1e-6  # ParallaxBA's tau
    # LM only (None = the form's default): "free" releases the 7 gauge DoF during the solve
    # (damped, not held) and maps the result back into the held gauge (ba/gauge.py); "fixed"
    # holds them. Gauss-Newton always holds them.
    lm_gauge: str | None = None
    function_tolerance: float = 1e-6  # stop when |d cost| / cost < this after an accepted step
    gradient_tolerance: float = 1e-10  # stop when max |gradient| < this
    parameter_tolerance: float = 1e-8  # stop when |step| < this * (|x| + this)
    initial_trust_radius: float = 1e4  # 1 / initial LM damping mu (Ceres' default)
    max_trust_radius: float = 1e16  # cap on the trust radius
    # largest growth of the radius after one step: radius /= max(1 / this, 1 - (2 rho - 1)^3).
    # Ceres' rule is 3; above 3 only steps with gain rho > 0.94 grow faster (the model was
    # near exact, so the damping, not the model, limited the step). Measured
    # (reports/bench-ba-scale/lm-growth.md, 4 forms x 8 bench problems, LM iterations to the
    # stopping rule): 336 at 3, 320 at 30; synth-200 6 -> 4 in three forms, Ladybug-49 Euclidean
    # 7 -> 6; final objectives within +2.6e-8 relative, below the function tolerance.
    max_radius_growth: float = 30.0
    min_trust_radius: float = 1e-32  # stop (failure) below this radius
    staged: bool = False  # angular only: theta-only residuals first, then theta and phi jointly
    sigma_px: float = 1.0  # pixel noise used to weight angular residuals into px-equivalent units
    max_sigma_phi: float = 0.05  # angular: use phi only where its propagated sigma <= this [rad]
    # angular, phi-gated observations: "chart" = theta (cos phi, sin phi), smooth at the axis;
    # "theta" = theta only (a cone at the axis; stalls LM when rays cross it)
    axis_residual: str = "chart"
    dense_max_cameras: int = 700  # reduced camera system solved densely up to this many cameras
    # reduced camera system solver (reduced_solve.py): "auto" = dense Cholesky up to
    # dense_max_cameras, sparse LU up to pcg_min_cameras, PCG (block-Jacobi) above; or forced
    reduced_solver: str = "auto"
    pcg_min_cameras: int = 2000
    pcg_rtol: float = 1e-8  # PCG stops at |b - S x| <= pcg_rtol |b|
    pcg_max_iterations: int = 1000
    # per-iteration sums: "numba" compiled kernels (ba/kernels.py), "numpy" the reference
    # path, "auto" numba when it imports
    kernels: str = "auto"
    # three-slot forms, kernel path, dense S: "xspace" eliminates the points in the variable
    # y = dq + B dc (ba/xspace.py: no anchor cross terms, the same LM step to rounding);
    # "cross" the reference (anchor cross terms in the build and the Schur pass)
    anchor_schur: str = "xspace"
    # polar, kernel path: "mapped" builds the normal equations from two whitened rows per
    # observation, the view-angle row being a map of the pixel rows (ba/row_map.py: the same
    # normal equations to rounding); "explicit" the reference, three rows
    view_angle_row: str = "mapped"
    # BLAS threads inside the solve (threadpoolctl); None leaves the process setting alone. One
    # thread is fastest here: the BLAS calls are small and multi-threaded OpenBLAS on 2 busy
    # cores spent 0.64 s instead of 0.014 s in the Ladybug-49 Cholesky solves.
    blas_threads: int | None = 1
    # self-calibration (intrinsics.py): intrinsics groups refined, subset of ("focal", "pp",
    # "dist"); () holds the intrinsics fixed (the solve is then exactly the fixed-camera one)
    refine: tuple = ()
    # refine the principal point of an intrinsics group of one image too (else held, with a
    # warning: one image does not separate it from the rotation)
    refine_pp_single: bool = False

    def __post_init__(self) -> None:
        if self.param not in PARAMS:
            raise ValueError(f"unknown BA parameterization {self.param!r}; choose {', '.join(PARAMS)}")
        if self.loss not in LOSSES:
            raise ValueError(f"unknown loss {self.loss!r}; choose {', '.join(LOSSES)}")
        if not 0 < self.loss_scale < float("inf"):
            raise ValueError(f"loss_scale must be finite and > 0, got {self.loss_scale}")
        if self.solver not in SOLVERS:
            raise ValueError(f"unknown solver {self.solver!r}; choose {', '.join(SOLVERS)}")
        if self.damping is not None and self.damping not in DAMPINGS:
            raise ValueError(f"unknown damping {self.damping!r}; choose {', '.join(DAMPINGS)}")
        if self.lm_gauge is not None and self.lm_gauge not in ("free", "fixed"):
            raise ValueError(f"unknown lm_gauge {self.lm_gauge!r}; choose free or fixed")
        if not self.max_radius_growth >= 1.0:
            raise ValueError(f"max_radius_growth must be >= 1, got {self.max_radius_growth}")
        if not self.nielsen_tau > 0:
            raise ValueError(f"nielsen_tau must be > 0, got {self.nielsen_tau}")
        if self.kernels not in ("auto", "numba", "numpy"):
            raise ValueError(f"unknown kernels {self.kernels!r}; choose auto, numba or numpy")
        if self.anchor_schur not in ("xspace", "cross"):
            raise ValueError(f"unknown anchor_schur {self.anchor_schur!r}; choose xspace or cross")
        if self.view_angle_row not in VIEW_ANGLE_ROWS:
            raise ValueError(f"unknown view_angle_row {self.view_angle_row!r}; choose "
                             f"{', '.join(VIEW_ANGLE_ROWS)}")
        if self.axis_residual not in ("chart", "theta"):
            raise ValueError(f"unknown axis_residual {self.axis_residual!r}; choose chart or theta")
        if self.reduced_solver not in REDUCED_SOLVERS:
            raise ValueError(f"unknown reduced_solver {self.reduced_solver!r}; choose "
                             f"{', '.join(REDUCED_SOLVERS)}")
        if not (0 < self.pcg_rtol < 1 and self.pcg_max_iterations >= 1):
            raise ValueError(f"pcg_rtol must be in (0, 1) and pcg_max_iterations >= 1, got "
                             f"{self.pcg_rtol}, {self.pcg_max_iterations}")
        if self.blas_threads is not None and self.blas_threads < 1:
            raise ValueError(f"blas_threads must be >= 1 or None, got {self.blas_threads}")
        if self.refine:
            object.__setattr__(self, "refine", parse_refine(self.refine))
        if self.max_iterations < 0:
            raise ValueError(f"max_iterations must be >= 0, got {self.max_iterations}")


@dataclass
class IterationRecord:
    """One LM iteration of the trace (for plots)."""

    iteration: int
    cost: float  # objective after the iteration (the new one if accepted)
    accepted: bool
    trust_radius: float  # Ceres: radius used for this step (mu = 1 / radius); Nielsen / GN: 0
    step_norm: float
    gradient_max_norm: float
    wall_s: float  # since the start of the solve
    damping: float = float("nan")  # mu of this step: (H + mu D) dx = -g (0 in Gauss-Newton)
    gain: float = float("nan")  # actual / predicted (model) cost decrease of this step


class Termination(enum.StrEnum):
    """Why a bundle adjustment stopped (Ceres' names where Ceres has the same rule).

    A ``str`` subclass: it compares equal to, and serialises as, its value.
    """

    FUNCTION_TOLERANCE = "function_tolerance"
    GRADIENT_TOLERANCE = "gradient_tolerance"
    PARAMETER_TOLERANCE = "parameter_tolerance"
    MAX_ITERATIONS = "max_iterations"
    LINEAR_SOLVER_FAILURE = "linear_solver_failure"
    NON_FINITE_COST = "non_finite_cost"
    MAX_DAMPING = "max_damping"              # Nielsen damping grew past its limit
    MIN_TRUST_RADIUS = "min_trust_radius"    # Ceres-style trust region shrank past its limit


@dataclass
class IntrinsicsResult:
    """Refined intrinsics of one camera group (typed record for summaries and metrics)."""

    group: int
    model: str
    names: tuple[str, ...]
    initial: list[float]
    refined: list[float]
    refined_names: tuple[str, ...]  # the parameters that were free
    num_images: int

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class BASummary:
    """Result of one bundle adjustment (the problem is updated in place)."""

    param: str
    loss: str
    initial_cost: float  # objective 1/2 sum rho(|r|^2) of the chosen parameterization
    final_cost: float
    initial_pixel_cost: float  # 1/2 sum rho(|uv - proj|^2): one cost definition for all forms
    final_pixel_cost: float
    initial_rms_px: float  # sqrt(mean squared pixel-residual component), no robust loss
    final_rms_px: float
    iterations: int  # LM iterations (accepted + rejected)
    accepted_iterations: int
    wall_s: float
    termination: Termination  # a plain string is converted (ValueError for an unknown one)
    num_cameras: int
    num_points: int
    num_observations: int
    num_variable_cameras: int
    gauge: str  # which 7 DoF were fixed, in words
    exclusions: dict[str, int] = field(default_factory=dict)  # what was left out and how many
    linear_solver: str = ""
    rejected_iterations: int = 0  # iterations - accepted_iterations
    solver: str = "lm"  # lm | gn
    damping: str = ""  # ceres | nielsen (LM), none (Gauss-Newton)
    trace: list[IterationRecord] = field(default_factory=list)
    time_in: dict[str, float] = field(default_factory=dict)  # seconds per solver phase (profiling)
    # seconds before the first LM iteration (validation, landmarks, index structures, first
    # evaluation); (wall_s - setup_s) / iterations is the steady per-iteration cost
    setup_s: float = 0.0
    # observations with depth <= 0 in their camera, initial/final, on the XYZ geometry (the
    # input and the written-back points), the same count for every parameterization
    behind_camera: dict[str, int] = field(default_factory=dict)
    points_state: np.ndarray | None = field(default=None, repr=False)  # (P, 3) internal landmark params
    # parallax forms (omega kept in [0, pi - margin]): points ending at_lower (omega = 0, at
    # infinity along +d, written back FAR away) / at_upper, and accepted steps that were clipped
    point_bounds: dict[str, int] = field(default_factory=dict)
    # self-calibration: one record per camera group
    intrinsics: list[IntrinsicsResult] = field(default_factory=list)
    # two-stage polar solve (theta-only, then joint): why the first stage stopped; None otherwise
    first_stage_termination: Termination | None = None

    def __post_init__(self) -> None:
        self.termination = Termination(self.termination)

    @property
    def termination_text(self) -> str:
        """The termination in words, both stages of a two-stage solve."""
        if self.first_stage_termination is None:
            return str(self.termination)
        return f"theta-only: {self.first_stage_termination}; joint: {self.termination}"
