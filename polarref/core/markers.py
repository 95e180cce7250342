"""Generated blocks in hand-written text (README tables and findings): the one place that finds
and replaces what stands between a pair of marker lines."""

from __future__ import annotations

from pathlib import Path

from polarref.core.atomic import atomic_write


def read_block(text: str, begin: str, end: str) -> str | None:
    """What stands between ``begin`` and ``end`` (leading newlines dropped); None without markers."""
    if begin not in text or end not in text:
        return None
    return text.split(begin, 1)[1].split(end, 1)[0].lstrip("\n")


def replace_block(text: str, begin: str, end: str, body: str) -> str:
    """``text`` with the block between the markers replaced by ``body`` (ending in a newline).

    Raises:
        ValueError: the markers are missing.
    """
    if read_block(text, begin, end) is None:
        raise ValueError(f"no {begin!r} ... {end!r} block")
    head, rest = text.split(begin, 1)
    return head + begin + "\n" + body + end + rest.split(end, 1)[1]


def rewrite_block(path: Path, begin: str, end: str, body: str) -> Path:
    """Replace the block of the file at ``path`` in place (atomically); the README generators'
    ``python -m`` entry points end here, so a missing marker exits with one line naming the file."""
    try:
        text = replace_block(path.read_text(), begin, end, body)
    except ValueError as exc:
        raise SystemExit(f"{path}: {exc}") from exc
    return atomic_write(path, text)
