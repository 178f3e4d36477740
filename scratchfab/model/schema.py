"""Strict parsing of TOML tables into frozen dataclasses.

Every configuration file of scratchfab (design, pipeline, machine profile) goes through
:func:`parse_table`: unknown keys are rejected with the nearest valid key, missing keys
and wrong types are named with the file and the dotted key path, and numeric ranges
declared in a field's metadata (``gt``, ``ge``, ``lt``, ``le``) are enforced.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import sys
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

from scratchfab.errors import ConfigError
from scratchfab.fileio import read_input

T = TypeVar("T")

#: The largest integer that converts to a finite float (larger ones overflow).
_MAX_FLOAT_INT = int(sys.float_info.max)


def spec(
    *,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
) -> dict[str, Any]:
    """Metadata for a dataclass field: numeric bounds checked by :func:`parse_table`."""
    return {"gt": gt, "ge": ge, "lt": lt, "le": le}


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file, turning I/O and syntax problems into one-line ConfigErrors."""
    file = Path(path)
    raw = read_input(file, "a TOML file")
    try:
        return tomllib.loads(raw.decode("utf-8-sig"))  # -sig: a BOM (Notepad, Excel) is dropped
    except UnicodeDecodeError:
        raise ConfigError(f"{file}: not a UTF-8 text file, expected TOML") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{file}: invalid TOML: {exc}") from None
    except ValueError:  # Python converts integers of at most 4300 digits
        raise ConfigError(f"{file}: invalid TOML: an integer of more than 4300 digits") from None
    except RecursionError:
        raise ConfigError(f"{file}: invalid TOML: arrays or tables nested too deeply") from None


