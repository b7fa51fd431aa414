"""Dotted overrides of nested frozen dataclasses, of any depth, checked against field types.

``apply(EnvConfig(), {"knowledge__coverage__soft": True}, source)`` returns a new config.
Keys are paths of field names joined by ``__`` (command lines, TOML tables flattened) or
``.``; a nested table ``{"knowledge": {"coverage": {"soft": true}}}`` is flattened first.
A value must have the field's type: bool for bool, a whole number for int, a finite number
for float, a string for str; a mismatch or an unknown name is one :class:`InputError`
naming the source and the full key.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any

from rosmeery_jax.core.errors import InputError


def flatten(values: dict, prefix: str = "", source: str = "config") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` -> ``{"a__b": 1}``; dotted keys become ``__`` paths. One setting
    spelt twice (``a__b`` and ``a.b``, or a key and a table) is an InputError: which should win?"""
    return {path: value for path, _, value in _leaves(values, prefix, source=source)}


def _leaves(values: dict, prefix: str = "", label: str = "", source: str = "config", seen: dict | None = None):
    """(path, label, value) per leaf, each path once: the path joins field names with ``__``;
    the label is the key as the user wrote it, a nested table's keys joined to it by ``.``
    (messages)."""
    seen = {} if seen is None else seen
    for key, value in values.items():
        path, name = prefix + str(key).replace(".", "__"), label + str(key)
        if isinstance(value, dict):
            yield from _leaves(value, path + "__", name + ".", source, seen)
            continue
        if path in seen:
            raise InputError(source, name, f"sets what {seen[path]} sets already: give each setting once")
        seen[path] = name
        yield path, name, value


def apply(config, overrides: dict[str, Any], source: str = "config"):
    """A copy of the dataclass ``config`` with every override set (see module docstring)."""
    for key, label, value in _leaves(overrides, source=source):
        config = _set(config, key.split("__"), value, label, source)
    return config


def in_table(err: InputError, table: str) -> InputError:
    """``err`` about a key of a file's ``table`` (``[env]``), the key spelt as in the file:
    ``robot__max_speed`` -> ``env.robot.max_speed``."""
    return InputError(err.source, f"{table}.{err.where.replace('__', '.')}", err.problem)


def _set(obj, path: list[str], value, key: str, source: str):
    names = {f.name: f for f in dataclasses.fields(obj)}
    head = path[0]
    if head not in names:
        where = key[: key.rfind(head)].rstrip("_.") or "top level"
        raise InputError(source, key, f"unknown option {head!r} in {where} (options: {', '.join(sorted(names))})")
    current = getattr(obj, head)
    if len(path) > 1:
        if not dataclasses.is_dataclass(current):
            raise InputError(source, key, f"{head!r} has no sub-options")
        return dataclasses.replace(obj, **{head: _set(current, path[1:], value, key, source)})
    hint = typing.get_type_hints(type(obj)).get(head, type(current))
    return dataclasses.replace(obj, **{head: _checked(value, hint, current, key, source)})


SCALARS = (bool, int, float, str)


def check_fields(obj, source: str, prefix: str = "") -> None:
    """Every scalar field (bool, int, float, str) of the dataclass ``obj`` holds a value of
    its type, as a file's value must (a dataclass built in Python skips the loaders' checks);
    one InputError naming ``source`` and ``prefix`` + the field. Other fields are the
    caller's to check."""
    hints = typing.get_type_hints(type(obj))
    for f in dataclasses.fields(obj):
        hint = hints[f.name]
        kinds = typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)
        if all(k in SCALARS or k is type(None) for k in kinds):
            _checked(getattr(obj, f.name), hint, None, prefix + f.name, source)


def _checked(value, hint, current, key: str, source: str):
    if dataclasses.is_dataclass(current):
        raise InputError(source, key, "is a section: set its fields as KEY__FIELD")
    allowed = typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)
    if value is None and type(None) in allowed:
        return None
    for kind in allowed:
        if kind is bool and isinstance(value, bool):
            return value
        if kind is int and isinstance(value, int) and not isinstance(value, bool):
            return value
        if kind is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            if not math.isfinite(value):
                raise InputError(source, key, f"{value!r} must be a finite number")
            return float(value)
        if kind is str and isinstance(value, str):
            return value
    names = " or ".join(getattr(k, "__name__", str(k)) for k in allowed)
    raise InputError(source, key, f"{value!r} is not of type {names}")
