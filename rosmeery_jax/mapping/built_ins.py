"""The built-in mappers by entry name, beside the plugins a session names."""

from __future__ import annotations

from rosmeery_jax.mapping.fused import FusedMapper
from rosmeery_jax.mapping.perceived import PerceivedMapper
from rosmeery_jax.mapping.protocol import mapper_class

MAPPERS = {"perceived": PerceivedMapper, "fused": FusedMapper}


def mapper_for(spec: str) -> type:
    """A session's mapper entry's class: a built-in mapper or a plugin."""
    return MAPPERS[spec] if built_in(spec) else mapper_class(spec)


def built_in(spec: str) -> bool:
    """Whether a session's mapper entry is a built-in mapper, not a plugin (a subclass of
    one included). A session trusts it: its maps are well formed and never changed once
    handed out, so they are taken as they are (a plugin's are checked and copied:
    :func:`~rosmeery_jax.mapping.protocol.check_map`), and the envs' mappers run in parallel
    threads (a plugin's may share state: they run one after another)."""
    return spec in MAPPERS
