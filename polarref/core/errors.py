"""Exceptions the CLI turns into one clear error line and a non-zero exit."""

from __future__ import annotations


class PolarrefError(Exception):
    """A user-facing failure: bad input, missing data, degenerate geometry.

    The message must name the offending thing (file, scene, option, value) and, where there is
    one, what to do. Library code never spells command-line flags: it names the parameter in
    ``option`` (e.g. ``"overwrite"``) and the CLI adds "use --overwrite".
    """

    def __init__(self, message: str = "", *, option: str | None = None) -> None:
        super().__init__(message)
        self.option = option


class UsageError(PolarrefError):
    """Options that cannot go together, found after parsing: a usage error (exit 2)."""


class DataNotFoundError(PolarrefError):
    """Reference data (``$POLARREF_DATA`` or ``../shared/data``) is absent."""


def is_out_of_memory(exc: BaseException) -> bool:
    """MemoryError, or OpenCV's allocation failure (a ``cv2.error``, not a MemoryError)."""
    if isinstance(exc, MemoryError):
        return True
    text = str(exc)
    return type(exc).__module__.startswith("cv2") and ("Insufficient memory" in text
                                                       or "Failed to allocate" in text)


def failure_text(exc: BaseException) -> str:
    """What a failed run's metrics.json records about ``exc``: never empty, the disk error or
    interrupt named as such."""
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted (Ctrl-C or SIGINT) before the run finished"
    if is_out_of_memory(exc):
        return "out of memory"
    if isinstance(exc, OSError):
        what = " ".join(str(exc.strerror or exc).split()) or type(exc).__name__
        return f"{exc.filename}: {what}" if exc.filename else what
    text = " ".join(str(exc).split())
    if isinstance(exc, PolarrefError):
        return text or type(exc).__name__
    return f"unexpected {type(exc).__name__}: {text}" if text else f"unexpected {type(exc).__name__}"
