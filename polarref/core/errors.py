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


class DataNotFoundError(PolarrefError):
    """Reference data (``$POLARREF_DATA`` or ``../shared/data``) is absent."""
