"""The policy interface (one env; vmap over seeds)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import jax
import jax.numpy as jnp

from rosmeery_jax.navigation import REACHED, STUCK, TIMEOUT, UNREACHABLE, IDLE


class Policy(ABC):
    """Subclasses set ``name`` and implement ``decide`` (and ``init`` when they keep state)."""

    name = "policy"

    def __init__(self, env):
        self.env = env

    def init(self, key: jax.Array) -> Any:
        return jnp.zeros(())

    @abstractmethod
    def decide(self, state, pstate, key: jax.Array) -> tuple[jax.Array, Any]:
        """One env: (target pose (3,), new pstate)."""


def needs_target(state) -> jax.Array:
    """True when the navigator is done with its target (reached, failed or none yet)."""
    s = state.nav.status
    return (s == IDLE) | (s == REACHED) | (s == STUCK) | (s == UNREACHABLE) | (s == TIMEOUT)
