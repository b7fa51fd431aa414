"""Plugins by name: ``FILE.py:Name`` or ``package.module:Name``, wherever the benchmark takes
a name (policies, metrics). A plugin is code the user chose to run: it is imported as it
is, with the user's rights, like any Python module they import themselves.

Loading a plugin never raises anything but :class:`InputError`, one line naming the plugin
and the problem (no such file, a syntax or import error, no such name).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
import traceback
from contextlib import contextmanager
from pathlib import Path

from rosmeery_jax.core import specs
from rosmeery_jax.core.errors import InputError


def load(spec: str, source: str, field: str):
    """The object ``spec`` names; one InputError naming ``source``, ``field`` and the plugin."""
    m = specs.PLUGIN.fullmatch(spec)
    if m is None:
        raise InputError(source, field, f"{spec!r} is not a plugin name (FILE.py:Name or package.module:Name)")
    module = _module(m.group("module"), spec, source, field)
    try:
        return getattr(module, m.group("name"))
    except AttributeError:
        raise InputError(source, field, f"plugin {spec!r}: {m.group('module')} defines no {m.group('name')!r}") from None


def _module(where: str, spec: str, source: str, field: str):
    if where.endswith(".py") and not Path(where).is_file():
        raise InputError(source, field, f"plugin {spec!r}: no such file {where!r}")
    try:
        if where.endswith(".py"):
            path = Path(where).resolve()
            name = "rosmeery_plugin_" + hashlib.sha1(str(path).encode()).hexdigest()[:12]
            if name in sys.modules:
                return sys.modules[name]
            loader = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(loader)
            sys.modules[name] = module
            try:
                loader.loader.exec_module(module)
            except BaseException:
                sys.modules.pop(name, None)
                raise
            return module
        return importlib.import_module(where)
    except InputError as err:  # ours, raised by the plugin's code (a register_metric name)
        raise InputError(source, field, f"plugin {spec!r} failed to import: {err}") from None
    except SystemExit as err:  # its exit would end the command with no word (and status 0)
        raise InputError(source, field, f"plugin {spec!r} failed to import: it exits (sys.exit({err.code!r}))") \
            from None
    except Exception as err:  # the plugin's own code failed to import: say where
        raise InputError(source, field, f"plugin {spec!r} failed to import: {describe(err)}") from None


@contextmanager
def raised_by(spec: str, field: str, doing: str, who: str | None = None):
    """An exception of a plugin's code while it runs (not ours: an InputError passes) as one
    InputError naming the config ``field``, the plugin (``who``: how to name it, when not by
    its entry ``spec``), what it was doing and its line."""
    try:
        yield
    except InputError:
        raise
    except SystemExit as err:
        raise InputError("config", field, f"{who or f'plugin {spec!r}'} exits in {doing} (sys.exit({err.code!r}))") \
            from None
    except Exception as err:
        raise InputError("config", field, f"{who or f'plugin {spec!r}'} failed in {doing}: {describe(err)}") from None


def describe(err: Exception) -> str:
    """An exception raised by a plugin's code, in one short line, with the line of the
    user's code it came from (the last frame outside this package and the installed
    libraries)."""
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0][:200] if text else ''}{_where(err)}"


def _where(err: Exception) -> str:
    if isinstance(err, SyntaxError) and err.filename:
        return f" ({Path(err.filename).name}, line {err.lineno})"
    ours = [Path(__file__).resolve().parents[1], Path(sys.prefix).resolve(), Path(sys.base_prefix).resolve()]
    for frame in reversed(traceback.extract_tb(err.__traceback__)):
        path = Path(frame.filename).resolve()
        if frame.filename.startswith("<") or any(path.is_relative_to(p) for p in ours):
            continue
        return f" ({path.name}, line {frame.lineno}, in {frame.name})"
    return ""
