"""Strict, typed loading of the app's YAML configs into dataclasses (the idiom of Drake's ``yaml_load_typed``).

A config section is a dataclass whose fields are the section's keys; :func:`load_typed` builds it from a parsed
YAML mapping and refuses what the schema does not hold:

* an unknown or misspelt key is an error naming the file, the key path and the nearest valid key
  (``rfma.yaml: scafolds: unknown key; did you mean 'scaffolds'?``), found by :mod:`difflib`;
* a value of the wrong type is an error naming the key path: a word where a number belongs, a list of the wrong
  length where a fixed-size tuple belongs (``tuple[float, float, float]``), a number where a list belongs;
* a field without a default is required.

Supported field types: ``float``, ``int``, ``bool``, ``str``, ``Any``, nested dataclasses, ``X | None``, unions
(first alternative that fits), ``list[X]``, ``tuple[X, ...]``, fixed ``tuple[X, Y]`` and ``dict[str, X]``. An int
is accepted for a float; a bool is never a number. The physics checks (ranges, joint counts, limits) stay with each
config's own validation step; this module checks only the shape of the file.

Drake's ``pydrake.common.yaml.yaml_load_typed`` does the same for Drake's own structs; this loader adds what the
app's messages need (the file, the whole key path, the nearest key, per-joint values) and needs no C++ binding.
"""
from __future__ import annotations

import dataclasses
import difflib
import numbers
import os
import types
import typing
from pathlib import Path
from typing import Any, Iterable, TypeVar

import numpy as np
import yaml

__all__ = ["ConfigError", "load_typed", "read_yaml", "check_keys", "nearest_key", "nearest_hint", "per_joint",
           "join_key"]

T = TypeVar("T")


class ConfigError(ValueError):
    """A config file does not fit its schema; the message names the file, the key path and the problem."""


def nearest_key(key: str, valid: Iterable[str]) -> str | None:
    """The valid key nearest ``key``: the closest by :mod:`difflib` ratio (≥ 0.6; a tie goes to the longer common
    prefix, so ``ixzz`` → ``ixz``), else one that ``key`` abbreviates or extends (``com`` → ``com_flange``), else the
    closest with ratio ≥ 0.4; ``None`` when nothing is near."""
    valid = sorted(str(v) for v in valid)
    key = str(key)
    scored = sorted(((difflib.SequenceMatcher(None, key, v).ratio(), len(os.path.commonprefix([key, v])), v)
                     for v in valid), key=lambda s: (-s[0], -s[1], s[2]))
    if scored and scored[0][0] >= 0.6:
        return scored[0][2]
    affix = [v for v in valid if key and (v.startswith(key) or key.startswith(v))]
    if affix:
        return min(affix, key=lambda v: abs(len(v) - len(key)))
    return scored[0][2] if scored and scored[0][0] >= 0.4 else None


def nearest_hint(key: str, valid: Iterable[str]) -> str:
    """``"; did you mean 'x'? (valid: ...)"`` for the valid key nearest ``key`` (:func:`nearest_key`), else the
    list of valid keys."""
    valid = sorted(str(v) for v in valid)
    near = nearest_key(key, valid)
    listing = ", ".join(valid) or "(none)"
    return f"; did you mean '{near}'? (valid: {listing})" if near else f"; valid keys: {listing}"


def check_keys(mapping: dict[str, Any], valid: Iterable[str], where: str,
               error: type[Exception] = ConfigError) -> None:
    """Raise ``error`` for the first key of ``mapping`` not in ``valid``, naming ``where.key`` and the nearest key."""
    valid = list(valid)
    for key in mapping:
        if key not in valid:
            raise error(f"{join_key(where, str(key))}: unknown key{nearest_hint(str(key), valid)}")


def read_yaml(path: str | Path | None = None, text: str | None = None, source: str | None = None,
              error: type[Exception] = ConfigError) -> Any:
    """Parse YAML ``text`` (or the file ``path``) with ``yaml.safe_load``; a syntax error names ``source``."""
    source = source or str(path)
    if text is None:
        text = Path(path).read_text()
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise error(f"{source}: not valid YAML ({exc})") from exc


