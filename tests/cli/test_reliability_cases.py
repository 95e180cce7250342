"""Regression tests for the cases of issue 15 that need more than one row of the hostile-input
table (tests/cli/test_hostile_inputs.py): real reconstructions, renders, full disks, Ctrl-C, caches.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import signal
import subprocess
import sys
import time
import tracemalloc

import numpy as np
import pytest

from polarref.cli import main

TINY = ["--preset", "small", "--spp", "2"]


def _err_lines(capsys) -> list[str]:
    return [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]


def _sfm(scene, out, *extra):
    return main(["-q", "sfm", str(scene), "--out", str(out), "--preset", "small", *extra])


# ---- case 2: image names not in gt/ -> model kept, metrics.json names the skipped metrics ---
def test_gt_names_mismatch_keeps_model_and_names_failure(small_copy, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("POLARREF_CACHE", str(tmp_path / "cache"))
    for p in (small_copy / "images").iterdir():
        p.rename(p.with_name("renamed_" + p.name))
    out = tmp_path / "out"
    assert _sfm(small_copy, out) == 1
    lines = _err_lines(capsys)
    assert len(lines) == 1 and "metrics vs ground truth skipped" in lines[0] and str(out) in lines[0]
    m = json.loads((out / "metrics.json").read_text())
    assert m["status"] == "ok" and m["metrics"].get("gt") is None
    assert "image names must match" in m["gt_skipped"]
    assert m["metrics"]["registered_images"] >= 5 and m["metrics"]["tie_points"] > 100  # the reconstruction itself is fine
    assert (out / "model" / "points3D.txt").stat().st_size > 1000


# ---- cases 6 and 12: a failing rerun never loses or mixes with an earlier result -------------
def test_full_disk_during_export_keeps_earlier_result(small_copy, tmp_path, monkeypatch, capsys):
    from polarref.model import Reconstruction

    monkeypatch.setenv("POLARREF_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "out"
    assert _sfm(small_copy, out) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    real = Reconstruction.write_text

    def full_disk(self, path):
        real(self, path)  # the model is half written when the disk fills up
        raise OSError(errno.ENOSPC, "No space left on device", str(path / "points3D.txt"))

    monkeypatch.setattr(Reconstruction, "write_text", full_disk)
    capsys.readouterr()
    assert _sfm(small_copy, out, "--overwrite", "--seed", "3") == 1
    lines = _err_lines(capsys)
    assert len(lines) == 1 and "No space left on device" in lines[0] and "free disk space" in lines[0]
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before  # the earlier finished result is untouched
    assert not [p for p in tmp_path.iterdir() if ".tmp-" in p.name]  # nothing half-written left
    monkeypatch.setattr(Reconstruction, "write_text", real)
    assert _sfm(small_copy, out, "--overwrite", "--seed", "3") == 0  # the rerun is not blocked


def test_failing_overwrite_keeps_finished_result(small_copy, tmp_path, monkeypatch, capsys):
    # issue 31 case 2: a failing --overwrite rerun leaves the finished result as it was
    monkeypatch.setenv("POLARREF_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "out"
    assert _sfm(small_copy, out) == 0
    (out / "notes.txt").write_text("mine")
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    for p in sorted((small_copy / "images").iterdir())[1:]:
        p.unlink()  # one image left: the rerun fails inside the pipeline
    capsys.readouterr()
    assert _sfm(small_copy, out, "--overwrite") == 1
    lines = _err_lines(capsys)
    assert len(lines) == 1 and "was kept" in lines[0]
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert json.loads((out / "metrics.json").read_text())["status"] == "ok"


def test_ba_full_disk_writes_nothing(tmp_path, monkeypatch, capsys):
    import polarref.core.atomic as atomic

    real_open = open

    class Full:
        def __init__(self, fh):
            self.fh = fh

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

        def write(self, data):
            self.fh.write(data[: len(data) // 2])
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(atomic, "open", lambda *a, **k: Full(real_open(*a, **k)), raising=False)
    out = tmp_path / "o.json"
    assert main(["ba", "synth-20", "--max-iterations", "2", "--out", str(out)]) == 1
    lines = _err_lines(capsys)
    assert len(lines) == 1 and lines[0].startswith(f"polarref ba: {out}: No space left on device")
    assert list(tmp_path.iterdir()) == []


# ---- case 3: render --overwrite with fewer views / another size leaves nothing stale ---------
def test_render_overwrite_removes_stale_views(tmp_path, capsys):
    out = tmp_path / "s"
    base = ["-q", "render", "comet", "--out", str(out), *TINY]
    assert main([*base, "--views", "4", "--width", "64", "--height", "48"]) == 0
    (out / "notes.txt").write_text("mine")
    assert main([*base, "--views", "2", "--width", "48", "--height", "32", "--overwrite"]) == 0
    assert sorted(p.name for p in (out / "images").iterdir()) == ["0000.png", "0001.png"]
    assert sorted(p.name for p in (out / "depth").iterdir()) == ["0000.npy", "0001.npy"]
    assert np.load(out / "depth" / "0000.npy").shape == (32, 48)
    assert (out / "notes.txt").read_text() == "mine"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


# ---- case 5: a header claiming 10^9 points allocates nothing large --------------------------
def test_bal_huge_header_validated_before_allocating(tmp_path):
    from polarref.io import FormatError
    from polarref.io.bal import read_bal

    path = tmp_path / "p.txt"
    path.write_text("1 1000000000 1000000000\n0 0 1.0 2.0\n")
    tracemalloc.start()
    try:
        with pytest.raises(FormatError, match="file ends after 1 of 1000000000 observations"):
            read_bal(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1_000_000  # was 32 GB (16 bytes x 2 x 10^9) before the first data line


# ---- case 7: Ctrl-C -> 130, also when an extension turns the KeyboardInterrupt into another error
def test_interrupt_wrapped_by_extension_exits_130(monkeypatch, capsys, tmp_path):
    import polarref.commands.render as render_cmd

    def fake_run(args):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)  # the handler raises here
        except KeyboardInterrupt:
            raise RuntimeError("drjit: exception in callback") from None
        return 0

    monkeypatch.setattr(render_cmd, "run", fake_run)
    before = signal.getsignal(signal.SIGINT)  # whatever pytest or an earlier test installed
    assert main(["render", "comet", "--out", str(tmp_path / "o")]) == 130
    lines = _err_lines(capsys)
    assert lines == ["polarref render: interrupted; finished outputs were kept"]
    assert signal.getsignal(signal.SIGINT) is before  # restored


def test_interrupt_swallowed_by_extension_still_exits_130(monkeypatch, capsys, tmp_path):
    import polarref.commands.render as render_cmd

    def fake_run(args):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)
        except KeyboardInterrupt:
            pass  # an extension that eats it and carries on
        return 0

    monkeypatch.setattr(render_cmd, "run", fake_run)
    assert main(["render", "comet", "--out", str(tmp_path / "o")]) == 130
    assert len(_err_lines(capsys)) == 1


# A child that runs the real entry point and sends itself SIGINT when the entry's import of
# ``module`` begins: before the fix a SIGINT there (the CLI's imports take over 0.5 s on a loaded
# machine) ended in an import traceback and exit -2.
_INTERRUPT_AT_IMPORT = """
import importlib.abc, os, signal, sys
MODULE = sys.argv[1]
class Interrupt(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == MODULE:
            os.kill(os.getpid(), signal.SIGINT)
        return None
sys.meta_path.insert(0, Interrupt())
sys.argv = ["polarref", "-q", "doctor"]
import polarref.__main__
polarref.__main__.run()
"""


@pytest.mark.parametrize("module", ["polarref.cli", "numpy", "ctypes", "polarref.core.execution"])
def test_sigint_while_the_cli_imports_exits_130_with_one_line(module):
    from polarref.__main__ import INTERRUPTED

    proc = subprocess.run([sys.executable, "-c", _INTERRUPT_AT_IMPORT, module],
                          capture_output=True, text=True, timeout=120)
    assert (proc.returncode, proc.stderr.strip().splitlines()) == (130, [INTERRUPTED]), proc.stderr
    assert proc.stdout == ""


def test_entry_point_without_interrupt_returns_the_commands_code():
    done = subprocess.run([sys.executable, "-m", "polarref", "--version"], capture_output=True, text=True,
                          timeout=120)
    usage = subprocess.run([sys.executable, "-m", "polarref", "no-such-command"], capture_output=True,
                           text=True, timeout=120)
    assert (done.returncode, usage.returncode) == (0, 2)
    assert "0.1.0" in done.stdout and "Traceback" not in usage.stderr


def test_console_script_goes_through_the_guarded_entry():
    import importlib
    import tomllib
    from pathlib import Path

    import polarref.__main__ as entry

    pyproject = Path(__file__).resolve().parents[2] / "pyproject.toml"
    module, func = tomllib.loads(pyproject.read_text())["project"]["scripts"]["polarref"].split(":")
    assert getattr(importlib.import_module(module), func) is entry.run


@pytest.mark.slow
def test_sigint_during_render_always_exits_130(tmp_path):
    """Real SIGINTs at random moments of a render (imports, scene build, Mitsuba)."""
    rng = np.random.default_rng(7)
    for k in range(8):
        out = tmp_path / f"r{k}"
        proc = subprocess.Popen([sys.executable, "-m", "polarref", "-q", "render", "comet", "--out", str(out),
                                 "--preset", "small", "--views", "40", "--width", "64", "--height", "48",
                                 "--spp", "4", "--seed", str(k)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(float(rng.uniform(0.5, 6.0)))
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
        lines = err.strip().splitlines()
        if proc.returncode == 0:  # finished before the signal
            continue
        assert proc.returncode == 130 and len(lines) == 1 and "interrupted" in lines[0], err
        assert not list(out.rglob(".*tmp*")) if out.exists() else True


def test_verbose_shows_traceback_and_still_one_final_line(monkeypatch, capsys, tmp_path):
    import polarref.commands.ba as ba_cmd

    def boom(args):
        raise ZeroDivisionError("simulated bug")

    monkeypatch.setattr(ba_cmd, "run", boom)
    assert main(["ba", "synth-20", "--out", str(tmp_path / "o.json")]) == 1
    lines = _err_lines(capsys)
    assert lines == ["polarref ba: synth-20: unexpected ZeroDivisionError: simulated bug "
                     "(rerun with -v for the traceback and report it)"]
    assert main(["-v", "ba", "synth-20", "--out", str(tmp_path / "o.json")]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and err.strip().splitlines()[-1].startswith("polarref ba: synth-20: unexpected")


# ---- case 8: a corrupt cache entry is detected, reported once, recomputed -------------------
def test_corrupt_cache_entry_recomputed(small_copy, tmp_path, monkeypatch, caplog):
    cache = tmp_path / "cache"
    monkeypatch.setenv("POLARREF_CACHE", str(cache))
    (small_copy / "images" / "broken.png").write_bytes(b"not an image")
    with caplog.at_level(logging.WARNING):
        assert _sfm(small_copy, tmp_path / "a") == 0
    unreadable = [r for r in caplog.records if "broken.png" in r.getMessage()]
    assert len(unreadable) == 1  # warned once, not twice
    first = json.loads((tmp_path / "a" / "metrics.json").read_text())
    entries = sorted((cache / "sfm").glob("features-*.npz"))
    assert len(entries) == 1
    data = bytearray(entries[0].read_bytes())
    data[len(data) // 2] ^= 0xFF  # one flipped byte: still a zip, wrong content
    entries[0].write_bytes(bytes(data))
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert _sfm(small_copy, tmp_path / "b") == 0
    corrupt = [r for r in caplog.records if "corrupt" in r.getMessage()]
    assert len(corrupt) == 1 and entries[0].name in corrupt[0].getMessage()
    second = json.loads((tmp_path / "b" / "metrics.json").read_text())
    assert second["runtime_s"]["features_cached"] is False
    assert second["metrics"]["tie_points"] == first["metrics"]["tie_points"]  # recomputed, same result
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert _sfm(small_copy, tmp_path / "c") == 0
    assert not [r for r in caplog.records if "corrupt" in r.getMessage()]  # reported once only
    assert json.loads((tmp_path / "c" / "metrics.json").read_text())["runtime_s"]["features_cached"] is True


# ---- case 10 (library side): BAOptions refuses a non-finite loss scale ---------------------
@pytest.mark.parametrize("scale", [float("inf"), float("nan"), 0.0, -1.0])
def test_ba_options_reject_non_finite_loss_scale(scale):
    from polarref.ba import BAOptions

    with pytest.raises(ValueError, match="loss_scale"):
        BAOptions(loss="huber", loss_scale=scale)


# ---- library errors never spell CLI flags ----------------------------------------------------
def test_library_error_names_option_cli_adds_flag(tmp_path, capsys):
    from polarref.core.atomic import publish_dir
    from polarref.core.errors import PolarrefError

    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "x").write_text("1")
    with pytest.raises(PolarrefError) as info:
        with publish_dir(tmp_path / "o"):
            pass
    assert "--" not in str(info.value) and info.value.option == "overwrite"
    out = tmp_path / "o.json"
    out.write_text("{}")
    assert main(["ba", "synth-20", "--out", str(out)]) == 1
    assert _err_lines(capsys) == [f"polarref ba: {out} exists (use --overwrite)"]


def test_memory_error_and_warnings_are_one_line(monkeypatch, capsys, tmp_path):
    import warnings

    import polarref.commands.ba as ba_cmd

    def hungry(args):
        warnings.warn("overflow encountered in square\nsecond line", RuntimeWarning)
        raise MemoryError()

    monkeypatch.setattr(ba_cmd, "run", hungry)
    assert main(["ba", "p.txt", "--out", str(tmp_path / "o.json")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "polarref ba: p.txt: out of memory (use a smaller input or preset, or free memory)"


def test_finished_process_ignores_sigint_during_teardown():
    """A real process (argv from sys.argv) whose command finished ignores SIGINT from then on: a
    Ctrl-C during interpreter/drjit teardown killed it with -2 and no line (seen in CI)."""
    code = ("import signal, sys; from polarref.cli import main; sys.argv = ['polarref', '-q', 'doctor'];"
            " rc = main(); print(rc, signal.getsignal(signal.SIGINT) is signal.SIG_IGN)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "0 True"
