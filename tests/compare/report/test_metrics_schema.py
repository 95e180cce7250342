"""One metrics.json schema: `polarref sfm` and `polarref compare` embed the same ReconstructionMetrics
record (read back by one strict loader); a v1 compare file reads into the same values."""

import copy
import json

import pytest
from test_report_build import synthetic_metrics

from polarref import metrics as M
from polarref.core import records
from polarref.compare import schema
from polarref.core.data import REPO_ROOT
from polarref.metrics import GTErrors, ImageGTErrors, ReconstructionMetrics, SurfaceErrors
from polarref.core.provenance import Provenance
from polarref.sfm.pipeline import SfMConfig
from polarref.sfm.report import SfMReport

V1_NAMES = {"registered_images": "registered_images", "tie_points": "tie_points",
            "reprojected_px": "reprojected_px", "mean_reprojection_error_px": "mean_reprojection_error_px",
            "mean_reprojection_error_per_point_px": "mean_reprojection_error_px_per_point"}


def _metrics() -> ReconstructionMetrics:
    per = {"a.png": ImageGTErrors(0.1, 0.002, 0.05), "b.png": ImageGTErrors(0.3, 0.004, 0.07)}
    gt = GTErrors(2, "umeyama_centers", 0, 1.5, 10.0, 0.2, 0.2, 0.3, 0.003, 0.003, 0.004, 0.06, 0.07, per)
    return ReconstructionMetrics(num_images=3, registered_images=2, tie_points=40, reprojected_px=95,
                                 mean_reprojection_error_px=0.31, mean_reprojection_error_px_per_point=0.29,
                                 median_reprojection_error_px=float("nan"),   # undefined: null in the file
                                 mean_track_length=2.375, gt=gt,
                                 surface=SurfaceErrors(40, 0.5, 0.4, 0.9, 0.05, 0.04))


def _sfm_json(m: ReconstructionMetrics) -> dict:
    prov = Provenance("", None, 1, "", "", "", "3.11", {}, {}, {})
    report = SfMReport("images", SfMConfig(), prov, status="ok", metrics=m)
    return json.loads(json.dumps(report.to_json(), allow_nan=False))


def test_sfm_and_compare_embed_the_same_record():
    m = _metrics()
    sfm = _sfm_json(m)
    assert sfm["schema_version"] == schema.SCHEMA_VERSION == M.SCHEMA_VERSION == 2
    assert "tie_points" not in sfm and set(sfm["metrics"]) == {f for f in ReconstructionMetrics.__dataclass_fields__}
    from_sfm = M.read_metrics(sfm)

    data = synthetic_metrics()
    mf = schema.from_dict(data)
    mf.methods[1].set_metrics(m)
    from_compare = schema.from_dict(json.loads(schema.dumps(mf))).methods[1].metrics

    assert type(from_sfm) is type(from_compare) is ReconstructionMetrics
    assert from_sfm == from_compare
    assert from_sfm.median_reprojection_error_px is None            # NaN -> null -> None, both ways
    assert from_sfm.tie_points == 40 and from_sfm.gt.per_image["b.png"].rotation_error_deg == 0.3
    assert mf.methods[1].metrics == from_compare                     # in memory = what a reader gets
    assert mf.methods[1].metric("mean_reprojection_error_px_per_point") == 0.29
    with pytest.raises(AttributeError):
        mf.methods[1].metric("mean_reprojection_error_per_point_px")  # the v1 spelling is gone


def _downgrade(v2: dict) -> dict:
    """The same content as the v1 schema wrote it (compare's own names per method)."""
    v1 = copy.deepcopy(v2)
    v1["schema_version"] = 1
    for meth in v1["methods"]:
        m = meth.pop("metrics")
        for old, new in V1_NAMES.items():
            meth[old] = None if m is None else m[new]
    return v1


def test_v1_file_reads_into_the_same_values():
    v2 = synthetic_metrics()
    a = schema.from_dict(copy.deepcopy(v2))
    b = schema.from_dict(_downgrade(v2))
    assert b.schema_version == schema.SCHEMA_VERSION
    for ma, mb in zip(a.methods, b.methods):
        if ma.metrics is None:
            assert mb.metrics is None and mb.status == "failed"
            continue
        for new in V1_NAMES.values():
            assert mb.metric(new) == ma.metric(new), new
        # v1 did not record these: missing, never invented
        assert mb.metrics.median_reprojection_error_px is None and mb.metrics.mean_track_length is None
        assert ma.metrics.median_reprojection_error_px is not None
    assert schema.to_dict(b)["claims"] == schema.to_dict(a)["claims"]


