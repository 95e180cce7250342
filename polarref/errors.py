"""Exceptions the CLI turns into one clear error line and a non-zero exit."""


class PolarrefError(Exception):
    """A user-facing failure: bad input, missing data, degenerate geometry.

    The message must name the offending thing (file, scene, option, value).
    """


class DataNotFoundError(PolarrefError):
    """Reference data (``$POLARREF_DATA`` or ``../shared/data``) is absent."""
