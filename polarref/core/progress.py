"""Progress reporting: silent in the library, tqdm bars only when the CLI enables them."""

from __future__ import annotations

from typing import Iterable, Iterator, TypeVar

T = TypeVar("T")
_ENABLED = False


def enable(flag: bool = True) -> None:
    """Called by the CLI only; library users and tests get no bars."""
    global _ENABLED
    _ENABLED = flag


def track(items: Iterable[T], desc: str, total: int | None = None) -> Iterator[T]:
    """Iterate over ``items``, showing a progress bar when enabled."""
    if not _ENABLED:
        yield from items
        return
    try:
        from tqdm import tqdm
    except ImportError:  # tqdm is a dependency, but a bar is not worth a crash
        yield from items
        return
    yield from tqdm(items, desc=desc, total=total, leave=False, dynamic_ncols=True)
