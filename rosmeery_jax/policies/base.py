"""The policy interface (one env; the session vmaps it over the batch)."""

from __future__ import annotations

import copy
from abc import ABC, abstractmethod
from typing import Any

import jax
import jax.numpy as jnp

from rosmeery_jax.sim import navigation


class Policy(ABC):
    """Subclasses set ``name`` and implement ``decide`` (and ``init`` when they keep state).

    Class attributes a policy may change:
    - ``per_step``: ``decide`` returns one action per control step (steps, A) instead of
      one target held until the next decision;
    - ``env_overrides(spec, world)``: env settings the policy needs (e.g. velocity commands).
    """

    name = "policy"
    per_step = False

    def __init__(self, env):
        self.env = env

    def bind(self, env) -> "Policy":
        """This policy acting in ``env`` (an env of the same config and padded sizes, e.g.
        ``env.with_data(world)`` inside a jitted function). Policies read the world only
        through ``self.env`` when deciding, so one compiled function serves every world."""
        policy = copy.copy(self)
        policy.env = env
        return policy

    @classmethod
    def env_overrides(cls, spec: str, world: str) -> dict:
        """RobotEnv settings the policy entry ``spec`` needs in the world named ``world``."""
        return {}

    def seeds(self, session: range) -> range:
        """The seeds the policy runs, one batch entry each: the session's by default."""
        return session

    def init(self, key: jax.Array) -> Any:
        return jnp.zeros(())

    def init_batch(self, keys: jax.Array) -> Any:
        """The batched policy state for keys (B,)."""
        return jax.vmap(self.init)(keys)

    def task_goals(self, semantic_map, start, goal: str, attempts: int):
        """Executed tasks (``task = "objectnav"``, docs/tasks.md), on the host: the poses (k,
        3), k <= ``attempts``, that a robot exploring with this policy drives to in turn to
        find an object of category ``goal`` from ``start`` (3,) with its final map
        ``semantic_map`` (a ``MapState``: points, instance, label, confidence); it stops at
        the first in a success region. None (the default): the built-in search."""
        return None

    def check_start(self, poses) -> None:
        """Raise InputError when the reset poses (B, 3) do not suit the policy."""

    @abstractmethod
    def decide(self, state, pstate, key: jax.Array) -> tuple[jax.Array, Any]:
        """One env: (target pose (3,), new pstate)."""


def needs_target(state) -> jax.Array:
    """True when the navigator is done with its target (reached, failed or none yet)."""
    return navigation.needs_target(state.nav)
