"""Procedural world names and their files: ``procedural:KIND:SEED[:option=value]...``
(:data:`NAME_FORM`) works wherever a world name does; the world is made by the generator
(:mod:`rosmeery_jax.world.generate`) and written on first use into a cache folder
(:func:`procedural_path`), where a later use checks it against a fresh one.
"""

from __future__ import annotations

import os
from pathlib import Path

from rosmeery_jax.core import specs
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import write_atomic
from rosmeery_jax.world.generate import VERSION, GenOptions, Layout, check_options, generate

# the options a procedural name takes, each with the letter NAME_FORM shows for its value
_NAME_OPTIONS = {"rooms": "R", "objects": "K", "clutter": "X", "tuck": "X", "turn": "D", "islands": "X", "spare": "X"}
NAME_FORM = "procedural:KIND:SEED" + "".join(f"[:{k}={v}]" for k, v in _NAME_OPTIONS.items())


def parse_name(text: str) -> GenOptions:
    """A name of the form :data:`NAME_FORM` as options (InputError if bad)."""
    m = specs.PROCEDURAL_NAME.match(text)
    if not m:
        raise InputError(text, "", f"a procedural world is named {NAME_FORM}")
    kind, seed, extra = m.groups()
    opts: dict = {}
    for item in filter(None, (extra or "").split(":")):
        key, _, value = item.partition("=")
        if key not in _NAME_OPTIONS:
            *most, last = _NAME_OPTIONS
            raise InputError(text, key, f"unknown option ({', '.join(most)} or {last})")
        if key in opts:
            raise InputError(text, key, "given twice")
        try:
            opts[key] = int(value) if key in ("rooms", "objects") else float(value)
        except ValueError:
            raise InputError(text, key, f"{value!r} is not a number") from None
    if not seed.isdigit():
        raise InputError(text, "seed", f"{seed!r} is not a non-negative integer")
    options = GenOptions(kind, int(seed), **opts)
    check_options(options, text)
    return options




def cache_dir() -> Path:
    """Where named procedural worlds are written on first use."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "rosmeery-jax" / "worlds" / f"v{VERSION}"


def write_world(layout: Layout, folder: Path) -> Path:
    """Write ``layout`` to ``folder/<name>.xml`` atomically. A file already there is kept
    when it is this world, and refused (one InputError) when it differs: an edited world is
    never replaced."""
    path = Path(folder) / f"{layout.options.name}.xml"
    text = layout.xml()
    check_unchanged(path, text)
    return path if path.is_file() else write_atomic(path, text)


def check_unchanged(path: Path, text: str) -> None:
    """Refuse ``path`` if it exists and is not ``text`` (edited since it was generated, or
    another world of that name)."""
    try:
        same = not path.exists() or path.read_text(encoding="utf-8") == text
    except (OSError, UnicodeDecodeError):
        same = False
    if not same:
        raise InputError(str(path), "file", "differs from the world this generator makes under that name (edited "
                         "since?): it is never replaced; move it away, or write elsewhere")


def procedural_path(text: str) -> Path:
    """The file of procedural world ``text``, generated into :func:`cache_dir` on first use."""
    options = parse_name(text)
    return write_world(generate(options), cache_dir())  # a cached file is checked against a fresh one
