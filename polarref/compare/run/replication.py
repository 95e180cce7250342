"""Replication of the scene-dependent claims (C3, C4, C5) over pre-registered scenes (issue 30).

The scenes are the ``[replication]`` section of ``preregistration.toml``: seeds of the synthetic
scene (``polarref compare --seed``: render, noise and method seeds) and real image sets under the
data root. Each scene is one ``polarref compare`` run (its methods only, no claim experiments)
in its own folder, judged by the scene rules of :func:`polarref.compare.claims.scorecard.scene_claims`;
a claim is "replicated" when every planned scene ran and gave the same verdict. C1, C2 and
C6-C8 are decided by experiments that do not read the scene (derivations, seeded synthetic BA
problems), so they are named as scene-independent instead of being repeated.

Resumable: a scene folder whose ``metrics.json`` exists is read, never rerun (delete the folder
to rerun it). The figures the scene rules use (reprojection error, Sim3-aligned GT rotation
error, wall time, counts) do not depend on the frame of the world.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from polarref.compare import schema
from polarref.compare.claims.scorecard import scene_claims
from polarref.compare.claims.preregistration import PREREG, ReplicationPlan, file_commit
from polarref.compare.report.build import render_rationale
from polarref.core.provenance import Provenance, collect_record
from polarref.core.status import RunStatus

SCENE_INDEPENDENT = ("C1", "C2", "C6", "C7", "C8")
REPLICATED, NOT_REPLICATED, NOT_TESTED = "yes", "no", "not tested"


@dataclass(frozen=True)
class SceneSpec:
    """One planned scene: ``argument`` is compare's SCENE|DIR, ``folder`` its run folder's name."""

    folder: str
    argument: str
    seed: int
    real: bool


@dataclass
class SceneClaim:
    claim_id: str
    verdict: str
    text: str                 # the scene rule's rationale, figures filled in


@dataclass
class SceneOutcome:
    """One scene's run and its C3-C5 verdicts (empty when it did not run)."""

    folder: str
    argument: str
    seed: int
    real: bool
    status: RunStatus
    reason: str = ""
    reused: bool = False      # read from an earlier run's metrics.json
    num_images: int | None = None
    git_commit: str = ""
    git_dirty: bool | None = None
    runtime_s: float | None = None
    claims: list[SceneClaim] = field(default_factory=list)

    def verdict(self, claim_id: str) -> str:
        return next((c.verdict for c in self.claims if c.claim_id == claim_id), NOT_TESTED)


@dataclass
class ReplicationRow:
    claim_id: str
    verdicts: list[str]       # per scene, in the order of ``ReplicationReport.scenes``
    replicated: str           # REPLICATED / NOT_REPLICATED / NOT_TESTED


@dataclass
class ReplicationReport:
    provenance: Provenance
    preregistration_commit: str
    preregistration_modified: bool | None
    measure: str
    preset: str
    methods: list[str]
    scenes: list[SceneOutcome]
    rows: list[ReplicationRow]
    scene_independent: list[str]
    wall_s: float
    load_start: list[float]   # 1/5/15-minute load averages when the run started and ended
    load_end: list[float]


def planned_scenes(plan: ReplicationPlan, data: Path | None) -> list[SceneSpec]:
    """The synthetic seeds, then the real sets (``data``/name; a set that is absent is still
    listed, so the report shows it as not run)."""
    out = [SceneSpec(f"{plan.scene}-{plan.preset}-seed{s}", plan.scene, s, False) for s in plan.scene_seeds]
    for name in plan.real_sets:
        where = (data / name) if data is not None else Path(name)
        out.append(SceneSpec(f"{name}-{plan.preset}", str(where), 0, True))
    return out


def compare_command(spec: SceneSpec, plan: ReplicationPlan, folder: Path) -> list[str]:
    return [sys.executable, "-m", "polarref", "--no-progress", "-q", "compare", spec.argument,
            "--preset", plan.preset, "--seed", str(spec.seed), "--no-claims",
            "--methods", *plan.methods, "--out", str(folder)]


def run_scene(spec: SceneSpec, plan: ReplicationPlan, out: Path, timeout_s: float) -> SceneOutcome:
    """Read the scene's finished run, or run it; a failure is recorded with its reason."""
    folder = out / spec.folder
    base = SceneOutcome(spec.folder, spec.argument, spec.seed, spec.real, RunStatus.SKIPPED)
    metrics_path = folder / "metrics.json"
    reused = metrics_path.is_file()
    if not reused:
        if spec.real and not Path(spec.argument).is_dir():
            base.reason = f"data not found: {spec.argument} (set $POLARREF_DATA)"
            return base
        try:
            r = subprocess.run(compare_command(spec, plan, folder), capture_output=True, text=True,
                               timeout=timeout_s, env=os.environ | {"PYTHONPATH": str(Path(__file__).parents[2])})
        except subprocess.TimeoutExpired:
            base.status, base.reason = RunStatus.TIMEOUT, f"compare ran past {timeout_s:.0f} s"
            return base
        if r.returncode != 0 or not metrics_path.is_file():
            tail = (r.stderr.strip().splitlines() or ["no message"])[-1]
            base.status, base.reason = RunStatus.FAILED, f"compare exited {r.returncode}: {tail}"
            return base
    return judge(base, schema.load(metrics_path), reused)


def judge(base: SceneOutcome, metrics: schema.MetricsFile, reused: bool = False) -> SceneOutcome:
    """``base`` completed from one scene's metrics: its provenance and the scene rules' verdicts."""
    env = metrics.environment
    claims = [SceneClaim(c.claim_id, c.verdict, render_rationale(c)) for c in scene_claims(metrics)]
    return SceneOutcome(base.folder, base.argument, base.seed, base.real, RunStatus.OK, "", reused,
                        metrics.scene.num_images, env.git_commit, env.git_dirty, env.total_runtime_s, claims)


def rows(scenes: list[SceneOutcome], claim_ids) -> list[ReplicationRow]:
    """Replicated: every scene ran and tested the claim, with one verdict; not tested: none did."""
    out = []
    for cid in claim_ids:
        verdicts = [s.verdict(cid) for s in scenes]
        tested = [v for v in verdicts if v != NOT_TESTED]
        rep = (NOT_TESTED if not tested else
               REPLICATED if len(tested) == len(verdicts) and len(set(tested)) == 1 else NOT_REPLICATED)
        out.append(ReplicationRow(cid, verdicts, rep))
    return out


def replicate(out: Path, data: Path | None, timeout_s: float = 900.0,
              plan: ReplicationPlan | None = None, progress=None) -> ReplicationReport:
    """Run (or reuse) every planned scene under ``out`` and tabulate the verdicts."""
    plan = plan or PREREG.replication
    if plan is None:
        raise ValueError(f"{PREREG.path.name} has no [replication] section")
    t0, load0 = time.perf_counter(), list(os.getloadavg())
    prov = collect_record(seeds={s.folder: s.seed for s in planned_scenes(plan, data) if not s.real})
    fc = file_commit()
    scenes = []
    for spec in planned_scenes(plan, data):
        if progress is not None:
            progress(spec)
        scenes.append(run_scene(spec, plan, out, timeout_s))
    indep = [f"{cid}: scene-independent (decided by experiments that do not read the scene; see the "
             "comparison reports)" for cid in SCENE_INDEPENDENT]
    return ReplicationReport(prov, fc.commit, fc.modified, plan.measure, plan.preset, list(plan.methods), scenes,
                             rows(scenes, plan.claims), indep, time.perf_counter() - t0, load0, list(os.getloadavg()))
