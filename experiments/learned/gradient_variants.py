"""Variants of ``gradient_nbv`` that test what limits it (docs/learned.md): no gradient step,
more steps, more starts, more candidates of random's kind, and the ground truth as its
belief, as its view model, or both (``gradient_variants.toml``); the ground truth's belief
weighed by ORI or as its samples, and its own belief widened to occupied cells
(``gradient_beliefs.toml``). Run as plugins; none is a policy to explore with (those named
for the ground truth or a true view read it; the widened belief did not hold its lead)."""

from pathlib import Path

import jax
import jax.numpy as jnp

from rosmeery_jax.core.plugins import load
from rosmeery_jax.policies.gradient_nbv import GradientNBVPolicy
from rosmeery_jax.rl.candidates import surface_maps
from rosmeery_jax.sim import occupancy
from rosmeery_jax.core import grid
from rosmeery_jax.sim.coverage import FAR

# the ground truth's gain of a view, from the view_oracle measure beside this file
ViewOracle = load(f"{Path(__file__).with_name('view_oracle.py')}:ViewOracle", __file__, "ViewOracle")
ori_weights = load(f"{Path(__file__).with_name('view_oracle.py')}:ori_weights", __file__, "ori_weights")
newly_observed = load(f"{Path(__file__).with_name('view_oracle.py')}:newly_observed", __file__, "newly_observed")


def true_view(policy, state, views):
    """(M,) the ground-truth samples the camera would newly observe from each of ``views``
    (M, 3): ``view_oracle``'s gain."""
    return jax.vmap(lambda q: ViewOracle.worth(policy, newly_observed(policy.env, state, q)))(views)


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


def _sample_cells(policy) -> tuple[jax.Array, int]:
    """(S,) the flat coarse cell of each ground-truth sample, and the coarse cells' count."""
    table = policy.env.sk.table
    i, j = policy.coarse.cell(jnp.stack([table.points[0], table.points[1]], -1))
    hc, wc = policy.shape
    return i * wc + j, hc * wc


class GradOracle(GradientNBVPolicy):
    """An upper bound on the belief: a belief point in every coarse cell holding a ground-truth
    surface sample the camera has not observed, in place of the robot's guess from the
    surface it labelled."""
    name = "grad_oracle"

    def belief(self, state):
        table = self.env.sk.table
        unseen = (state.knowledge.seen <= 0.5) & (table.points[0] < FAR / 2)  # padding samples stand at FAR
        count = jax.ops.segment_sum(unseen.astype(jnp.float32), *_sample_cells(self))
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
        return starts, true_view(self, state, starts)


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
        return true_view(self, state, views)


class GradDrawsOracle(GradDraws, GradOracle):
    """The same candidates scored by its own view model, with the ground truth as its belief."""
    name = "grad_draws_oracle"


def _ori_weight(env, state):
    """(S,) ``ori_weights`` of the samples the camera has not observed, else 0 (padding 0)."""
    table = env.sk.table
    return jnp.where((state.knowledge.seen <= 0.5) & (table.points[0] < FAR / 2), ori_weights(env), 0.0)


class GradOracleORI(GradientNBVPolicy):
    """The ground-truth belief of ``grad_oracle``, each coarse cell weighed by the ORI its
    unseen samples hold (times N) rather than 1: the belief as ORI counts it, still one point
    per cell at ``point_height``, still seen through the robot's rendered view."""
    name = "grad_oracle_ori"

    def belief(self, state):
        mass = jax.ops.segment_sum(_ori_weight(self.env, state), *_sample_cells(self))
        return self.belief_points(), jnp.where(self.coarse.inside().reshape(-1), mass, 0.0)

    def believed_opacity(self, held):
        return self.belief_opacity * (held > 0).reshape(self.shape)


class GradOracleSamples(GradientNBVPolicy):
    """The belief at its limit: the ground-truth samples themselves (true positions and
    heights), weighed by the ORI each would add, seen through the robot's rendered view (a
    depth per image column through its map), as against ``grad_draws_true_view``'s cast at
    the true scene."""
    name = "grad_oracle_samples"

    def init(self, key):
        s = super().init(key)
        return s._replace(viewed=jnp.zeros(self.env.sk.table.points.shape[1], jnp.float32))

    def belief(self, state):
        return self.env.sk.table, _ori_weight(self.env, state)

    def start_weights(self, weight):
        return weight + 1e-9 * (self.env.sk.table.points[0] < FAR / 2)

    def believed_opacity(self, held):
        cells = jax.ops.segment_max((held > 0).astype(jnp.float32), *_sample_cells(self))
        return self.belief_opacity * jnp.maximum(cells, 0.0).reshape(self.shape)


class GradDrawsOracleORI(GradDraws, GradOracleORI):
    """``grad_draws`` with the ORI-weighted ground-truth cells as its belief."""
    name = "grad_draws_oracle_ori"


class GradDrawsOracleSamples(GradDraws, GradOracleSamples):
    """``grad_draws`` with the ground-truth samples, ORI-weighted, as its belief."""
    name = "grad_draws_oracle_samples"


class GradOccupied(GradientNBVPolicy):
    """Its own belief widened from its own data: beside the cells near labelled surface, every
    coarse cell its map shows occupied (the laser saw something there: furniture not yet
    seen by the camera, or a wall) where it has observed no object surface. A wall's point
    is soon viewed by the camera and weighs nothing after; an object the camera has not yet
    seen is believed in before it is labelled."""
    name = "grad_occupied"

    def belief(self, state):
        table, held = super().belief(state)
        surface, _ = surface_maps(self.env, self.env.labelled_knowledge(state))
        occupied = grid.block_any(self.env.occupancy(state) == occupancy.OCCUPIED, self.f)
        extra = occupied & ~grid.block_any(surface > 0, self.f) & self.coarse.inside()
        return table, jnp.maximum(held, extra.reshape(-1).astype(jnp.float32))


class GradDrawsOccupied(GradDraws, GradOccupied):
    """``grad_occupied`` with random's draws beside its refined views."""
    name = "grad_draws_occupied"
