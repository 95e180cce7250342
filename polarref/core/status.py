"""The one status vocabulary of a run (a method, a stage, a job, a dense run).

A ``StrEnum``: members compare equal to their strings and are written to JSON as those strings,
so files written before the enum read back unchanged."""

from __future__ import annotations

import enum


class RunStatus(enum.StrEnum):
    RUNNING = "running"   # started, not finished (a record written before the work)
    OK = "ok"
    FAILED = "failed"
    TIMEOUT = "timeout"   # stopped by the run's time budget
    SKIPPED = "skipped"   # not run (an option, or an earlier stage failed)
