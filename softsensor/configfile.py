"""Typed, validated TOML sections: the one place config files are turned into dataclasses.

Each TOML section maps onto one frozen dataclass. Fields without a default are required;
unknown keys are rejected; a field typed ``tuple[float, ...]`` (or of another scalar type) is
an array whose items are checked one by one, a field typed as a dataclass is a sub-table built
the same way; numbers are range-checked and choices checked from the field's
metadata (:func:`num`, :func:`choice`); a ``check()`` method adds cross-field rules. A key that
has moved (one rule, one key) is named in the class's ``MOVED_KEYS`` with where it went, and
refused saying so. Every error is a one-line :class:`~softsensor.errors.ConfigError` naming the
file and the dotted key, e.g. ``config/dryer1.toml: tube.length must be > 0, got -3``.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

from softsensor.errors import ConfigError

T = TypeVar("T")


#: Field metadata naming the TOML key of a field whose Python name differs (``type`` is a
#: builtin's name, so :class:`~softsensor.ingest.tagmap.TagSpec` calls it ``data_type``).
TOML_KEY = "toml_key"
_BOUNDS = ("gt", "ge", "lt", "le")


def num(default: Any = dataclasses.MISSING, *, gt: float | None = None,
        ge: float | None = None, lt: float | None = None, le: float | None = None) -> Any:
    """A dataclass field with bounds checked on load (``gt``/``ge``/``lt``/``le``)."""
    meta = {k: v for k, v in zip(_BOUNDS, (gt, ge, lt, le), strict=True) if v is not None}
    return dataclasses.field(default=default, metadata=meta)


def choice(options: typing.Iterable[str], default: Any = dataclasses.MISSING, *,
           toml_key: str | None = None) -> Any:
    """A dataclass field whose value must be one of ``options`` (read from ``toml_key`` when
    the TOML key is not the field's name)."""
    meta: dict[str, Any] = {"one_of": tuple(options)}
    if toml_key is not None:
        meta[TOML_KEY] = toml_key
    return dataclasses.field(default=default, metadata=meta)


def read_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file; a missing or malformed file is a one-line ConfigError."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: no such config file")
    try:
        with p.open("rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: malformed TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not UTF-8 text (byte {exc.start}), so not TOML") from exc
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read: {exc.strerror}") from exc


def _check_value(value: Any, typ: Any, key: str, source: str, meta: dict) -> Any:
    if "one_of" in meta:
        if isinstance(value, bool) or value not in meta["one_of"]:
            raise ConfigError(f"{source}: {key} must be one of {', '.join(meta['one_of'])}, "
                              f"got {value!r}")
        return value
    origin = typing.get_origin(typ)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(typ) if a is not type(None)]
        if value is None:
            return None
        typ = args[0]
    if dataclasses.is_dataclass(typ):
        return build_section(typ, value, key, source)
    if typing.get_origin(typ) is dict:  # a table another part of the program builds
        if not isinstance(value, dict):
            raise ConfigError(f"{source}: [{key}] must be a table, got {type(value).__name__}")
        return value
    if typing.get_origin(typ) is tuple:
        return _check_tuple(value, typing.get_args(typ), key, source, meta)
    if typ is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{source}: {key} must be true or false, got {value!r}")
        return value
    if typ is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{source}: {key} must be an integer, got {value!r}")
    elif typ is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{source}: {key} must be a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"{source}: {key} must be finite, got {value!r}")
    elif typ is str:
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{source}: {key} must be a non-empty string, got {value!r}")
        return value
    for op, bound in ((op, meta[op]) for op in _BOUNDS if op in meta):
        ok = {"gt": value > bound, "ge": value >= bound, "lt": value < bound,
              "le": value <= bound}[op]
        if not ok:
            sym = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}[op]
            raise ConfigError(f"{source}: {key} must be {sym} {bound:g}, got {value!r}"
                              f"{_range_text(meta)}")
    return value


def _range_text(meta: dict) -> str:
    """`` (its range: lo to hi)`` for a field bounded both ways, else empty."""
    lo = next((meta[op] for op in ("gt", "ge") if op in meta), None)
    hi = next((meta[op] for op in ("lt", "le") if op in meta), None)
    return "" if lo is None or hi is None else f" (its range: {lo:g} to {hi:g})"


def _check_tuple(value: Any, args: tuple[Any, ...], key: str, source: str, meta: dict
                 ) -> tuple[Any, ...]:
    """A TOML array as the tuple ``tuple[T, ...]`` of checked items (each against ``meta``'s
    bounds), named ``key[i]`` in errors."""
    if not isinstance(value, list):
        raise ConfigError(f"{source}: {key} must be an array, got {value!r}")
    item = args[0] if args else Any
    return tuple(_check_value(v, item, f"{key}[{i}]", source, meta)
                 for i, v in enumerate(value))


def build_section(cls: type[T], table: Any, key: str, source: str,
                  given: typing.Mapping[str, Any] | None = None) -> T:
    """Build the frozen dataclass ``cls`` from the TOML ``table`` found at dotted ``key``
    (``""``: the file's top level, whose keys are its sections).

    ``given`` holds field values that do not come from the table (e.g. the name of the table
    itself); their fields are not TOML keys.
    """
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: [{key}] must be a table, got {type(table).__name__}")
    given = dict(given or {})
    hints = typing.get_type_hints(cls)
    fields = {f.metadata.get(TOML_KEY, f.name): f for f in dataclasses.fields(cls)
              if f.name not in given}
    moved: typing.Mapping[str, str] = getattr(cls, "MOVED_KEYS", {})
    for old in sorted(set(table) & set(moved)):
        raise ConfigError(f"{source}: {_dotted(key, old)} is not a key any more: {moved[old]}")
    unknown = sorted(set(table) - set(fields))
    if unknown:
        what = (f"{key}.{unknown[0]} is not a known key" if key
                else f"[{unknown[0]}] is not a known section")
        raise ConfigError(f"{source}: {what} (known: {', '.join(fields)})")
    values: dict[str, Any] = given
    for toml_key, f in fields.items():
        if toml_key not in table:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                what = f"{key}.{toml_key}" if key else f"section [{toml_key}]"
                raise ConfigError(f"{source}: {what} is missing")
            continue
        values[f.name] = _check_value(table[toml_key], hints[f.name], _dotted(key, toml_key),
                                      source, dict(f.metadata))
    obj = cls(**values)
    check = getattr(obj, "check", None)
    if check is not None:
        problem = check()
        if problem:
            raise ConfigError(f"{source}: {_dotted(key, problem)}")
    return obj


def _dotted(key: str, name: str) -> str:
    """``key.name``, or ``name`` at the file's top level."""
    return f"{key}.{name}" if key else name
