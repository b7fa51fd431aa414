"""An explorer plugin: drive to the farthest cell the robot's own map shows free and clear
of obstacles (cells next to a wall are where the navigator cannot stand).

A policy is a subclass of ``rosmeery_jax.Policy`` with a ``name`` (its label in the
results) and a pure-JAX ``decide(state, pstate, key) -> (target (3,), pstate)``; the
session vmaps it over seeds and compiles it with the built-ins. It reads only what the
robot knows (its occupancy map, its pose), never the world's ground truth.

    rosmeery run --worlds small_office --policies frontier,examples/farthest_free_policy.py:FarthestFree \\
        --detector oracle --duration 60 --out results/plugin
"""

import jax
import jax.numpy as jnp

from rosmeery_jax import Policy
from rosmeery_jax.policies.base import needs_target
from rosmeery_jax.policies.frontier import blocked_within
from rosmeery_jax.sim import occupancy


class FarthestFree(Policy):
    name = "farthest_free"

    def init(self, key):
        return jnp.zeros(3, jnp.float32)  # the target being driven to

    def decide(self, state, target, key):
        known = self.env.occupancy(state)  # (H, W) from the robot's own laser
        free = (known == occupancy.FREE) & ~blocked_within(known == occupancy.OCCUPIED, 3)
        centres = self.env.grid.centers()  # (H, W, 2)
        dist = jnp.linalg.norm(centres - state.pose[:2], axis=-1)
        noise = jax.random.uniform(key, dist.shape, maxval=0.5)  # ties broken at random
        score = jnp.where(free, dist + noise, -1.0)
        i, j = jnp.unravel_index(jnp.argmax(score), score.shape)
        xy = centres[i, j]
        new = jnp.concatenate([xy, jnp.arctan2(xy[1] - state.pose[1], xy[0] - state.pose[0])[None]])
        target = jnp.where(needs_target(state), new, target)  # keep driving until the navigator is done
        return target, target
