"""Atomic outputs: a file or a folder appears complete under its final name, or not at all.

Every command writes through these helpers. A file is written to a hidden temporary sibling
``.<name>.tmp-<pid>`` and renamed over ``<name>``; a folder is built in a hidden temporary
sibling of the same form and renamed into place only when complete. A crash, a full disk or
Ctrl-C therefore never leaves a half-written output, and an earlier result is only replaced by
a complete new one.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import IO

from polarref.core.errors import PolarrefError


def temp_sibling(path: str | os.PathLike, tag: str = "tmp") -> Path:
    """The hidden temporary name beside ``path``: ``.<name>.<tag>-<pid>``."""
    path = Path(path)
    return path.with_name(f".{path.name}.{tag}-{os.getpid()}")


def _remove(path: Path) -> None:
    with contextlib.suppress(OSError):
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb", *, encoding: str | None = None) -> Iterator[IO]:
    """Open a temporary sibling of ``path`` for writing; rename it over ``path`` on success.

    On any exception (including KeyboardInterrupt) the temporary file is removed and ``path``
    is left as it was. Raises OSError (e.g. ENOSPC, EACCES) from the write or the rename.
    """
    if "w" not in mode:
        raise ValueError(f"atomic_open writes only; got mode {mode!r}")
    path = Path(path)
    tmp = temp_sibling(path)
    if "b" not in mode and encoding is None:
        encoding = "utf-8"
    try:
        with open(tmp, mode, encoding=encoding) as fh:
            yield fh
            fh.flush()
        os.replace(tmp, path)
    except OSError as exc:
        _remove(tmp)
        # name the output the user asked for, not our temporary name
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from exc
    except BaseException:
        _remove(tmp)
        raise


def atomic_write(path: str | os.PathLike, data: str | bytes) -> Path:
    """Write ``data`` (text as UTF-8, or bytes) to ``path`` atomically; return ``path``."""
    path = Path(path)
    with atomic_open(path, "wb") as fh:
        fh.write(data.encode("utf-8") if isinstance(data, str) else data)
    return path


def check_writable_parent(path: str | os.PathLike) -> None:
    """Fail early (before any work) when ``path`` cannot be created: PolarrefError naming it.

    Checks that the nearest existing ancestor is a writable folder and that ``path`` itself,
    if it exists, is not a folder where a file is expected (callers check that separately).
    """
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    probe = parent
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise PolarrefError(f"{path}: {probe} is not a folder (choose another output path)")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise PolarrefError(f"{path}: folder {probe} is not writable (choose another output path)")


MANIFEST = ".polarref-outputs"  # names of the entries the last publish_dir put in a folder


@contextlib.contextmanager
def publish_dir(target: str | os.PathLike, *, overwrite: bool = False,
                owned: tuple[str, ...] = ()) -> Iterator[Path]:
    """Build a folder in a temporary sibling and rename it to ``target`` when the block ends.

    Replacing a folder (``overwrite``) swaps the whole new folder in, so our outputs are never a
    mix of two runs; entries that are not ours (a user's notes) are moved over into the new
    folder. "Ours" are the entries listed in the folder's manifest (written by the previous
    publish) or, for folders written before manifests existed, the names in ``owned``.

    Args:
        target: the final folder.
        overwrite: replace an existing non-empty ``target`` (it is only touched once the new
            folder is complete).
        owned: names this kind of output may contain, for folders without a manifest.
    Yields:
        the temporary folder to write into. On an exception it is removed and ``target`` is
        left as it was.
    Raises:
        PolarrefError: ``target`` is a file, or is non-empty and ``overwrite`` is false.
    """
    target = Path(target)
    check_dir_target(target, overwrite)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(target)
    _remove(tmp)
    tmp.mkdir()
    try:
        yield tmp
        names = sorted(p.name for p in tmp.iterdir())
        atomic_write(tmp / MANIFEST, "".join(n + "\n" for n in names))
    except BaseException:
        _remove(tmp)
        raise
    ours = set(owned) | {MANIFEST}
    if (target / MANIFEST).is_file():
        ours |= set((target / MANIFEST).read_text(encoding="utf-8", errors="replace").split("\n"))
    _swap_into_place(tmp, target, ours)


def check_dir_target(target: Path, overwrite: bool) -> None:
    """PolarrefError unless ``target`` is absent, an empty folder, a folder holding only a failed
    run of ours (a corrected rerun needs no flag), or a folder we may replace."""
    if target.exists() and not target.is_dir():
        raise PolarrefError(f"{target} exists and is not a folder (choose another output path)")
    if target.is_dir() and any(target.iterdir()) and not overwrite and not holds_failed_run(target):
        raise PolarrefError(f"output folder {target} exists and is not empty", option="overwrite")


def _run_status(target: Path) -> str | None:
    """The ``status`` of ``target/metrics.json`` (None: absent or unreadable)."""
    try:
        data = json.loads((Path(target) / "metrics.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    status = data.get("status") if isinstance(data, dict) else None
    return status if isinstance(status, str) else None


def holds_failed_run(target: Path) -> bool:
    """True when every entry of ``target`` was written by one of our runs (its manifest) and
    that run's metrics.json says it failed: nothing in it is worth keeping."""
    target = Path(target)
    if _run_status(target) != "failed" or not (target / MANIFEST).is_file():
        return False
    ours = set((target / MANIFEST).read_text(encoding="utf-8", errors="replace").split("\n")) | {MANIFEST}
    return all(p.name in ours for p in target.iterdir())


def holds_finished_result(target: Path) -> bool:
    """True when ``target/metrics.json`` records a run that did not fail: a failing rerun must
    leave such a folder as it is rather than replace it by its failure."""
    status = _run_status(Path(target))
    return status is not None and status != "failed"


def refuse_inside_inputs(out: str | os.PathLike, inputs: Sequence[str | os.PathLike]) -> None:
    """PolarrefError when the output path ``out`` is one of ``inputs``, lies inside one, or
    contains one: writing (or swapping a folder) there would replace the inputs themselves.

    Paths are compared after resolving symbolic links and ``..``.
    """
    target = Path(out).resolve()
    for given in inputs:
        src = Path(given).resolve()
        if target == src or src in target.parents or target in src.parents:
            relation = ("is" if target == src else "lies inside" if src in target.parents else "contains")
            raise PolarrefError(f"{out}: the output {relation} the input {given}; outputs are never "
                                "written into their inputs (choose another output path)")


def _swap_into_place(tmp: Path, target: Path, ours: set[str]) -> None:
    old = temp_sibling(target, "old")
    moved_old = False
    try:
        if target.exists():
            _remove(old)
            os.replace(target, old)
            moved_old = True
        os.replace(tmp, target)
    except BaseException:
        if moved_old and not target.exists():
            os.replace(old, target)
        _remove(tmp)
        raise
    if not moved_old:
        return
    # Carry the user's entries over; if this is interrupted they are still in ``old``, not lost.
    for entry in old.iterdir():
        if entry.name not in ours and not (target / entry.name).exists() \
                and not entry.name.startswith(f".{target.name}."):
            os.replace(entry, target / entry.name)
    if not any(e.name not in ours for e in old.iterdir()):
        _remove(old)


def is_disk_full(exc: BaseException) -> bool:
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)
