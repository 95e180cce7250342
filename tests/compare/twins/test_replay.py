"""The mapper replay's record arithmetic and its refusals (the replay itself runs whole mappers:
its numbers are in reports/paper-tables/mapper-replays/)."""

import json

import pytest

from polarref.ba.options import BASummary
from polarref.compare.twins import replay as RP
from polarref.core import isolated as runner
from polarref.core.status import RunStatus
from polarref.sfm.ba_runs import BARun


def _ba(kind, wall, setup, obs, **time_in):
    summary = BASummary("polar", "cauchy", 1.0, 0.5, 1.0, 0.5, 1.0, 0.5, 3, 3, wall, "max_iterations", 2, 10, obs, 1,
                        "fixed", time_in=time_in, setup_s=setup)
    return BARun("polar", kind=kind, summary=summary)


def test_split_ba_sums_one_kind_and_reads_every_phase():
    recs = [_ba("local", 1.0, 0.25, 100, evaluate=0.5, schur=0.125), _ba("global", 9.0, 2.0, 1000, evaluate=3.0),
            _ba("local", 2.0, 0.5, 300, evaluate=0.25, normal_equations=1.0), BARun("polar", "local", skipped="few")]
    s = RP.split_ba(recs, "local")
    assert (s.calls, s.wall_s, s.setup_s, s.observations) == (2, 3.0, 0.75, 400)
    assert dict(zip(RP.PHASES, s.phases_s)) == {"evaluate": 0.75, "normal_equations": 1.0, "schur": 0.125,
                                                "solve": 0.0, "structure": 0.0, "update": 0.0}
    assert RP.split_ba(recs, "global").wall_s == 9.0
    assert RP.split_ba(recs[1:2], "local") is None


def _run(method, k, ba, local=None):
    split = None if local is None else RP.BASplit(1, local, 0.0, (0.0,) * len(RP.PHASES), 10)
    return RP.ReplayRun(method, k, RunStatus.OK, "", ba + 5.0, ba, split, None)


def test_ratio_is_the_ratio_of_medians_and_not_tested_without_a_form():
    runs = (_run("ours-euclidean", 0, 100.0, 60.0), _run("ours-polar", 0, 130.0, 80.0),
            _run("ours-polar", 1, 118.0, 70.0), _run("ours-euclidean", 1, 90.0, 50.0),
            _run("ours-euclidean", 2, 200.0, 55.0), _run("ours-polar", 2, 121.0, 75.0))
    rep = RP.MapperReplay(RP.FORMAT, "cell", "abc", runs, None)
    assert rep.ratio() == pytest.approx(121.0 / 100.0)
    assert rep.ratio("local") == pytest.approx(75.0 / 55.0)
    assert rep.ratio("whole") is None  # no global split recorded: not tested, not 0 s
    failed = RP.ReplayRun("ours-polar", 3, RunStatus.FAILED, "boom", 1.0, None, None, None)
    only_e = RP.MapperReplay(RP.FORMAT, "cell", "abc", runs[:1] + (failed,), None)
    assert only_e.ratio() is None
    assert "not tested" in RP.summary_lines(only_e)[-3]


def _cell(tmp_path, cache=True):
    stages = tmp_path / "cell" / "stages"
    stages.mkdir(parents=True)
    for m in ("ours-euclidean", "ours-polar"):
        kw = {"cache_dir": str(tmp_path / ("cache" if cache else "gone")), "seed": 2, "threads": 2}
        (stages / f"{m}.result.json").write_text(json.dumps({"ok": True, "job": "x", "kwargs": kw, "result": None}))
    (tmp_path / "cache").mkdir(exist_ok=True)
    return tmp_path / "cell"


@pytest.mark.parametrize("case", ["no-stage", "no-cache", "repeats"])
def test_refusals_are_one_line_errors(tmp_path, capsys, case):
    cell = _cell(tmp_path, cache=case != "no-cache")
    if case == "no-stage":
        (cell / "stages" / "ours-polar.result.json").unlink()
    argv = [str(cell), "--out", str(tmp_path / "r.json")] + (["--repeats", "5000"] if case == "repeats" else [])
    assert RP.main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:")
    assert {"no-stage": "ours-polar", "no-cache": "cache", "repeats": "--repeats"}[case] in err[0]
    assert not (tmp_path / "r.json").exists()


def test_an_existing_record_is_kept_without_overwrite(tmp_path, capsys):
    cell = _cell(tmp_path)
    out = tmp_path / "r.json"
    out.write_text("{}")
    assert RP.main([str(cell), "--out", str(out)]) == 1
    assert "--overwrite" in capsys.readouterr().err and out.read_text() == "{}"


def test_finished_kwargs_reads_only_a_finished_call(tmp_path):
    path = tmp_path / "job.result.json"
    path.write_text(json.dumps({"ok": True, "job": "m:f", "kwargs": {"a": 1, "b": "x"}, "result": None}))
    assert dict(runner.finished_kwargs(path)) == {"a": 1, "b": "x"}
    path.write_text(json.dumps({"ok": False, "error": "boom"}))
    assert runner.finished_kwargs(path) is None
    path.write_text("not json")
    assert runner.finished_kwargs(path) is None
    assert runner.finished_kwargs(tmp_path / "absent.json") is None


def test_an_output_under_a_file_is_refused_before_any_run(tmp_path, capsys):
    cell = _cell(tmp_path)
    (tmp_path / "blocker").write_text("x")
    assert RP.main([str(cell), "--out", str(tmp_path / "blocker" / "r.json")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a folder" in err[0]
