"""``learned_known`` (docs/learned.md, a measure, not shipped): the shipped learned policy,
never sent to a target whose cell its own occupancy map holds unknown while some offered
candidate's cell is known. It tests where learned's unreachable targets come from: the
navigator counts unknown cells as open, and the laser may later show them enclosed."""

import jax
import jax.numpy as jnp

from rosmeery_jax.policies.learned import LearnedPolicy
from rosmeery_jax.rl.candidates import FEATURES
from rosmeery_jax.sim import occupancy


class LearnedKnown(LearnedPolicy):
    name = "learned_known"

    def __init__(self, env):
        super().__init__(env)
        self.name = type(self).name

    def logits(self, state, on_offer) -> jax.Array:
        """The network's scores, with the offered candidates on unknown cells refused."""
        logits = super().logits(state, on_offer)
        i, j = self.env.grid.cell(on_offer.targets[:, :2])
        offered = on_offer.features[:, FEATURES.index("valid")] > 0.5
        known = (self.env.occupancy(state)[i, j] != occupancy.UNKNOWN) & offered
        return jnp.where(jnp.any(known) & ~known, -jnp.inf, logits)
