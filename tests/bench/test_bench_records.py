"""The executor bench's typed records: the committed results read strictly, the overhead figure
is the wall time per task."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from polarref.bench.executor import overhead_per_task
from polarref.bench.records import ExecutorMode, TaskOverhead
from polarref.core import execution, records

ROOT = Path(__file__).resolve().parents[2]


def test_committed_executor_results_read_strictly():
    data = json.loads((ROOT / "reports" / "bench-exec" / "bench.json").read_text())
    modes = [records.from_dict(ExecutorMode, r, label="bench-exec") for r in data["results"]]
    assert [m.mode for m in modes] == [r["mode"] for r in data["results"]] and modes
    for m, r in zip(modes, data["results"]):
        assert m.render_s_per_view == pytest.approx(m.render_s / m.render_views, rel=1e-12)
        assert m.overhead.per_task_ms == pytest.approx(1e3 * m.overhead.wall_s / m.overhead.tasks, rel=1e-12)
        assert m.config.views == m.render_views
    with pytest.raises(records.RecordError, match="extra"):
        records.from_dict(ExecutorMode, {**data["results"][0], "extra": 1})


def test_overhead_per_task_in_process():
    with execution.using(workers=None) as ex:
        o = overhead_per_task(ex, 40)
    assert isinstance(o, TaskOverhead) and o.tasks == 40
    assert o.per_task_ms == pytest.approx(1e3 * o.wall_s / 40, rel=1e-12) and 0 < o.wall_s < 5.0
