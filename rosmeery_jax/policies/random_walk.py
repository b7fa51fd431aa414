"""``random``: a random walker on the robot's own map.

A target drawn uniformly over the cells the robot can reach on its own map (the navigator's
planning cells, free or still unknown, connected to the robot's through cells the map does
not show blocked; ``Navigator.reachable``), with a uniform yaw; a new one whenever the
navigator reports the current one reached, stuck, unreachable or timed out. It reads
nothing of the world beyond its own map: an unknown cell may still turn out to lie behind a
wall the robot has not seen, and the navigator then gives up on it once the map shows it
enclosed.
"""

from __future__ import annotations

import jax.numpy as jnp

from rosmeery_jax.policies.base import Policy, needs_target
from rosmeery_jax.sim import occupancy


class RandomPolicy(Policy):
    name = "random"

    def init(self, key):
        return jnp.zeros(3, jnp.float32)  # the current target

    def decide(self, state, target, key):
        occupied = self.env.occupancy(state) == occupancy.OCCUPIED
        fresh = self.env.navigator.draw_reachable(state.nav, state.pose, occupied, key, 1)[0]
        target = jnp.where(needs_target(state), fresh, target)
        return target, target
