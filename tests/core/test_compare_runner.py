"""Isolated method jobs: results, exceptions, crashes and timeouts all come back as outcomes."""

import json
import os
import subprocess
import time

from _jobs import Counted, counted, wrong_record

from polarref.core.isolated import run_isolated


def test_ok_result(tmp_path):
    out = run_isolated(json.loads, {"s": '{"a": 1, "b": [2, 3]}'}, 60, tmp_path, "ok")
    assert out.status == "ok" and out.result == {"a": 1, "b": [2, 3]}


def test_typed_record_comes_back_typed(tmp_path):
    out = run_isolated(counted, {"value": 1.5, "log": str(tmp_path / "n")}, 60, tmp_path, "rec")
    assert out.status == "ok" and out.result == Counted(3.0, 1)


def test_record_of_the_wrong_shape_is_a_failure(tmp_path):
    out = run_isolated(wrong_record, {"log": ""}, 60, tmp_path, "bad")
    assert out.status == "failed" and "malformed job result" in out.reason and "value" in out.reason


def test_finished_job_is_reused_only_for_the_same_call(tmp_path):
    """hloc-style resume: a finished job is loaded, not rerun; new arguments or reuse=False rerun it."""
    log = str(tmp_path / "runs.txt")
    runs = lambda: len((tmp_path / "runs.txt").read_text().splitlines())
    first = run_isolated(counted, {"value": 1.0, "log": log}, 60, tmp_path, "job")
    assert first.result == Counted(2.0, 1) and not first.reused
    again = run_isolated(counted, {"value": 1.0, "log": log}, 60, tmp_path, "job", reuse=True)
    assert runs() == 1 and again.reused and again.result == Counted(2.0, 1)
    assert again.wall_s == first.wall_s                       # the recorded time, not a new one
    other = run_isolated(counted, {"value": 5.0, "log": log}, 60, tmp_path, "job", reuse=True)
    assert runs() == 2 and not other.reused and other.result == Counted(10.0, 2)
    forced = run_isolated(counted, {"value": 5.0, "log": log}, 60, tmp_path, "job", reuse=False)
    assert runs() == 3 and not forced.reused and forced.result.runs == 3


def test_failed_job_is_not_reused(tmp_path):
    assert run_isolated(json.loads, {"s": "not json"}, 60, tmp_path, "bad").status == "failed"
    again = run_isolated(json.loads, {"s": "not json"}, 60, tmp_path, "bad", reuse=True)
    assert again.status == "failed" and not again.reused


def test_exception_becomes_failed_with_reason(tmp_path):
    out = run_isolated(json.loads, {"s": "not json"}, 60, tmp_path, "bad")
    assert out.status == "failed"
    assert out.reason.startswith("JSONDecodeError")
    assert "Traceback" in (tmp_path / "bad.log").read_text()


def test_crash_becomes_failed(tmp_path):
    out = run_isolated(os.abort, {}, 60, tmp_path, "crash")
    assert out.status == "failed" and "exit code" in out.reason


def test_timeout_kills_the_job(tmp_path):
    t0 = time.perf_counter()
    out = run_isolated(subprocess.run, {"args": ["sleep", "30"]}, 3, tmp_path, "slow")
    assert out.status == "timeout" and "3 s" in out.reason
    assert time.perf_counter() - t0 < 20
