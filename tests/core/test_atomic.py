"""polarref.core.atomic: outputs appear whole or not at all; a replaced folder never mixes two runs."""

import errno
import os

import pytest

from polarref.core.atomic import MANIFEST, atomic_open, atomic_write, publish_dir
from polarref.core.errors import PolarrefError


def _hidden(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(".") and p.name != MANIFEST)


def test_atomic_write_replaces_whole_file_or_nothing(tmp_path):
    path = tmp_path / "a.json"
    atomic_write(path, "old")
    with pytest.raises(RuntimeError):
        with atomic_open(path, "w") as fh:
            fh.write("new, half")
            raise RuntimeError("crash mid-write")
    assert path.read_text() == "old" and _hidden(tmp_path) == []
    atomic_write(path, b"\x00new")
    assert path.read_bytes() == b"\x00new"


def test_atomic_open_names_the_target_on_os_errors(tmp_path):
    target = tmp_path / "missing-dir" / "a.json"
    with pytest.raises(OSError) as info:
        atomic_write(target, "x")
    assert info.value.errno == errno.ENOENT and info.value.filename == str(target)


def test_publish_dir_swaps_whole_folder_and_keeps_user_files(tmp_path):
    out = tmp_path / "run"
    with publish_dir(out) as d:
        (d / "model").mkdir()
        (d / "model" / "a.txt").write_text("1")
        (d / "metrics.json").write_text("first")
    (out / "notes.txt").write_text("mine")
    with pytest.raises(PolarrefError, match="not empty") as info:
        with publish_dir(out):
            pass
    assert info.value.option == "overwrite"
    with publish_dir(out, overwrite=True) as d:
        (d / "metrics.json").write_text("second")  # no model/ this time
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "metrics.json", "notes.txt"]
    assert (out / "metrics.json").read_text() == "second" and (out / "notes.txt").read_text() == "mine"
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_publish_dir_interrupted_leaves_old_folder(tmp_path):
    out = tmp_path / "run"
    with publish_dir(out) as d:
        (d / "metrics.json").write_text("first")
    with pytest.raises(KeyboardInterrupt):
        with publish_dir(out, overwrite=True) as d:
            (d / "metrics.json").write_text("half")
            raise KeyboardInterrupt
    assert (out / "metrics.json").read_text() == "first"
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_publish_dir_without_manifest_uses_owned_names(tmp_path):
    out = tmp_path / "old-style"
    (out / "model").mkdir(parents=True)
    (out / "metrics.json").write_text("old")
    (out / "keep.txt").write_text("user")
    with publish_dir(out, overwrite=True, owned=("model", "metrics.json")) as d:
        (d / "metrics.json").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "keep.txt", "metrics.json"]


def test_publish_dir_refuses_a_file_target(tmp_path):
    target = tmp_path / "f"
    target.write_text("x")
    with pytest.raises(PolarrefError, match="not a folder"):
        with publish_dir(target, overwrite=True):
            pass
    assert target.read_text() == "x" and os.listdir(tmp_path) == ["f"]