def _show(value: Any) -> str:
    """``value`` for a one-line message: a huge integer by its digits, a long value cut short."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**30:
        return f"an integer of {len(str(abs(value)))} digits"
    text = repr(value)
    return text if len(text) <= 100 else f"{text[:60]}... ({len(text)} characters)"


def _type_name(tp: Any) -> str:
    origin = get_origin(tp)
    if origin is Literal:
        return " or ".join(repr(a) for a in get_args(tp))
    if origin in (Union, types.UnionType):
        return " or ".join(_type_name(a) for a in get_args(tp) if a is not type(None))
    if origin is tuple:
        args = get_args(tp)
        item = _type_name(args[0]).removeprefix("a ").removeprefix("an ")
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {item}s"
        return f"a list of {len(args)} {item}s"
    if dataclasses.is_dataclass(tp):
        return "a table"
    return {float: "a number", int: "an integer", str: "a string", bool: "true or false"}.get(
        tp, getattr(tp, "__name__", str(tp))
    )


def _convert(value: Any, tp: Any, where: str) -> Any:
    """Convert one TOML value to the annotated type ``tp`` or raise ConfigError."""
    origin = get_origin(tp)
    if tp is Any:
        return value
    if origin in (Union, types.UnionType):
        if value is None and type(None) in get_args(tp):
            return None
        options = [o for o in get_args(tp) if o is not type(None)]
        if len(options) == 1:
            return _convert(value, options[0], where)
        for option in options:
            try:
                return _convert(value, option, where)
            except ConfigError:
                continue
        raise ConfigError(f"{where}: expected {_type_name(tp)}, got {_show(value)}")
    if origin is Literal:
        if value in get_args(tp):
            return value
        raise ConfigError(f"{where}: expected {_type_name(tp)}, got {_show(value)}")
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {_show(value)}")
        if isinstance(value, int) and abs(value) > _MAX_FLOAT_INT:
            raise ConfigError(f"{where}: expected a finite number, got {_show(value)}")
        if not math.isfinite(value):
            raise ConfigError(f"{where}: expected a finite number, got {_show(value)}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {_show(value)}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {_show(value)}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {_show(value)}")
        if "\0" in value:  # no name, path or port holds one; a path with one is unusable
            raise ConfigError(f"{where}: expected a string without a NUL character (\\u0000)")
        return value
    if origin is tuple:
        args = get_args(tp)
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected {_type_name(tp)}, got {_show(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(
                f"{where}: expected {_type_name(tp)}, got {len(value)} values ({value!r})"
            )
        return tuple(
            _convert(v, a, f"{where}[{i}]")
            for i, (v, a) in enumerate(zip(value, args, strict=True))
        )
    if origin is dict:
        key_tp, val_tp = get_args(tp)
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a table, got {_show(value)}")
        return {
            _convert(k, key_tp, where): _convert(v, val_tp, f"{where}.{k}")
            for k, v in value.items()
        }
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return _parse(tp, value, where)
    raise TypeError(f"unsupported schema type {tp!r} at {where}")  # programming error


def _check_bounds(value: Any, meta: Mapping[str, Any], where: str) -> None:
    if not isinstance(value, int | float) or isinstance(value, bool):
        return
    checks = (
        ("gt", lambda v, b: v > b, "greater than"),
        ("ge", lambda v, b: v >= b, "at least"),
        ("lt", lambda v, b: v < b, "less than"),
        ("le", lambda v, b: v <= b, "at most"),
    )
    for key, ok, words in checks:
        bound = meta.get(key)
        if bound is not None and not ok(value, bound):
            lower = meta.get("gt") if meta.get("gt") is not None else meta.get("ge")
            upper = meta.get("lt") if meta.get("lt") is not None else meta.get("le")
            if lower is not None and upper is not None:
                lo = "(" if meta.get("gt") is not None else "["
                hi = ")" if meta.get("lt") is not None else "]"
                raise ConfigError(
                    f"{where}: expected a value in {lo}{lower}, {upper}{hi}, got {_show(value)}"
                )
            raise ConfigError(f"{where}: expected a value {words} {bound}, got {_show(value)}")


def check_bounds(obj: Any) -> None:
    """Refuse a dataclass whose fields lie outside their :func:`spec` bounds.

    :func:`parse_table` checks the bounds of a file's values; a ``__post_init__`` calls
    this so that a dataclass built in code meets the same bounds.

    Raises:
        ValueError: Naming the class, the field and the bounds.
    """
    for f in dataclasses.fields(obj):
        if not f.metadata:
            continue
        value = getattr(obj, f.name)
        for item in value if isinstance(value, tuple) else (value,):
            try:
                _check_bounds(item, f.metadata, f"{type(obj).__name__}.{f.name}")
            except ConfigError as exc:
                raise ValueError(str(exc)) from None


def reject_unknown_keys(data: Mapping[str, Any], valid: list[str], here: str) -> None:
    """Raise a ConfigError naming the first key of ``data`` not in ``valid`` and the nearest one.

    Args:
        data: A TOML table.
        valid: Its valid keys, in the order the message lists them.
        here: The file and dotted key of ``data``, the message's prefix.
    """
    for key in data:
        if key not in valid:
            close = difflib.get_close_matches(str(key), valid, n=1, cutoff=0.5)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise ConfigError(f"{here}: unknown key '{key}'{hint}; valid keys: {', '.join(valid)}")


def _parse(cls: type[T], data: Any, where: str) -> T:
    here = where.rstrip(":")
    if not isinstance(data, Mapping):
        raise ConfigError(f"{here}: expected a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    reject_unknown_keys(data, list(fields), here)
    kwargs: dict[str, Any] = {}
    for name, field in fields.items():
        key_where = f"{where}.{name}" if not where.endswith(":") else f"{where} {name}"
        if name not in data:
            if (
                field.default is dataclasses.MISSING
                and field.default_factory is dataclasses.MISSING
            ):
                raise ConfigError(f"{key_where}: missing required key ({_type_name(hints[name])})")
            continue
        value = _convert(data[name], hints[name], key_where)
        items = value if isinstance(value, tuple) else (value,)
        for item in items:
            _check_bounds(item, field.metadata, key_where)
        kwargs[name] = value
    try:
        return cls(**kwargs)
    except ValueError as exc:
        raise ConfigError(f"{here}: {exc}") from None


def parse_table(cls: type[T], data: Any, source: str, key: str = "") -> T:
    """Parse ``data`` (a TOML table) into dataclass ``cls``.

    Args:
        cls: A (frozen) dataclass. Field metadata from :func:`spec` gives numeric bounds;
            ``__post_init__`` may raise ``ValueError`` for cross-field checks.
        data: The table as read by :mod:`tomllib`.
        source: The file name, used as the prefix of every error message.
        key: The dotted key path of ``data`` inside the file ("" for the top level).

    Raises:
        ConfigError: One line naming ``source``, the key and what is expected.
    """
    where = f"{source}: {key}" if key else f"{source}:"
    return _parse(cls, data, where)


def to_table(obj: Any) -> Any:
    """Turn a dataclass tree back into plain TOML-ready values (tuples become lists, None dropped)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out = {}
        for f in dataclasses.fields(obj):
            if not f.init:
                continue
            value = to_table(getattr(obj, f.name))
            if value is not None:
                out[f.name] = value
        return out
    if isinstance(obj, tuple | list):
        return [to_table(v) for v in obj]
    if isinstance(obj, dict):
        return {k: to_table(v) for k, v in obj.items() if v is not None}
    return obj
