"""The pre-registration of the controlled claim experiments (``preregistration.toml``, issue 30).

The file states, per claim, the measure, the margins or thresholds, the levels, the test seeds
and the pilot seeds (disjoint), and the pilot's standard deviations; :mod:`thresholds` takes every
claim threshold from it. :func:`file_commit` gives the commit of its last change, which each
report shows beside the run's commit. :func:`mde` is the minimum detectable effect of a paired
t-test from the pilot's standard deviation.
"""

from __future__ import annotations

import subprocess
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarref.core import records
from polarref.core.errors import PolarrefError

PATH = Path(__file__).with_name("preregistration.toml")
_LIST_KEYS = ("test_seeds", "pilot_seeds", "levels", "outlier_levels", "parallax_levels", "real_problems")


@dataclass(frozen=True)
class ClaimPlan:
    """One claim's entry. ``values``: every other key (thresholds, pilot figures, paper effects)."""

    claim_id: str
    measure: str
    test_seeds: tuple[int, ...]
    pilot_seeds: tuple[int, ...]
    levels: tuple = ()
    outlier_levels: tuple[float, ...] = ()
    parallax_levels: tuple[float, ...] = ()
    real_problems: tuple[str, ...] = ()          # items of the reference data (C4), skipped when absent
    values: tuple[tuple[str, float | str], ...] = ()

    def value(self, name: str) -> float:
        for k, v in self.values:
            if k == name:
                return float(v)
        raise PolarrefError(f"{PATH.name}: [{self.claim_id}] has no '{name}'")


@dataclass(frozen=True)
class ReplicationPlan:
    """The ``[replication]`` section: the scenes on which the scene-dependent claims are rerun."""

    measure: str
    scene: str                       # synthetic scene of ``polarref compare``
    preset: str
    scene_seeds: tuple[int, ...]     # ``polarref compare --seed``: render, noise and method seeds
    real_sets: tuple[str, ...]       # folder names under the data root
    methods: tuple[str, ...]
    claims: tuple[str, ...]


@dataclass(frozen=True)
class Preregistration:
    path: Path
    alpha: float
    power: float
    claims: tuple[ClaimPlan, ...]
    replication: ReplicationPlan | None = None

    def claim(self, claim_id: str) -> ClaimPlan:
        for c in self.claims:
            if c.claim_id == claim_id:
                return c
        raise PolarrefError(f"{self.path.name}: no [{claim_id}] section")


def load(path: Path = PATH) -> Preregistration:
    """The pre-registration; PolarrefError (one line) when a section is malformed or a claim's
    pilot seeds overlap its test seeds."""
    try:
        raw = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise PolarrefError(f"{path}: {exc}") from exc
    claims = []
    for cid, sec in raw.items():
        if not cid.startswith("C"):
            continue
        lists = {k: tuple(sec.get(k, ())) for k in _LIST_KEYS}
        if set(lists["test_seeds"]) & set(lists["pilot_seeds"]) or not lists["test_seeds"]:
            raise PolarrefError(f"{path}: [{cid}] needs test seeds, disjoint from its pilot seeds")
        rest = tuple((k, v) for k, v in sec.items() if k not in _LIST_KEYS and k != "measure")
        claims.append(ClaimPlan(cid, str(sec.get("measure", "")), values=rest, **lists))
    p = raw.get("power", {})
    return Preregistration(Path(path), float(p.get("alpha", 0.05)), float(p.get("power", 0.8)), tuple(claims),
                           _replication(raw.get("replication"), path))


def _replication(sec: dict | None, path: Path) -> ReplicationPlan | None:
    if sec is None:
        return None
    try:
        plan = records.from_dict(ReplicationPlan, sec, label=f"{Path(path).name} [replication]")
    except records.RecordError as exc:
        raise PolarrefError(str(exc)) from exc
    if len(plan.scene_seeds) + len(plan.real_sets) < 2 or len(set(plan.scene_seeds)) != len(plan.scene_seeds):
        raise PolarrefError(f"{path}: [replication] needs >= 2 distinct scenes")
    return plan


@dataclass(frozen=True)
class FileCommit:
    """The commit of a file's last change; ``modified``: it differs from that commit now (None:
    not in a git checkout)."""

    commit: str
    date: str
    modified: bool | None


def file_commit(path: Path = PATH) -> FileCommit:
    def git(*args: str) -> str | None:
        try:
            r = subprocess.run(["git", *args], cwd=path.parent, capture_output=True, text=True, timeout=20)
        except (OSError, subprocess.TimeoutExpired):
            return None
        return r.stdout.strip() if r.returncode == 0 else None

    # --follow with A/M only: moving the file (a pure rename) is no change of the pre-registration
    log = git("log", "-1", "--follow", "--diff-filter=AM", "--format=%H %cI", "--", path.name)
    if not log:
        return FileCommit("", "", None)
    commit, date = log.split(" ", 1)
    status = git("status", "--porcelain", "--", path.name)
    return FileCommit(commit, date, None if status is None else bool(status))


def mde(sd: float, n: int, alpha: float, power: float) -> float:
    """Minimum detectable mean difference of a paired t-test on ``n`` pairs with standard
    deviation ``sd`` (two-sided ``alpha``, ``power``); inf with fewer than 2 pairs or no pilot."""
    from scipy.stats import t as student_t

    if n < 2 or not np.isfinite(sd):
        return float("inf")
    return float((student_t.ppf(1 - alpha / 2, n - 1) + student_t.ppf(power, n - 1)) * sd / np.sqrt(n))


def seeds_needed(sd: float, effect: float, alpha: float, power: float, n_max: int = 100_000) -> int | None:
    """Smallest number of pairs whose :func:`mde` is at or below ``effect`` (None beyond ``n_max``
    or without a pilot): how many seeds an experiment needs to detect the effect it tests."""
    if not (np.isfinite(sd) and effect > 0):
        return None
    lo, hi = 2, 2
    while mde(sd, hi, alpha, power) > effect:     # the MDE falls with n: double, then bisect
        if hi >= n_max:
            return None
        lo, hi = hi, min(2 * hi, n_max)
    while lo < hi:
        mid = (lo + hi) // 2
        lo, hi = (mid + 1, hi) if mde(sd, mid, alpha, power) > effect else (lo, mid)
    return hi


PREREG = load()
