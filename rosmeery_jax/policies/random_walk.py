"""``random``: the paper's random walker.

A uniformly random reachable target pose (position uniform over the world's reachable free
space, the ground-truth map the benchmark knows; yaw uniform), a new one whenever the
navigator reports the current one reached, stuck, unreachable or timed out.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from rosmeery_jax.policies.base import Policy, needs_target


class RandomPolicy(Policy):
    name = "random"

    def init(self, key):
        return jnp.zeros(3, jnp.float32)  # the current target

    def decide(self, state, target, key):
        k1, k2, k3 = jax.random.split(key, 3)
        world = self.env.data
        xy = world.reachable[jax.random.randint(k1, (), 0, world.n_reachable)]
        xy = xy + jax.random.uniform(k2, (2,), minval=-0.5, maxval=0.5) * self.env.grid.resolution
        fresh = jnp.concatenate([xy, jax.random.uniform(k3, (1,), minval=-jnp.pi, maxval=jnp.pi)])
        target = jnp.where(needs_target(state), fresh, target)
        return target, target