def test_committed_report_reads_whatever_its_version():
    path = REPO_ROOT / "reports" / "comet-small" / "metrics.json"
    if not path.is_file():
        pytest.skip(f"no committed report at {path}")
    raw = json.loads(path.read_text())
    m = schema.load(path)
    for rm, mm in zip(raw["methods"], m.methods):
        if raw["schema_version"] == 1:
            for old, new in V1_NAMES.items():
                assert mm.metric(new) == rm[old], (rm["name"], old)
        else:
            assert records.to_dict(mm.metrics) == rm["metrics"] if rm["metrics"] else mm.metrics is None
    assert any(mm.metric("tie_points") for mm in m.methods)


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d["metrics"].update(mean_reprojection_error_per_point_px=0.2), "unknown key"),
    (lambda d: d["metrics"]["gt"].update(bogus=1), "unknown key"),
    (lambda d: d.update(schema_version=1), "schema_version"),
    (lambda d: d.pop("metrics"), "no metrics"),
    (lambda d: d["metrics"].update(tie_points=None), "integer"),
])
def test_sfm_metrics_read_strictly(mutate, message):
    d = _sfm_json(_metrics())
    mutate(d)
    with pytest.raises(records.RecordError, match=message):
        M.read_metrics(d)


def test_v1_file_with_unknown_names_is_rejected():
    v1 = _downgrade(synthetic_metrics())
    v1["methods"][0]["mean_reprojection_error_px_per_point"] = 0.3   # a v2 name in a v1 method
    with pytest.raises(records.RecordError, match="unknown key"):
        schema.from_dict(v1)


@pytest.mark.parametrize("finished", [True, False])
def test_the_report_entry_is_the_method_run_seen_by_the_report(finished):
    """metrics.json keeps the report's view of a MethodRun (issue 29 (b)): built in one place,
    every figure the run holds carried over unchanged, nothing the run does not hold invented."""
    from polarref.compare.run.methods import select
    from polarref.compare.run.pipeline import method_result
    from polarref.core.status import RunStatus
    from polarref.model.run import MethodRun

    spec = select(["ours-polar"])[0]
    run = MethodRun("ours-polar", form="polar", status=RunStatus.OK if finished else RunStatus.TIMEOUT,
                    reason="" if finished else "timed out after 90 s", timeout_s=90.0,
                    stage_runtime_s={"features": 1.25, "mapping (excl. BA)": 2.5, "bundle adjustment": 0.75},
                    wall_s=9.0, peak_rss_mb=512.0, model_dir="/elsewhere/model" if finished else "",
                    metrics=_metrics() if finished else None)
    res = method_result(spec, run, None, num_images=3)
    back = schema.from_dict(json.loads(schema.dumps(_file_with(res)))).methods[0]
    assert (back.name, back.ba, back.status, back.reason, back.timeout_s) == \
        ("ours-polar", "polar", run.status, run.reason, 90.0)
    assert back.stage_runtime_s == run.stage_runtime_s
    # the runtime is the sum of the timed stages once the method's own job finished, unknown before
    assert back.runtime_s == (4.5 if finished else None)
    if finished:   # the one ReconstructionMetrics record, as `polarref sfm` writes it (NaN -> None)
        assert records.to_dict(back.metrics) == json.loads(json.dumps(records.to_dict(run.metrics)))
        assert back.metric("tie_points") == 40 and back.metric("median_reprojection_error_px") is None
    else:
        assert back.metrics is None and back.metric("tie_points") is None
    # machine facts of the process stay in the run's own result file, not in the published figures
    assert "peak_rss_mb" not in json.loads(schema.dumps(_file_with(res)))["methods"][0]


def _file_with(res):
    m = schema.from_dict(copy.deepcopy(synthetic_metrics()))
    m.methods = [res]
    m.pairs, m.claims = [], []
    return m
