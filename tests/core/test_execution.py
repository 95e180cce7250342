"""polarref.core.execution: serial vs Dask (LocalCluster and real dask scheduler/worker processes).

Every cluster run is compared with the serial run byte for byte (images, depth maps, models) or
entry for entry (metrics.json, timings left out). The killed-worker test kills a worker process
in the middle of a render and still expects the serial bytes.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from polarref.core import execution
from polarref.core.errors import PolarrefError
from synth.config import preset
from synth.render import render_scene

sys.path.insert(0, str(Path(__file__).parents[1]))
from _cluster import SubprocessCluster, free_port, metrics_equal_apart_from_timings, tree_files  # noqa: E402

REDUCED_UAV = dict(views=6, width=128, height=96, spp=4)  # the small UAV scene, fewer and smaller images


# ---- mode selection and bad scheduler ------------------------------------------------------------
def test_mode_resolution_and_environment_variable(monkeypatch, caplog):
    monkeypatch.setattr(execution, "available_cores", lambda: 4)
    assert execution.resolve(None, None, environ={}) == execution.ExecutionSpec("serial")
    env = {execution.ENV_SCHEDULER: "tcp://10.1.2.3:8786"}
    assert execution.resolve(None, None, environ=env) == execution.ExecutionSpec("remote", address="tcp://10.1.2.3:8786")
    # explicit options win over the environment variable
    assert execution.resolve(3, None, environ=env) == execution.ExecutionSpec("local", workers=3)
    # issue 31 case 6: more workers than cores are capped at the cores, with a warning
    assert execution.resolve(999, None, environ={}) == execution.ExecutionSpec("local", workers=4)
    assert "999 workers requested on 4 available core(s): using 4" in caplog.text
    assert execution.resolve(None, "tcp://h:1", environ=env).address == "tcp://h:1"
    with pytest.raises(PolarrefError, match="exclude"):
        execution.resolve(2, "tcp://h:1", environ={})
    with pytest.raises(PolarrefError, match=">= 1"):
        execution.resolve(0, None, environ={})


def test_unreachable_scheduler_is_one_line_naming_it_and_exit_1(tmp_path):
    address = f"tcp://127.0.0.1:{free_port()}"  # nothing listens there
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "polarref", "--scheduler", address, "render", "uav",
                           "--out", str(tmp_path / "r"), "--views", "2", "--width", "32", "--height", "24"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and not ln.startswith("INFO ")]
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("polarref render: cannot reach the Dask scheduler at " + address)
    assert "Traceback" not in proc.stderr
    assert time.perf_counter() - t0 < 60  # the short connect timeout, not Dask's 30 s default x retries


def test_scheduler_from_environment_variable(tmp_path, monkeypatch, capsys):
    from polarref.cli import main

    address = f"tcp://127.0.0.1:{free_port()}"
    monkeypatch.setenv("POLARREF_SCHEDULER", address)
    try:
        rc = main(["render", "uav", "--out", str(tmp_path / "r"), "--views", "2", "--width", "32", "--height", "24"])
    finally:
        monkeypatch.delenv("POLARREF_SCHEDULER")
        execution.configure()  # back to serial for the tests that follow
    assert execution.current().in_process
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and address in err[-1] and "cannot reach the Dask scheduler" in err[-1]


def test_workers_and_scheduler_together_is_a_usage_error(capsys):
    from polarref.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["--workers", "2", "--scheduler", "tcp://127.0.0.1:1", "doctor"])
    assert exc.value.code == 2
    assert "not allowed with" in capsys.readouterr().err


# ---- LocalCluster: 2 worker processes ------------------------------------------------------------
@pytest.fixture(scope="module")
def local_cluster():
    with execution.using(workers=2) as ex:
        yield ex


def _render(out: Path, **overrides) -> None:
    render_scene("uav", out, preset("uav", "small", **{**REDUCED_UAV, **overrides}))


def test_local_cluster_render_equals_serial(tmp_path, local_cluster):
    assert not local_cluster.in_process and len(local_cluster.workers()) == 2
    pids = {w.pid for w in local_cluster.workers()}
    assert os.getpid() not in pids and len(pids) == 2
    _render(tmp_path / "dask")
    with execution.using():  # serial, in this process
        _render(tmp_path / "serial")
    a, b = tree_files(tmp_path / "serial"), tree_files(tmp_path / "dask")
    assert sorted(a) == sorted(b) and len([k for k in a if k.startswith("images/")]) == REDUCED_UAV["views"]
    assert [k for k in a if a[k] != b[k]] == []


def test_local_cluster_spreads_tasks_and_raises_task_errors(local_cluster):
    from synth.render import ViewTask, render_view

    pids = local_cluster.map(_pid_after, [0.3] * 6, desc="pids")
    assert len(set(pids)) == 2  # both worker processes took tasks
    assert os.getpid() not in pids
    bad = ViewTask("/nonexistent/folder", preset("uav", "small", **REDUCED_UAV), 0, "no_such_variant")
    with pytest.raises(PolarrefError, match="no_such_variant"):
        local_cluster.map(render_view, [bad], desc="bad")


def _pid_after(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


@pytest.mark.slow
def test_local_cluster_sfm_equals_serial(tmp_path, local_cluster, comet_small_scene):
    from polarref.cli import build_parser

    def sfm(out: Path) -> None:  # the CLI command, with the executor chosen here
        args = build_parser().parse_args(["sfm", str(comet_small_scene), "--preset", "small", "--no-cache",
                                          "--out", str(out)])
        assert args._run(args) == 0

    sfm(tmp_path / "dask")
    with execution.using():
        sfm(tmp_path / "serial")
    a, b = tree_files(tmp_path / "serial" / "model"), tree_files(tmp_path / "dask" / "model")
    assert a and a == b
    assert metrics_equal_apart_from_timings(tmp_path / "serial" / "metrics.json",
                                            tmp_path / "dask" / "metrics.json") == []


# ---- real dask scheduler + dask worker processes on 127.0.0.1 -----------------------------------
def _cli(*args: str, env: dict | None = None, timeout: float = 900) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "polarref", "-q", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory):
    cluster = SubprocessCluster(tmp_path_factory.mktemp("dask"), n=2)
    yield cluster
    cluster.close()


@pytest.mark.slow
def test_dask_cluster_render_and_sfm_equal_serial(tmp_path, dask_cluster, comet_small_scene):
    for where in ("serial", "dask"):
        extra = ["--scheduler", dask_cluster.address] if where == "dask" else []
        proc = _cli(*extra, "render", "uav", "--preset", "small", "--out", str(tmp_path / where / "uav"))
        assert proc.returncode == 0, proc.stderr
        proc = _cli(*extra, "sfm", str(comet_small_scene), "--preset", "small", "--no-cache",
                    "--out", str(tmp_path / where / "sfm"))
        assert proc.returncode == 0, proc.stderr
    a, b = tree_files(tmp_path / "serial" / "uav"), tree_files(tmp_path / "dask" / "uav")
    assert len(a) > 12 and a == b
    a, b = tree_files(tmp_path / "serial" / "sfm" / "model"), tree_files(tmp_path / "dask" / "sfm" / "model")
    assert a and a == b
    assert metrics_equal_apart_from_timings(tmp_path / "serial" / "sfm" / "metrics.json",
                                            tmp_path / "dask" / "sfm" / "metrics.json") == []


@pytest.mark.slow
def test_killed_worker_mid_render_completes_on_the_other(tmp_path):
    (tmp_path / "cluster").mkdir()
    cluster = SubprocessCluster(tmp_path / "cluster", n=2, nanny=False)  # no nanny: a killed worker stays dead
    try:
        victim_addr, victim_pid = sorted(cluster.worker_pids().items())[0]
        out = tmp_path / "dask"
        run = subprocess.Popen([sys.executable, "-m", "polarref", "-q", "--scheduler", cluster.address, "render",
                                "uav", "--preset", "small", "--out", str(out)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.time() + 300
        while not (out / "images").is_dir() or not any((out / "images").glob("*.png")):
            assert run.poll() is None and time.time() < deadline, run.communicate()
            time.sleep(0.05)
        done_before = len(list((out / "images").glob("*.png")))
        os.kill(victim_pid, signal.SIGKILL)  # in the middle of its current view
        _, err = run.communicate(timeout=600)
        assert run.returncode == 0, err
        assert done_before < 12  # it really was killed mid-run
        assert cluster.workers[0].poll() is not None or cluster.workers[1].poll() is not None
        serial = tmp_path / "serial"
        render_scene("uav", serial, preset("uav", "small"))
        a, b = tree_files(serial), tree_files(out)
        assert len(a) > 12 and [k for k in a if a.get(k) != b.get(k)] == [] and sorted(a) == sorted(b)
    finally:
        cluster.close()


@pytest.mark.slow
@pytest.mark.parametrize("where", ["local", "dask"])
def test_compare_small_equals_serial(tmp_path, where, request):
    """Every method's entries equal apart from timings, and the models byte for byte (pycolmap runs
    with one thread, so its results repeat too)."""
    base = ["compare", "comet", "--preset", "small", "--no-claims"]
    proc = _cli(*base, "--out", str(tmp_path / "serial"))
    assert proc.returncode == 0, proc.stderr
    extra = ["--workers", "2"] if where == "local" else ["--scheduler", request.getfixturevalue("dask_cluster").address]
    proc = _cli(*extra, *base, "--out", str(tmp_path / "cluster"))
    assert proc.returncode == 0, proc.stderr
    assert "8/8 methods succeeded" in proc.stdout
    assert metrics_equal_apart_from_timings(tmp_path / "serial" / "metrics.json",
                                            tmp_path / "cluster" / "metrics.json") == []
    for method in ("ours-euclidean", "ours-polar", "pycolmap-incremental-sift", "pycolmap-global-ours"):
        a = tree_files(next((tmp_path / "serial" / "runs" / method).rglob("model")))
        b = tree_files(next((tmp_path / "cluster" / "runs" / method).rglob("model")))
        assert a and a == b, method
