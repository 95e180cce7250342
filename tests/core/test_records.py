"""polarref.core.records: strict typed records (unknown/missing keys, wrong types, NaN, versions)."""

import enum
import json
import math
from dataclasses import dataclass, field
from typing import ClassVar

import pytest

from polarref.core import records
from polarref.core.records import RecordError


class Kind(enum.Enum):
    A = "a"
    B = "b"


@dataclass
class Inner:
    x: float
    n: int


@dataclass
class Outer:
    SCHEMA_VERSION: ClassVar[int] = 2
    schema_version: int
    name: str
    kind: Kind
    flag: bool
    inner: Inner
    items: list[Inner] = field(default_factory=list)
    table: dict[str, float] = field(default_factory=dict)
    pair: tuple[float, ...] = ()
    maybe: float | None = None


def _outer():
    return Outer(2, "s", Kind.B, True, Inner(1.5, 3), [Inner(-2.0, 0)], {"k": 0.25}, (1.0, 2.0), None)


def test_round_trip_through_a_file(tmp_path):
    rec = _outer()
    path = records.save(rec, tmp_path / "r.json")
    data = json.loads(path.read_text())
    assert data["kind"] == "b" and data["pair"] == [1.0, 2.0] and data["maybe"] is None
    assert records.load(Outer, path) == rec


def test_non_finite_floats_are_written_as_missing():
    rec = _outer()
    rec.maybe = math.nan
    assert records.to_dict(rec)["maybe"] is None
    rec.inner.x = math.inf                               # a required float cannot be missing
    with pytest.raises(RecordError, match=r"inner\.x should be a finite number"):
        records.from_dict(Outer, records.to_dict(rec))


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d.update(extra=1), r"unknown key\(s\) \['extra'\] in Outer"),
    (lambda d: d["inner"].update(y=1), r"unknown key\(s\) \['y'\] in Outer\.inner"),
    (lambda d: d.pop("name"), r"missing key\(s\) \['name'\]"),
    (lambda d: d["inner"].pop("n"), r"missing key\(s\) \['n'\] in Outer\.inner"),
    (lambda d: d.update(name=3), r"Outer\.name should be a string"),
    (lambda d: d.update(flag=1), r"Outer\.flag should be true or false"),
    (lambda d: d["inner"].update(n=1.5), r"Outer\.inner\.n should be an integer"),
    (lambda d: d["inner"].update(n=True), r"Outer\.inner\.n should be an integer"),
    (lambda d: d["inner"].update(x="1"), r"Outer\.inner\.x should be a finite number"),
    (lambda d: d.update(kind="c"), r"Outer\.kind should be one of \['a', 'b'\]"),
    (lambda d: d.update(items={}), r"Outer\.items should be a list"),
    (lambda d: d.update(table=[]), r"Outer\.table should be an object"),
    (lambda d: d.update(inner=None), r"Outer\.inner should be an object"),
    (lambda d: d.update(schema_version=3), r"unsupported schema_version 3 \(this polarref reads 1\.\.2\)"),
    (lambda d: d.pop("schema_version"), r"unsupported schema_version None"),
])
def test_strict_loader_rejects(mutate, message):
    data = records.to_dict(_outer())
    records.from_dict(Outer, data)                       # the unmutated record loads
    mutate(data)
    with pytest.raises(RecordError, match=message):
        records.from_dict(Outer, data, label="r.json")


def test_defaults_fill_optional_keys():
    data = records.to_dict(_outer())
    for k in ("items", "table", "pair", "maybe"):
        del data[k]
    back = records.from_dict(Outer, data)
    assert back.items == [] and back.table == {} and back.pair == () and back.maybe is None


@pytest.mark.parametrize("text, message", [("{", "not valid JSON"), ('{"x": NaN, "n": 1}', "not valid JSON"),
                                           (b"\xff\xfe", "not UTF-8")])
def test_bad_files_name_the_problem(tmp_path, text, message):
    path = tmp_path / "bad.json"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(RecordError, match=message):
        records.load(Inner, path)
    with pytest.raises(RecordError, match="not found"):
        records.load(Inner, tmp_path / "absent.json")


def test_reconstruction_metrics_round_trip(tmp_path):
    """The one metrics record (with GT errors per image) survives save -> strict load unchanged."""
    from polarref.ba.synthetic import synthetic_reconstruction
    from polarref.metrics import ReconstructionMetrics, evaluate

    noisy, truth = synthetic_reconstruction(5, 80, seed=4, noise_px=0.5)
    m = evaluate(noisy, gt=truth)
    assert m.gt is not None and len(m.gt.per_image) == 5
    assert m.mean_reprojection_error_px > 0.0 and m.gt.rotation_error_deg_max > 0.0   # a perturbed start
    back = records.load(ReconstructionMetrics, records.save(m, tmp_path / "m.json"))
    assert back == m
    name = next(iter(m.gt.per_image))
    assert back.gt.per_image[name].rotation_error_deg == m.gt.per_image[name].rotation_error_deg
