"""`polarref compare comet --preset small` twice: identical metrics apart from runtimes and provenance;
and the committed reports' verdicts against a fresh run (issue 12). Slow: two full comparisons."""

import json
import shutil
from pathlib import Path

import pytest

from polarref.cli import main
from polarref.compare import schema
from polarref.core.data import REPO_ROOT

TIMING_CLAIMS = ("C4",)        # decided by wall times: may differ between runs by design
RUNTIME_KEYS = {"runtime_s", "stage_runtime_s", "time_s", "wall_s"}


def _strip(m: dict) -> dict:
    """metrics.json without runtimes and provenance."""
    m = json.loads(json.dumps(m))
    m.pop("environment")
    m["scene"].pop("render_s", None)
    for meth in m["methods"]:
        for k in RUNTIME_KEYS:
            meth.pop(k, None)
    for tr in m["ba_traces"]:
        for p in tr["points"]:
            p.pop("time_s")
    m["claims"] = [c for c in m["claims"] if c["claim_id"] not in TIMING_CLAIMS]
    for c in m["claims"]:      # C3/C5 carry BA wall times of the controlled experiment as figures
        c["figures"] = [f for f in c["figures"] if f["unit"] != "s"]
    return m


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    out = []
    for k in range(2):
        d = tmp_path_factory.mktemp(f"run{k}") / "comet-small"
        assert main(["--no-progress", "compare", "comet", "--preset", "small", "--out", str(d)]) == 0
        out.append(json.loads((d / "metrics.json").read_text()))
        shutil.rmtree(d / "runs")
    return out


@pytest.mark.slow
def test_two_small_runs_give_identical_metrics(two_runs):
    a, b = two_runs
    assert {m["name"] for m in a["methods"] if m["family"] == "pycolmap" and m["status"] == "ok"}, \
        "no pycolmap method succeeded: nothing to check"
    for ma, mb in zip(_strip(a)["methods"], _strip(b)["methods"]):
        assert ma == mb, ma["name"]
    assert _strip(a) == _strip(b)
    env = a["environment"]
    assert len(env["git_commit"]) == 40 and env["threads"]["pycolmap"] == 1 and env["cpu_model"]


@pytest.mark.slow
def test_committed_small_report_verdicts_match_a_fresh_run(two_runs):
    """The committed reports/comet-small against a fresh run: same verdicts, key figures close.

    Active once the committed report carries provenance (regenerated after issue 12):
    ``bash scripts/regen-reports.sh`` (or ``polarref --no-progress -q compare comet --preset small
    --out reports/comet-small --overwrite``).
    """
    path = REPO_ROOT / "reports" / "comet-small" / "metrics.json"
    if not path.is_file():
        pytest.skip(f"no committed report at {path}")
    old = schema.to_dict(schema.load(path))   # v1 (before the lead regenerates it) or v2: one layout
    if not old["environment"].get("git_commit"):
        pytest.skip("the committed comet-small report predates provenance (issue 12); regenerate it with "
                    "`bash scripts/regen-reports.sh`")
    fresh = two_runs[0]
    # C4 is a speed measurement of this machine at that moment (the committed run: 2 cores shared
    # with other work); its verdict moved between "inconclusive" and "not supported" with the load.
    # Every other verdict is a function of seeded computations and must repeat.
    verdicts = lambda m: {c["claim_id"]: c["verdict"] for c in m["claims"] if c["claim_id"] != "C4"}   # noqa: E731
    assert verdicts(fresh) == verdicts(old)
    assert {c["verdict"] for c in fresh["claims"] if c["claim_id"] == "C4"} <= {"inconclusive", "not supported", "supported"}
    by_old = {m["name"]: m for m in old["methods"]}
    for m in fresh["methods"]:
        o = by_old[m["name"]]
        assert m["status"] == o["status"], m["name"]
        if m["status"] != "ok":
            continue
        assert m["metrics"]["registered_images"] == o["metrics"]["registered_images"], m["name"]
        ra, rb = m["gt"]["rotation_error_deg_mean"], o["gt"]["rotation_error_deg_mean"]
        assert abs(ra - rb) <= max(0.01, 0.25 * rb), (m["name"], ra, rb)
        tp, otp = m["metrics"]["tie_points"], o["metrics"]["tie_points"]
        assert abs(tp - otp) <= 0.05 * otp, m["name"]
    for cid in ("C3", "C5", "C6", "C8"):
        figs = {f["key"]: f["value"] for c in fresh["claims"] if c["claim_id"] == cid for f in c["figures"]}
        ofigs = {f["key"]: f["value"] for c in old["claims"] if c["claim_id"] == cid for f in c["figures"]}
        assert set(figs) == set(ofigs), cid
        for k in ("c_rotation_d", "ratio6", "ratio6_raw", "c5_tp_d"):
            if k in figs and figs[k] is not None:
                assert figs[k] == pytest.approx(ofigs[k], rel=0.05, abs=1e-3), (cid, k)
