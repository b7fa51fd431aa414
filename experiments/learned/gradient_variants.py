"""Variants of ``gradient_nbv`` that test what limits it (docs/learned.md): no gradient step,
more steps, more starts, and the ground truth as its belief. Run as plugins by
``gradient_variants.toml``; none is a policy to explore with (``grad_oracle`` reads the
ground truth)."""

import jax
import jax.numpy as jnp

from rosmeery_jax.policies.gradient_nbv import GradientNBVPolicy
from rosmeery_jax.sim.coverage import FAR


class GradIt0(GradientNBVPolicy):
    """The starts scored as they are: no Adam step."""
    name = "grad_it0"

    def __init__(self, env):
        super().__init__(env, iterations=0)


class GradIt48(GradientNBVPolicy):
    """Four times the Adam steps (48)."""
    name = "grad_it48"

    def __init__(self, env):
        super().__init__(env, iterations=48)


class GradC32(GradientNBVPolicy):
    """Four times the starts (32)."""
    name = "grad_c32"

    def __init__(self, env):
        super().__init__(env, candidates=32)


class GradOracle(GradientNBVPolicy):
    """An upper bound on the belief: a belief point in every coarse cell holding a ground-truth
    surface sample the camera has not observed, in place of the robot's guess from the
    surface it labelled."""
    name = "grad_oracle"

    def belief(self, state):
        table = self.env.sk.table
        unseen = (state.knowledge.seen <= 0.5) & (table.points[0] < FAR / 2)  # padding samples stand at FAR
        i, j = self.coarse.cell(jnp.stack([table.points[0], table.points[1]], -1))
        hc, wc = self.shape
        count = jax.ops.segment_sum(unseen.astype(jnp.float32), i * wc + j, hc * wc)
        return self.belief_points(), ((count > 0) & self.coarse.inside().reshape(-1)).astype(jnp.float32)
