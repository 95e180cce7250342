"""The records of ``polarref bench ba`` (issue 29): one solve, one solver's row, one problem, the bench.

The JSON layout is the one the committed ``reports/bench-ba*/bench.json`` files have, so they
load as they are. Those files come from several versions of the bench (the tau targets, the
roofline, the cold process and peak memory were added in issue 35), so every field that an
older file lacks has a default; reading is otherwise strict: an unknown key is a
:class:`polarref.core.records.RecordError` naming the key path.

Fields that only live during a bench (a solve's iteration trace, the settings Ceres reported)
are not written. Settings of the solvers stay key-value maps: they are the option objects of
three different solvers (ours, pycolmap's Ceres, scipy) as they printed at the time.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from polarref.core.provenance import Provenance
from polarref.core.records import RecordError
from polarref.core.status import RunStatus
from polarref.model.run import MethodRun

# one solver option as stored: tolerances, counts, names, flags, ``refine`` groups, unset
Setting = str | int | float | bool | list[str] | None


class SolverKind(enum.Enum):
    OURS = "ours"
    CERES = "ceres"
    SCIPY = "scipy"


@dataclass(frozen=True)
class Stats:
    """Median and range of repeated measurements (None and n = 0: nothing measured)."""

    median: float | None = None
    min: float | None = None
    max: float | None = None
    n: int = 0

    @classmethod
    def of(cls, values) -> Stats:
        v = [float(x) for x in values if x is not None]
        if not v:
            return cls()
        return cls(float(np.median(v)), min(v), max(v), len(v))


@dataclass(frozen=True)
class TracePoint:
    """One LM step of a solve: its number (from 1), accepted, seconds since the start, pixel cost."""

    iteration: int
    accepted: bool
    wall_s: float
    cost: float


@dataclass(frozen=True)
class SolveRun:
    """One complete solve of one solver (ours, Ceres or scipy) on the problem.

    ``run`` is the solve as the one record of a run (:class:`polarref.model.run.MethodRun`):
    ``method`` the solver's name where the solve records it (scipy's runs: their peer's; else ""),
    ``status`` OK (a solve that did not finish is a row's ``error``), ``wall_s``,
    ``stage_runtime_s`` (ours: seconds per solver stage) and ``peak_rss_mb`` (first full run:
    memory the solve added, forked child; MiB). The other fields are the solver's own counts.
    Build one with :meth:`measured`; bench.json keeps the flat layout (:class:`_SolveFile`).
    """

    run: MethodRun
    final_cost: float                  # 1/2 sum of squared pixel residuals, recomputed
    iterations: int                    # LM steps, accepted + rejected
    accepted: int | None = None        # None: the solver does not say (scipy)
    rejected: int | None = None
    termination: str = ""
    final_rms_px: float | None = None
    initial_cost: float | None = None
    linear_solver: str = ""
    objective_final: float | None = None   # ours: the form's own objective at the end
    setup_s: float | None = None           # ours: preparation before the first step
    reported_cost: float | None = None     # peers: their own final cost
    behind_camera: int | None = None       # peers: observations behind their camera at the end
    trace_cost_shift: float | None = None  # Ceres: recomputed - reported final cost
    load_1min: float | None = None         # first full run: machine load at its start and end
    load_1min_end: float | None = None
    trace: tuple[TracePoint, ...] = field(default=(), metadata={"stored": False})
    settings_used: dict[str, Setting] | None = field(default=None, metadata={"stored": False})

    @staticmethod
    def measured(*, wall_s: float, time_in: dict[str, float] | None = None, peak_rss_mib: float | None = None,
                 name: str | None = None, **counts) -> SolveRun:
        """A finished solve from what the solver measured (``counts``: the other fields by name)."""
        run = MethodRun(name or "", status=RunStatus.OK, stage_runtime_s=dict(time_in or {}), wall_s=float(wall_s),
                        peak_rss_mb=peak_rss_mib)
        return SolveRun(run, **counts)

    @property
    def wall_s(self) -> float:
        return float(self.run.wall_s)

    @property
    def peak_rss_mib(self) -> float | None:
        return self.run.peak_rss_mb

    @property
    def name(self) -> str | None:
        return self.run.method or None

    def with_peak(self, peak_rss_mib: float | None) -> SolveRun:
        return dataclasses.replace(self, run=dataclasses.replace(self.run, peak_rss_mb=peak_rss_mib))

    def without_trace(self) -> SolveRun:
        return dataclasses.replace(self, trace=(), settings_used=None)

    def to_file(self) -> _SolveFile:
        return _SolveFile(self.final_cost, self.wall_s, self.iterations, self.accepted, self.rejected,
                          self.termination, self.final_rms_px, self.initial_cost, self.linear_solver,
                          self.objective_final, self.setup_s, dict(self.run.stage_runtime_s), self.reported_cost,
                          self.behind_camera, self.trace_cost_shift, self.peak_rss_mib, self.name, self.load_1min,
                          self.load_1min_end)

    @staticmethod
    def from_file(f: _SolveFile) -> SolveRun:
        return SolveRun.measured(
            wall_s=f.wall_s, time_in=f.time_in, peak_rss_mib=f.peak_rss_mib, name=f.name, final_cost=f.final_cost,
            iterations=f.iterations, accepted=f.accepted, rejected=f.rejected, termination=f.termination,
            final_rms_px=f.final_rms_px, initial_cost=f.initial_cost, linear_solver=f.linear_solver,
            objective_final=f.objective_final, setup_s=f.setup_s, reported_cost=f.reported_cost,
            behind_camera=f.behind_camera, trace_cost_shift=f.trace_cost_shift, load_1min=f.load_1min,
            load_1min_end=f.load_1min_end)


@dataclass(frozen=True)
class _SolveFile:
    """A solve as bench.json stores it (flat, in this order): read and written only through SolveRun."""

    final_cost: float
    wall_s: float
    iterations: int
    accepted: int | None = None
    rejected: int | None = None
    termination: str = ""
    final_rms_px: float | None = None
    initial_cost: float | None = None
    linear_solver: str = ""
    objective_final: float | None = None
    setup_s: float | None = None
    time_in: dict[str, float] = field(default_factory=dict)
    reported_cost: float | None = None
    behind_camera: int | None = None
    trace_cost_shift: float | None = None
    peak_rss_mib: float | None = None
    name: str | None = None
    load_1min: float | None = None
    load_1min_end: float | None = None


@dataclass(frozen=True)
class IterationsToTarget:
    total: int
    accepted: int | None = None   # None: read from a trace (LM steps up to the first at the target)
    rejected: int | None = None


@dataclass(frozen=True)
class TauTime:
    """One solver's time to one tau target over its full runs (empty Stats: not reached)."""

    time_s: Stats
    iterations: int | None = None


@dataclass(frozen=True)
class TauTarget:
    tau: float
    target_cost: float


@dataclass(frozen=True)
class TauSummary:
    """At one tau: the fastest Ceres setting, and every solver's time and ratio to it."""

    fastest_ceres: str | None
    fastest_ceres_s: float | None
    times_s: dict[str, float | None]
    ratio_to_fastest_ceres: dict[str, float | None]


@dataclass(frozen=True)
class SolverRow:
    """One solver on one problem: its settings, full runs and the times to the targets; or why it did not run."""

    solver: str
    kind: SolverKind
    settings: dict[str, Setting] = field(default_factory=dict)
    error: str | None = None
    full_runs: tuple[SolveRun, ...] = ()
    target_runs: tuple[SolveRun, ...] = ()
    pixel_objective: bool | None = None
    iterations_limit_to_target: int | None = None
    set_common_cost: bool | None = None
    reached_target: bool | None = None
    time_to_target_s: Stats | None = None
    time_to_target_kind: str | None = None
    iterations_to_target: IterationsToTarget | None = None
    warm_first_step_s: float | None = None
    wall_s: Stats | None = None
    final_cost: float | None = None
    iterations: int | None = None
    peak_rss_mib: float | None = None
    s_per_accepted_iteration: Stats | None = None
    per_iteration_vs_euclidean: float | None = None
    ratio_to_fastest_ceres: float | None = None
    tau: dict[str, TauTime] | None = None

    @property
    def ran(self) -> bool:
        return self.error is None and bool(self.full_runs)


@dataclass(frozen=True)
class FlopCounts:
    build: float
    schur: float
    factorisation: float | None


@dataclass(frozen=True)
class StageRates:
    """Achieved GFLOP/s per stage (None: not counted)."""

    build: Stats | None
    schur: Stats | None
    factorisation: Stats | None


@dataclass(frozen=True)
class SchurBytes:
    """Bytes the block-sparse Schur kernel moves per LM step in roofline.py's two models."""

    compulsory: float
    per_update: float
    entry_pairs: int
    pair_blocks: int


@dataclass(frozen=True)
class Roofline:
    """Our Euclidean form's flops per LM step and the rates its stages reached (roofline.py)."""

    form: str
    linear_solver: str
    flops_per_iteration: FlopCounts
    num_unknowns: int
    gflops: StageRates
    time_in_s: dict[str, Stats]
    schur_bytes: SchurBytes | None = None


@dataclass(frozen=True)
class ColdProcess:
    """``polarref ba PROBLEM`` timed in a fresh interpreter (error: why it did not finish)."""

    command: str
    process_wall_s: float | None = None
    solve_wall_s: float | None = None
    setup_s: float | None = None
    first_iteration_s: float | None = None
    iterations: int | None = None
    error: str | None = None


@dataclass(frozen=True)
class OwnCostRow:
    iterations_limit: int | None
    runs: tuple[SolveRun, ...] = ()
    time_to_target_s: Stats | None = None


@dataclass(frozen=True)
class OwnCost:
    """Euclidean vs Ceres to Ceres' own best final cost, where the common target is unusable."""

    target_cost: float
    why: str
    rows: dict[str, OwnCostRow]
    fastest_ceres: str | None = None
    euclidean_ratio_to_fastest_ceres: float | None = None


@dataclass(frozen=True)
class MachineRates:
    """The machine's dense GEMM rate (GFLOP/s per BLAS thread count), measured in the bench's run."""

    gemm_gflops: dict[str, float]
    gemm: str
    load_1min_at_gemm: float | None = None
    triad_gbs: float | None = None             # STREAM triad, 1 thread (roofline.triad_gbs)
    load_1min_at_triad: float | None = None


@dataclass(frozen=True)
class KernelSettings:
    used: str                                 # numba | numpy
    numba: str | None = None
    warm_up_s: float | None = None
    cold_process_load_s: float | None = None
    threads: int = 1


@dataclass(frozen=True)
class BenchSettings:
    """What every problem of a bench run shares."""

    repeat: int
    target: str
    converged_rel: float
    ours: dict[str, Setting]
    ceres: tuple[str, ...]
    kernels: KernelSettings
    heap: str = ""
    taus: tuple[float, ...] = ()
    bisect_max_obs: int | None = None
    ceres_max_s: float | None = None
    solvers: list[str] | str = "all"
    dense_schur_max_cameras: int | None = None


@dataclass(frozen=True)
class ProblemResult:
    """Every solver on one problem, the targets and the measurements beside the timings."""

    problem: str
    num_cameras: int
    num_points: int
    num_observations: int
    best_final_cost: float
    common_final_cost: float
    target_cost: float
    rows: tuple[SolverRow, ...]
    repeat: int = 1
    load_1min: float | None = None
    load_1min_end: float | None = None
    initial_cost: float | None = None
    tau_targets: dict[str, TauTarget] = field(default_factory=dict)
    time_to_target_method: str = "bisection + timed solves"
    fastest_ceres: str | None = None
    fastest_ceres_time_to_target_s: float | None = None
    tau_summary: dict[str, TauSummary] = field(default_factory=dict)
    roofline: Roofline | None = None
    cold_process: ColdProcess | None = None
    ceres_own_cost: OwnCost | None = None
    ceres_scope: str | None = None   # the done-when's scope rule: why no Ceres ratio exists here
    bench_s: float | None = None
    environment: Provenance | None = None     # a merged problem keeps its own run's
    machine: MachineRates | None = None
    settings: BenchSettings | None = None

    def row(self, solver: str) -> SolverRow | None:
        return next((x for x in self.rows if x.solver == solver), None)


@dataclass(frozen=True)
class BenchDoc:
    """``bench.json``: the run's provenance, settings, machine rates and every problem."""

    environment: Provenance
    settings: BenchSettings
    problems: tuple[ProblemResult, ...]
    machine: MachineRates | None = None
    merged_from: int | None = None


# --- JSON ----------------------------------------------------------------------------------

def _stored(f: dataclasses.Field) -> bool:
    return f.metadata.get("stored", True)


def to_json(obj):
    """The JSON-able form of a record: fields in order; optional fields at their default (None,
    empty) left out, as the bench wrote them before the records were typed."""
    if isinstance(obj, enum.Enum):
        return obj.value
    if isinstance(obj, SolveRun):
        return to_json(obj.to_file())
    if dataclasses.is_dataclass(obj):
        out = {}
        for f in dataclasses.fields(obj):
            v = getattr(obj, f.name)
            if not _stored(f) or (v is None and f.default is None) or (v == () and f.default == ()):
                continue
            out[f.name] = to_json(v)
        return out
    if isinstance(obj, dict):
        return {str(k): to_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_json(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _from_json(tp, value, where: str):
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None and len(args) < len(typing.get_args(tp)):
            return None
        if type(value) in args:   # a number stays the kind it was written as
            return value
        for a in args:
            try:
                return _from_json(a, value, where)
            except RecordError:
                continue
        raise RecordError(f"{where}: {value!r} fits none of {args}"[:300])
    if tp is SolveRun:
        return SolveRun.from_file(_from_json(_SolveFile, value, where))
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise RecordError(f"{where} should be an object")
        if tp is _SolveFile:   # scipy's runs were stored as the peer's result
            value = {{"accepted_iterations": "accepted", "rejected_iterations": "rejected"}.get(k, k): v
                     for k, v in value.items() if k not in ("settings", "trace")}
        if tp is Provenance:
            value = {"seeds": {}, **value}
        hints = typing.get_type_hints(tp)
        names = {f.name for f in dataclasses.fields(tp) if _stored(f)}
        unknown = set(value) - names
        if unknown:
            raise RecordError(f"unknown key(s) {sorted(unknown)} in {where}")
        try:
            return tp(**{k: _from_json(hints[k], v, f"{where}.{k}") for k, v in value.items()})
        except TypeError as exc:   # a required key missing
            raise RecordError(f"{where}: {exc}") from exc
    if origin in (list, tuple):
        if not isinstance(value, list):
            raise RecordError(f"{where} should be a list")
        return origin(_from_json(typing.get_args(tp)[0], v, f"{where}[{i}]") for i, v in enumerate(value))
    if origin is dict:
        if not isinstance(value, dict):
            raise RecordError(f"{where} should be an object")
        inner = typing.get_args(tp)[1]
        return {k: _from_json(inner, v, f"{where}.{k}") for k, v in value.items()}
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return tp(value)
    if tp is bool:
        if not isinstance(value, bool):
            raise RecordError(f"{where} should be true or false")
        return value
    if tp in (int, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or (tp is int and (not math.isfinite(value) or value != int(value))):
            raise RecordError(f"{where} should be a number ({tp.__name__})")
        return tp(value)
    if tp is str:
        if not isinstance(value, str):
            raise RecordError(f"{where} should be a string")
        return value
    raise TypeError(f"ba_records: unsupported field type {tp!r} at {where}")


def from_json(tp, data, where: str | None = None):
    """The record ``tp`` from parsed JSON (module docstring: defaults for older files, unknown keys refused)."""
    return _from_json(tp, data, where or tp.__name__)


def dumps_json(doc: BenchDoc) -> str:
    return json.dumps(to_json(doc), indent=1, default=float)


def read_json_doc(path: Path) -> BenchDoc:
    """bench.json at ``path`` as a :class:`BenchDoc` (RecordError names the key that does not fit)."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise RecordError(f"{path}: not a readable bench.json ({exc})") from exc
    try:
        return from_json(BenchDoc, data)
    except RecordError as exc:
        raise RecordError(f"{path}: {exc}") from exc
