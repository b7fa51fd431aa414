"""Variants of ``gradient_nbv`` that test what limits it (docs/learned.md): no gradient step,
more steps, more starts, more candidates of random's kind, and the ground truth as its
belief, as its view model, or both. Run as plugins by ``gradient_variants.toml``; none is a
policy to explore with (those named for the ground truth or a true view read it)."""

from pathlib import Path

import jax
import jax.numpy as jnp

from rosmeery_jax.core.plugins import load
from rosmeery_jax.policies.gradient_nbv import GradientNBVPolicy
from rosmeery_jax.sim import occupancy
from rosmeery_jax.sim.coverage import FAR

# the ground truth's gain of a view, from the view_oracle measure beside this file
ViewOracle = load(f"{Path(__file__).with_name('view_oracle.py')}:ViewOracle", __file__, "ViewOracle")


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


class GradTrueView(GradientNBVPolicy):
    """An upper bound on the view model: its starts (no Adam step: the true view has no
    gradient) scored by what the camera would really newly observe from each, the ground
    truth's samples (``view_oracle``'s gain), in place of the belief points' expected
    coverage through the rendered map. Its belief, choice and fallback are the shipped ones."""
    name = "grad_true_view"

    def __init__(self, env):
        super().__init__(env, iterations=0)

    def refine(self, opacity, table, weight, state, starts):
        return starts, jax.vmap(lambda q: ViewOracle.gain(self, state, q))(starts)


class GradOracleTrueView(GradTrueView, GradOracle):
    """Both bounds at once: the ground truth's belief places the starts, and the ground truth's
    view scores them."""
    name = "grad_oracle_true_view"


class GradDraws(GradientNBVPolicy):
    """More candidates of another kind: beside its refined views, ``draws`` of random's draws
    (reachable cells, uniform yaw), scored by its own view model, not refined."""
    name = "grad_draws"
    draws = 24

    def views(self, state, opacity, table, weight, key):
        views, gains = super().views(state, opacity, table, weight, key)
        occupied = self.env.occupancy(state) == occupancy.OCCUPIED
        drawn = self.env.navigator.draw_reachable(state.nav, state.pose, occupied, jax.random.fold_in(key, 1),
                                                  self.draws)
        return jnp.concatenate([views, drawn]), jnp.concatenate([gains, self.score(state, opacity, table, weight, drawn)])

    def score(self, state, opacity, table, weight, views):
        return jax.vmap(lambda q: self.gain(opacity, table, weight, q))(views)


class GradDrawsTrueView(GradDraws, GradTrueView):
    """The same candidates, every one scored by the ground truth's view."""
    name = "grad_draws_true_view"

    def score(self, state, opacity, table, weight, views):
        return jax.vmap(lambda q: ViewOracle.gain(self, state, q))(views)


class GradDrawsOracle(GradDraws, GradOracle):
    """The same candidates scored by its own view model, with the ground truth as its belief."""
    name = "grad_draws_oracle"
