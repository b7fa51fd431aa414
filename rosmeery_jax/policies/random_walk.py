"""``random``: a random walker on the robot's own map.

A target drawn uniformly over the cells of the robot's map that the map does not show
occupied (free or still unknown; ``tries`` uniform draws over the map's extent, the first
that qualifies), with a uniform yaw; a new one whenever the navigator reports the current
one reached, stuck, unreachable or timed out. It reads nothing of the world beyond the
map's frame and size: an unknown cell may lie behind a wall, and the navigator then gives
up on it and the walker draws again.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from rosmeery_jax.policies.base import Policy, needs_target
from rosmeery_jax.sim import occupancy


class RandomPolicy(Policy):
    name = "random"

    def __init__(self, env, tries: int = 16):
        super().__init__(env)
        self.tries = tries

    def init(self, key):
        return jnp.zeros(3, jnp.float32)  # the current target

    def decide(self, state, target, key):
        k_cell, k_yaw = jax.random.split(key)
        geo = self.env.grid
        u = jax.random.uniform(k_cell, (self.tries, 2))
        i = jnp.floor(u[:, 0] * geo.extent[0]).astype(jnp.int32)
        j = jnp.floor(u[:, 1] * geo.extent[1]).astype(jnp.int32)
        ok = self.env.occupancy(state)[i, j] != occupancy.OCCUPIED
        pick = jnp.argmax(ok)  # the first that qualifies (the first draw if none does)
        xy = geo.center(i[pick], j[pick])
        fresh = jnp.concatenate([xy, jax.random.uniform(k_yaw, (1,), minval=-jnp.pi, maxval=jnp.pi)])
        target = jnp.where(needs_target(state), fresh, target)
        return target, target
