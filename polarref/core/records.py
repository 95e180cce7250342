"""Typed records: strict JSON (de)serialisation of dataclasses that cross a module boundary.

A result that leaves a stage is a dataclass, written with :func:`save` and read back with
:func:`load`. Reading is strict: an unknown key, a missing required key or a value of the wrong
type is a :class:`RecordError` naming the file and the key path, so a stale or hand-edited file
fails loudly instead of being half-read. JSON has no NaN: a non-finite float is written as
``null`` (a missing value) and only an ``X | None`` field accepts ``null`` back.

Supported field types: ``int``, ``float``, ``str``, ``bool``, ``Enum`` subclasses (stored by
value), dataclasses, ``list[T]``, ``tuple[T, ...]``, ``dict[str, T]`` and ``T | None``.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import re
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

from polarref.core.atomic import atomic_write
from polarref.core.errors import PolarrefError

T = TypeVar("T")
# A parsed JSON value (what json.loads returns): the type of arguments that cross a process as JSON.
_JSON = typing.ForwardRef("JsonValue")
JsonValue = typing.Union[str, int, float, bool, None, list[_JSON], dict[str, _JSON]]


class RecordError(PolarrefError):
    """A record file does not match its schema (unknown/missing key, wrong type, bad version)."""


def _clean(value):
    """JSON-safe copy: NaN/inf become None (JSON has no NaN), tuples become lists, enums their value."""
    if isinstance(value, enum.Enum):
        return _clean(value.value)
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def to_dict(obj) -> dict:
    """The JSON-able form of the dataclass ``obj`` (see :func:`_clean`)."""
    return _clean(dataclasses.asdict(obj))


def _number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


def _build(tp, value, where: str, label: str):
    def fail(what: str):
        raise RecordError(f"{label}: {where} {what}, got {value!r}"[:400])

    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None and len(args) < len(typing.get_args(tp)):
            return None
        return _build(args[0], value, where, label)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise RecordError(f"{label}: {where} should be an object, got {type(value).__name__}")
        hints = typing.get_type_hints(tp)
        fields = {f.name: f for f in dataclasses.fields(tp) if f.init}
        unknown = set(value) - set(fields)
        if unknown:
            raise RecordError(f"{label}: unknown key(s) {sorted(unknown)} in {where}")
        missing = [n for n, f in fields.items() if n not in value and f.default is dataclasses.MISSING
                   and f.default_factory is dataclasses.MISSING]
        if missing:
            raise RecordError(f"{label}: missing key(s) {missing} in {where}")
        return tp(**{k: _build(hints[k], v, f"{where}.{k}", label) for k, v in value.items()})
    if origin in (list, tuple):
        args = typing.get_args(tp)
        if not isinstance(value, list):
            fail("should be a list")
        return origin(_build(args[0], v, f"{where}[{i}]", label) for i, v in enumerate(value))
    if origin is dict:
        _, inner = typing.get_args(tp)
        if not isinstance(value, dict):
            raise RecordError(f"{label}: {where} should be an object, got {type(value).__name__}")
        return {k: _build(inner, v, f"{where}.{k}", label) for k, v in value.items()}
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        try:
            return tp(value)
        except ValueError:
            fail(f"should be one of {[e.value for e in tp]}")
    if tp is float:
        if not _number(value):
            fail("should be a finite number")
        return float(value)
    if tp is int:
        if not _number(value) or value != int(value):
            fail("should be an integer")
        return int(value)
    if tp is bool:
        if not isinstance(value, bool):
            fail("should be true or false")
        return value
    if tp is str:
        if not isinstance(value, str):
            fail("should be a string")
        return value
    if tp is Any:
        return value
    raise TypeError(f"records: unsupported field type {tp!r} at {where}")


def from_dict(tp: type[T], data, *, label: str = "record", where: str | None = None) -> T:
    """Build the dataclass ``tp`` from parsed JSON, strictly (see the module docstring).

    Records with a ``schema_version`` field and a ``SCHEMA_VERSION`` class attribute are
    checked for a version this code reads (1..SCHEMA_VERSION).
    """
    current = getattr(tp, "SCHEMA_VERSION", None)
    if current is not None:
        version = data.get("schema_version") if isinstance(data, dict) else None
        if isinstance(version, bool) or not isinstance(version, int) or version < 1 or version > current:
            raise RecordError(f"{label}: unsupported schema_version {version!r} "
                              f"(this polarref reads 1..{current})")
    return _build(tp, data, where or tp.__name__, label)


def coerce(tp: type[T], value, *, label: str = "record") -> T:
    """The record ``tp`` from an in-memory JSON-like value, as :func:`save` then :func:`load`
    would give it (NaN/inf become None, tuples lists), strictly."""
    return from_dict(tp, _clean(value), label=label)


_NUMBER_LIST = re.compile(r"\[\s*(-?[0-9][-0-9.eE+]*(?:,\s*-?[0-9][-0-9.eE+]*)*)\s*\]")


def dumps(obj) -> str:
    """Indented JSON with innermost number lists on one line (plot arrays stay compact)."""
    text = json.dumps(to_dict(obj), indent=1, allow_nan=False)
    return _NUMBER_LIST.sub(lambda m: "[" + re.sub(r"\s+", "", m.group(1)).replace(",", ", ") + "]", text) + "\n"


def save(obj, path: str | Path) -> Path:
    """Write the record ``obj`` to ``path`` atomically (parents created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, dumps(obj))
    return path


def _reject_constant(name: str):
    raise ValueError(f"{name} is not a JSON number (a missing value is null)")


def read_json(path: str | Path):
    """Parsed JSON of ``path``; RecordError for a missing file, non-UTF-8 text or invalid JSON."""
    path = Path(path)
    if not path.is_file():
        raise RecordError(f"record file not found: {path}")
    try:
        # utf-8-sig skips a byte-order mark; NaN/Infinity are not JSON (we write missing as null)
        return json.loads(path.read_text(encoding="utf-8-sig"), parse_constant=_reject_constant)
    except UnicodeDecodeError as exc:
        raise RecordError(f"{path} is not UTF-8 text ({exc.reason} at byte {exc.start})") from exc
    except (json.JSONDecodeError, ValueError) as exc:
        raise RecordError(f"{path} is not valid JSON: {exc}") from exc


def load(tp: type[T], path: str | Path, *, label: str | None = None) -> T:
    """Read the record ``tp`` from ``path`` strictly; RecordError names the file and the key."""
    return from_dict(tp, read_json(path), label=label or str(path))
