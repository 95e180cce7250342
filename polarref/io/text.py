"""What every text reader shares: the one FormatError, line reading, number parsing, tracks."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from polarref.core.errors import PolarrefError
from polarref.model.observations import Observations


# A coordinate beyond this is a corrupt file, not a survey: squares and products of such values
# overflow float64 and turn costs into inf/NaN downstream.
MAX_ABS_VALUE = 1e100


class FormatError(PolarrefError):
    """A malformed input file; ``path`` and ``line`` (1-based, or None) name the place."""

    def __init__(self, path, line: int | None, message: str) -> None:
        self.path = Path(path)
        self.line = line
        where = f"{self.path}:{line}" if line is not None else f"{self.path}"
        super().__init__(f"{where}: {message}")


def read_lines(path) -> list[str]:
    """All lines of a text file; FormatError when it is missing or not text."""
    path = Path(path)
    if not path.is_file():
        raise FormatError(path, None, "file not found" if not path.exists() else "not a file")
    try:
        # utf-8-sig: a byte-order mark written by some Windows editors is skipped, not an error
        return path.read_text(encoding="utf-8-sig").splitlines()
    except UnicodeDecodeError as exc:
        raise FormatError(path, None, f"not a UTF-8 text file ({exc})") from exc
    except OSError as exc:
        raise FormatError(path, None, f"cannot read: {exc.strerror or exc}") from exc


def parse_numbers(path, lineno: int, tokens: list[str], kind=float, count: int | None = None,
                  what: str = "values") -> list:
    """Convert tokens to numbers, raising FormatError naming ``path:lineno`` on failure."""
    if count is not None and len(tokens) != count:
        raise FormatError(path, lineno, f"expected {count} {what}, found {len(tokens)}: "
                          f"{' '.join(tokens)!r}")
    try:
        values = [kind(t) for t in tokens]
    except ValueError as exc:
        raise FormatError(path, lineno, f"bad number in {what}: {exc}") from exc
    if kind is float and any(not abs(v) <= MAX_ABS_VALUE for v in values):
        bad = next(v for v in values if not abs(v) <= MAX_ABS_VALUE)
        raise FormatError(path, lineno, f"non-finite or huge value {bad!r} in {what} (|value| must be "
                          f"<= {MAX_ABS_VALUE:g} so that its square cannot overflow float64)")
    return values


def read_tracks(path, num_views: int, view: str = "camera", distinct: bool = False):
    """Parse a track file with one point per line: ``n  v1 u1 w1  v2 u2 w2 ...``.

    The layout shared by ParallaxBA's ``Feature.pmba`` and PVL-BA's ``Feature.txt``: ``n``
    observations of (0-based view index, u, v). Blank lines are skipped.

    Args:
        path: the track file.
        num_views: number of cameras/images; indices must lie in ``0..num_views-1``.
        view: what an index names, for error messages ("camera" or "image").
        distinct: reject a track that lists one view twice.
    Returns:
        (:class:`~polarref.model.Observations` (K) with image = the view index, track_start
        (P+1,) int64).
    Raises:
        FormatError naming the file and line.
    """
    path = Path(path)
    obs_point, obs_view, obs_uv, starts = [], [], [], [0]
    for i, s in enumerate(read_lines(path)):
        tokens = s.split()
        if not tokens:
            continue
        (n,) = parse_numbers(path, i + 1, tokens[:1], int, what="track length")
        if n < 1 or len(tokens) != 1 + 3 * n:
            raise FormatError(path, i + 1, f"track length {n} needs {1 + 3 * n} fields, "
                              f"found {len(tokens)}")
        trip = np.array(parse_numbers(path, i + 1, tokens[1:], float, what="observations"))
        trip = trip.reshape(n, 3)
        idx = trip[:, 0]
        if np.any(idx != np.round(idx)) or idx.min() < 0 or idx.max() >= num_views:
            raise FormatError(path, i + 1, f"{view} index out of range 0..{num_views - 1} "
                              f"or not an integer: {idx.tolist()}")
        if distinct and len(set(idx.tolist())) != n:
            raise FormatError(path, i + 1, f"{view} listed twice in one track: {idx.tolist()}")
        obs_point.extend([len(starts) - 1] * n)
        obs_view.extend(idx.astype(np.int64).tolist())
        obs_uv.append(trip[:, 1:])
        starts.append(starts[-1] + n)
    obs = Observations.from_arrays(np.array(obs_view, dtype=np.int64), np.array(obs_point, dtype=np.int64),
                                   np.concatenate(obs_uv) if obs_uv else np.zeros((0, 2)))
    return obs, np.array(starts, dtype=np.int64)
