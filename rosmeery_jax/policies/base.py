"""The policy interface (one env; vmap over seeds)."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from rosmeery_jax.navigation import REACHED, STUCK, TIMEOUT, UNREACHABLE, IDLE


class Policy:
    """Subclasses set ``name`` and implement ``init`` and ``decide``."""

    name = "policy"

    def __init__(self, env):
        self.env = env

    def init(self, key: jax.Array) -> Any:
        return jnp.zeros(())

    def decide(self, state, pstate, key: jax.Array) -> tuple[jax.Array, Any]:
        raise NotImplementedError


def needs_target(state) -> jax.Array:
    """True when the navigator is done with its target (reached, failed or none yet)."""
    s = state.nav.status
    return (s == IDLE) | (s == REACHED) | (s == STUCK) | (s == UNREACHABLE) | (s == TIMEOUT)
