"""The one configuration loader: a frozen dataclass's defaults, then a TOML file, then
command-line values, every scalar and nested section type-checked (:mod:`.overrides`).

Sessions (``rosmeery run --config``) and training (``rosmeery train --config``) both load
their files here; each names the fields it reads itself (lists of names, free tables) in a
``prepare`` function, so the rest is checked the same way everywhere.
"""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path
from typing import Callable, TypeVar

from rosmeery_jax.core import overrides
from rosmeery_jax.core.errors import InputError

T = TypeVar("T")
MAX_DEPTH = 16  # tables nested deeper than any config needs are refused, not recursed into


def read_toml(path: str | Path) -> dict:
    """A TOML file as a dict; a missing, non-UTF-8, malformed or absurdly nested file is
    one InputError."""
    try:
        values = tomllib.loads(Path(path).read_bytes().decode("utf-8"))
    except FileNotFoundError:
        raise InputError(path, "file", "not found") from None
    except IsADirectoryError:
        raise InputError(path, "file", "is a folder, not a TOML file") from None
    except UnicodeDecodeError as err:
        raise InputError(path, "file", f"not UTF-8 text (byte {err.start})") from None
    except tomllib.TOMLDecodeError as err:
        raise InputError(path, "file", f"not valid TOML ({err})") from None
    except RecursionError:
        raise InputError(path, "file", f"nested deeper than {MAX_DEPTH} levels") from None
    _check_depth(values, str(path))
    return values


def _check_depth(values, source: str, depth: int = 0) -> None:
    if depth > MAX_DEPTH:
        raise InputError(source, "file", f"nested deeper than {MAX_DEPTH} levels")
    children = values.values() if isinstance(values, dict) else values if isinstance(values, list) else ()
    for v in children:
        if isinstance(v, (dict, list)):
            _check_depth(v, source, depth + 1)


def load(default: T, path: str | Path | None, cli: dict, table: str | None = None,
         prepare: Callable[[dict, str], dict] | None = None) -> T:
    """``default`` with the values of the TOML file ``path`` (its top level, or its
    ``[table]`` when it has one), then ``cli`` (None = unset). ``prepare(values, source)``
    pops and checks the fields that are not plain typed options, returning them to set as
    given; every other key goes through :func:`overrides.apply` (unknown or mistyped: one
    InputError naming ``path`` and the key)."""
    source = str(path) if path is not None else "command line"
    values = read_toml(path) if path is not None else {}
    if table and table in values:
        extra = sorted(set(values) - {table})
        if extra:
            raise InputError(source, extra[0], f"is outside the [{table}] table: move it inside, or drop the table")
        values = values[table]
        if not isinstance(values, dict):
            raise InputError(source, table, "must be a table")
    values = {**values, **{k: v for k, v in cli.items() if v is not None}}
    given = prepare(values, source) if prepare else {}
    return replace(overrides.apply(default, values, source), **given)
