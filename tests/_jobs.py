"""Job functions for the isolated-runner tests (module level: the spawned child imports them)."""

from dataclasses import dataclass
from pathlib import Path


@dataclass
class Counted:
    """Result of :func:`counted`: the value and how often the job has run so far."""

    value: float
    runs: int


def counted(value: float, log: str) -> Counted:
    """Appends one line to ``log`` per real run, so a test can count runs across processes."""
    path = Path(log)
    with path.open("a") as fh:
        fh.write("run\n")
    return Counted(2.0 * value, len(path.read_text().splitlines()))


def wrong_record(log: str) -> Counted:
    """Returns a record that does not match its declared type."""
    return {"value": "not a number", "runs": 1}  # type: ignore[return-value]
