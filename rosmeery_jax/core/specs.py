"""The grammar of the entries a user writes for worlds, policies, metrics and mappers: one
parser, so every layer reads an entry the same way.

    NAME                            a built-in (a plain name)
    FILE.py:Name, package.module:Name   a plugin (:mod:`.plugins` loads it)
    procedural:KIND:SEED[-SEED]     generated worlds
    replay:FILE[+FILE...]           recorded teleop drives (files or glob patterns)
    learned:FILE                    a trained explorer's policy file
    agent:FILE.py:Name              a Python agent, driving through Gymnasium
    anything else                   a path (an MJCF world file)
"""

from __future__ import annotations

import re
from typing import NamedTuple

from rosmeery_jax.core.errors import InputError

PROCEDURAL, REPLAY, LEARNED, AGENT = "procedural:", "replay:", "learned:", "agent:"
PROCEDURAL_NAME = re.compile(rf"^{PROCEDURAL}([a-z]+):([^:]*)(?::(.*))?$")  # KIND:SEED[:OPTIONS]
MAX_WORLDS = 10_000  # worlds one command may name (a world bank of 10,000 small worlds fits in memory)
PLUGIN = re.compile(r"(?P<module>[^:]+\.py|[A-Za-z_][\w.]*):(?P<name>[A-Za-z_]\w*)")
NAME = re.compile(r"[A-Za-z_][\w-]*")
LABEL = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}")  # a results label: see label_name
LABEL_RULE = "letters, digits, _ . and -, at most 64 characters, starting with a letter, digit or _"
MAX_SEED = 2**31 - 1  # seeds are int32 keys, in sessions, recordings and the Gymnasium envs
KINDS = ("name", "plugin", "procedural", "replay", "learned", "agent", "path")


class Spec(NamedTuple):
    """One entry: its ``kind`` (one of :data:`KINDS`), the ``text`` as written and its
    ``body`` (the text after the prefix; the whole text for names, plugins and paths)."""

    kind: str
    text: str
    body: str


def parse(entry: str) -> Spec:
    """The kind of ``entry``; prefixes first, so ``learned:x`` is never a plugin."""
    for kind, prefix in (("procedural", PROCEDURAL), ("replay", REPLAY), ("learned", LEARNED), ("agent", AGENT)):
        if entry.startswith(prefix):
            return Spec(kind, entry, entry[len(prefix):])
    if PLUGIN.fullmatch(entry):
        return Spec("plugin", entry, entry)
    return Spec("name" if NAME.fullmatch(entry) else "path", entry, entry)


def kind(entry: str) -> str:
    return parse(entry).kind


def is_plugin(entry: str) -> bool:
    """Whether ``entry`` names a plugin (``FILE.py:Name`` or ``package.module:Name``)."""
    return kind(entry) == "plugin"


def regroup(tokens) -> tuple[str, ...]:
    """Entries from a list whose ``replay:`` files were split by commas
    (``replay:a.jsonl,b.jsonl,random``): a token that is a path joins the replay entry before
    it, as ``+FILE``."""
    out: list[str] = []
    for tok in tokens:
        if out and kind(out[-1]) == "replay" and kind(tok) == "path":
            out[-1] += "+" + tok
        else:
            out.append(tok)
    return tuple(out)


def plain_name(name: str) -> bool:
    """Whether ``name`` can be one file name's part in this folder: no separator, no leading
    dot (``..``), no control character; not an empty cell (NaN)."""
    return isinstance(name, str) and bool(name) and not name.startswith(".") and not any(c in name for c in "/\\") and \
        all(c.isprintable() for c in name)


def expand_ranges(names) -> tuple[str, ...]:
    """World names with seed ranges expanded: ``procedural:office:0-99`` is 100 worlds."""
    out = []
    for name in names:
        m = PROCEDURAL_NAME.match(name)
        rng = re.fullmatch(r"(\d+)-(\d+)", m.group(2)) if m else None
        if rng is None:
            out.append(name)
            continue
        lo, hi = int(rng.group(1)), int(rng.group(2))
        if hi < lo:
            raise InputError(name, "seed", f"empty range {lo}-{hi}")
        if hi - lo + 1 + len(out) > MAX_WORLDS:  # refused by its size, before any is expanded
            raise InputError(name, "seed", f"{lo}-{hi} is {hi - lo + 1:,} worlds: at most {MAX_WORLDS:,} in all")
        tail = f":{m.group(3)}" if m.group(3) else ""
        out += [f"{PROCEDURAL}{m.group(1)}:{s}{tail}" for s in range(lo, hi + 1)]
    return tuple(out)


def label_name(name) -> bool:
    """Whether ``name`` can label a plugin's results (a policy's, metric's, mapper's or
    agent's): :data:`LABEL_RULE`. Labels become parts of file names and plot titles."""
    return isinstance(name, str) and LABEL.fullmatch(name) is not None
