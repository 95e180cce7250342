"""Isolated method jobs: results, exceptions, crashes and timeouts all come back as outcomes."""

import time

from polarref.compare.runner import run_isolated


def test_ok_result(tmp_path):
    out = run_isolated("json:loads", {"s": '{"a": 1, "b": [2, 3]}'}, 60, tmp_path, "ok")
    assert out.status == "ok" and out.result == {"a": 1, "b": [2, 3]}


def test_exception_becomes_failed_with_reason(tmp_path):
    out = run_isolated("json:loads", {"s": "not json"}, 60, tmp_path, "bad")
    assert out.status == "failed"
    assert out.reason.startswith("JSONDecodeError")
    assert "Traceback" in (tmp_path / "bad.log").read_text()


def test_crash_becomes_failed(tmp_path):
    out = run_isolated("os:abort", {}, 60, tmp_path, "crash")
    assert out.status == "failed" and "exit code" in out.reason


def test_timeout_kills_the_job(tmp_path):
    t0 = time.perf_counter()
    out = run_isolated("subprocess:run", {"args": ["sleep", "30"]}, 3, tmp_path, "slow")
    assert out.status == "timeout" and "3 s" in out.reason
    assert time.perf_counter() - t0 < 20