def load_typed(schema: type[T], data: Any, where: str, error: type[Exception] = ConfigError) -> T:
    """The dataclass ``schema`` built strictly from the parsed YAML ``data`` (module docstring); ``where`` is the
    file (and key path) named in errors. ``None`` gives the schema's defaults."""
    return _convert(schema, {} if data is None else data, where, error)


def per_joint(value: Any, n: int, where: str, error: type[Exception] = ConfigError) -> list[float]:
    """A per-joint value (one number for every joint, or a list of ``n`` numbers) as a list of ``n`` floats."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        out = _convert(list[float], value, where, error)
        if len(out) != n:
            raise error(f"{where}: expected one number or a list of {n} numbers (one per joint), got {len(out)}")
        return out
    return [_convert(float, value, where, error)] * n


# ------------------------------------------------------------------------------------------------------------------
def join_key(where: str, key: str) -> str:
    """The key path: ``file: key`` below the file, ``file: a.b`` further down."""
    return f"{where}.{key}" if ": " in where else f"{where}: {key}"


def _type_name(tp: Any) -> str:
    if tp is float:
        return "a number"
    if tp is int:
        return "an integer"
    if tp is bool:
        return "true or false"
    if tp is str:
        return "a string"
    origin = typing.get_origin(tp)
    if origin in (list, tuple):
        return "a list"
    if origin is dict or dataclasses.is_dataclass(tp):
        return "a mapping"
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(tp))
    return getattr(tp, "__name__", str(tp))


def _convert(tp: Any, value: Any, where: str, error: type[Exception]) -> Any:
    if tp is Any:
        return value
    if isinstance(value, np.ndarray):            # a mapping built in code (a diagnosis' patch) may hold arrays
        value = value.tolist()
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        candidates = [a for a in args if a is not type(None)]
        for a in candidates:
            try:
                return _convert(a, value, where, error)
            except error:
                if len(candidates) == 1:
                    raise
        raise error(f"{where}: expected {_type_name(tp)}, got {value!r}")
    if dataclasses.is_dataclass(tp):
        return _dataclass(tp, value, where, error)
    if tp is bool:
        if not isinstance(value, bool):
            raise error(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise error(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, numbers.Integral):
            raise error(f"{where}: expected an integer, got {value!r}")
        return int(value)
    if tp is str:
        if not isinstance(value, str):
            raise error(f"{where}: expected a string, got {value!r}")
        return value
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise error(f"{where}: expected a list, got {value!r}")
        args = typing.get_args(tp)
        if origin is list or (len(args) == 2 and args[1] is Ellipsis):
            out = [_convert(args[0], v, f"{where}[{i}]", error) for i, v in enumerate(value)]
            return out if origin is list else tuple(out)
        if len(value) != len(args):
            raise error(f"{where}: expected a list of {len(args)} entries, got {len(value)}: {list(value)!r}")
        return tuple(_convert(a, v, f"{where}[{i}]", error) for i, (a, v) in enumerate(zip(args, value)))
    if origin is dict:
        if not isinstance(value, dict):
            raise error(f"{where}: expected a mapping, got {value!r}")
        _, vt = typing.get_args(tp)
        return {str(k): _convert(vt, v, join_key(where, str(k)), error) for k, v in value.items()}
    raise TypeError(f"typed_yaml: unsupported field type {tp!r} at {where}")


def _dataclass(cls: type, value: Any, where: str, error: type[Exception]) -> Any:
    if value is None:
        value = {}
    if not isinstance(value, dict):
        raise error(f"{where}: expected a mapping of keys, got {value!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    check_keys(value, fields, where, error)
    kwargs = {}
    for name, f in fields.items():
        if name in value:
            kwargs[name] = _convert(hints[name], value[name], join_key(where, name), error)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise error(f"{join_key(where, name)}: required key is missing")
    return cls(**kwargs)
