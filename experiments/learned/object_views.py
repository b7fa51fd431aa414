"""``learned_views`` (docs/learned.md, tried and not shipped): the shipped learned policy,
offered in sessions ``views`` more candidates beside its draws: views drawn among
semantic_nbv's (on a ring around each labelled object's observed centroid, facing it, on a
free cell), described by the same features, so the network scores them as any candidate."""

import jax
import jax.numpy as jnp

from rosmeery_jax.policies.learned import LearnedPolicy
from rosmeery_jax.policies.semantic_nbv import SemanticNBVPolicy, facing
from rosmeery_jax.rl.candidates import Offer, describe
from rosmeery_jax.core import grid


class LearnedViews(LearnedPolicy):
    name = "learned_views"
    views = 8

    def __init__(self, env):
        super().__init__(env)
        self.name = "learned_views"
        self.nbv = SemanticNBVPolicy(env)

    def object_views(self, state, key) -> tuple[jax.Array, jax.Array]:
        """(views, 3) poses facing labelled objects, drawn among the free ones, and (views,) which are free."""
        k = self.env.labelled_knowledge(state)
        centroid, _, count = self.nbv._objects(k.seen)  # (N, 2), (N,)
        ring, free = self.nbv.ring_views(state, centroid, (k.label >= 0) & (count > 0))  # (N, V, 2), (N, V)
        face = facing(centroid[:, None], ring).reshape(-1)
        ring, free = ring.reshape(-1, 2), free.reshape(-1)
        pick = grid.draw(key, jnp.where(free, 1.0, 0.0) + 1e-12, self.views)  # uniform over the free ones
        return jnp.concatenate([ring[pick], face[pick, None]], -1), free[pick]

    def candidates(self, state, ps, key):
        """The shipped offer, with ``views`` object views appended."""
        k_draw, k_view = jax.random.split(key)
        base = super().candidates(state, ps, k_draw)
        views, free = self.object_views(state, k_view)
        feats = describe(self.env, state, views, free, jnp.zeros(self.views, bool), self.rl.radius)
        return Offer(jnp.concatenate([base.targets, views]), jnp.concatenate([base.features, feats]), base.globals)
