"""``semantic_nbv``: a semantic next-best-view baseline (after the original S-Ave node).

What it knows is only what the robot has perceived: the objects it holds a label for, the
surface points of them its camera has observed (their centroid and extent), the directions
it has already seen each object from, and its own occupancy map. Nothing from the ground
truth beyond that.

Every decision it scores candidate views: ``views`` poses on a circle of ``radius`` around
each labelled object's observed centroid, facing it. A view's expected newly seen surface
is the object's observed footprint area (a stand-in for its size) when the robot has not
yet seen the object from that direction (one of ``views`` bearing sectors), else nothing.
Score = expected new surface / (travel distance + 1 m). Candidates must lie on cells the
robot's own map shows free, away from obstacles. With no worthwhile candidate it explores
like ``frontier`` (biggest frontier) to find more objects.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.policies.base import needs_target
from rosmeery_jax.policies.frontier import FrontierState, ViewPolicy, blocked_within
from rosmeery_jax.sim import occupancy


class NBVState(NamedTuple):
    target: jax.Array  # (3,)
    seen_from: jax.Array  # (N, V) bool: sectors the robot has seen each object from
    last_ps: jax.Array  # (N,) observed samples at the previous decision
    frontier: FrontierState
    exploring: jax.Array  # bool: the current target came from the frontier fallback
    view: jax.Array  # (2,) int32 (object, sector) of the current view target


class SemanticNBVPolicy(ViewPolicy):
    name = "semantic_nbv"

    def __init__(self, env, views: int = 8, radius: float = 1.0, clearance: float = 0.3):
        super().__init__(env)
        self.v, self.radius = views, radius
        self.n = env.sk.table.num_objects
        ang = np.arange(views) * 2 * np.pi / views
        self.ring = jnp.asarray(np.stack([np.cos(ang), np.sin(ang)], -1) * radius, jnp.float32)  # (V, 2)
        self.grow = max(1, int(round(clearance / env.grid.resolution)))

    def init(self, key):
        return NBVState(jnp.zeros(3, jnp.float32), jnp.zeros((self.n, self.v), bool), jnp.zeros(self.n, jnp.float32),
                        self.frontier.init(key), jnp.bool_(True), jnp.zeros(2, jnp.int32))

    def _objects(self, seen):
        """Observed centroid (N, 2), footprint area (N,) and count (N,) from observed samples."""
        w = (seen > 0.5).astype(jnp.float32)
        table = self.env.sk.table
        pts, obj = table.points, table.object  # (3, S), (S,)
        count = jax.ops.segment_sum(w, obj, self.n, indices_are_sorted=True)
        sx = jax.ops.segment_sum(w * pts[0], obj, self.n, indices_are_sorted=True)
        sy = jax.ops.segment_sum(w * pts[1], obj, self.n, indices_are_sorted=True)
        big = 1e6
        lo_x = jax.ops.segment_min(jnp.where(w > 0, pts[0], big), obj, self.n, indices_are_sorted=True)
        hi_x = jax.ops.segment_max(jnp.where(w > 0, pts[0], -big), obj, self.n, indices_are_sorted=True)
        lo_y = jax.ops.segment_min(jnp.where(w > 0, pts[1], big), obj, self.n, indices_are_sorted=True)
        hi_y = jax.ops.segment_max(jnp.where(w > 0, pts[1], -big), obj, self.n, indices_are_sorted=True)
        c = jnp.stack([sx, sy], -1) / jnp.maximum(count, 1.0)[:, None]
        area = jnp.where(count > 0, jnp.maximum(hi_x - lo_x, 0.1) * jnp.maximum(hi_y - lo_y, 0.1), 0.0)
        return c, area, count

    def ring_views(self, state, centroid: jax.Array, objects: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The candidate views' positions (N, V, 2), on the ring around each object's centroid
        (N, 2), and (N, V) which of them stand on a cell the robot's map shows free, away from
        obstacles, around one of the ``objects`` (N,) bool. A view faces its object (:func:`facing`)."""
        cand = centroid[:, None, :] + self.ring[None]
        occ = self.env.occupancy(state)
        blocked = blocked_within(occ == occupancy.OCCUPIED, self.grow)
        i, j = self.env.grid.cell(cand)
        return cand, (occ[i, j] == occupancy.FREE) & ~blocked[i, j] & objects[:, None]

    def decide(self, state, ps: NBVState, key):
        env = self.env
        k = env.labelled_knowledge(state)
        centroid, area, count = self._objects(k.seen)
        labelled = k.label >= 0
        # Sectors seen from: objects observed more since the last decision, from the robot's bearing.
        now = count > ps.last_ps
        rel = state.pose[:2] - centroid
        sector = (jnp.floor((jnp.arctan2(rel[:, 1], rel[:, 0]) % (2 * jnp.pi)) / (2 * jnp.pi / self.v))).astype(jnp.int32)
        seen_from = ps.seen_from | (now[:, None] & (jnp.arange(self.v)[None] == jnp.clip(sector, 0, self.v - 1)[:, None]))
        # A view the navigator is done with (reached or given up on) is not chosen again.
        done_view = needs_target(state) & ~ps.exploring
        seen_from = seen_from.at[ps.view[0], ps.view[1]].set(seen_from[ps.view[0], ps.view[1]] | done_view)

        cand, free = self.ring_views(state, centroid, labelled)
        ok = free & ~seen_from
        dist = jnp.linalg.norm(cand - state.pose[:2], axis=-1)
        score = jnp.where(ok, area[:, None] / (dist + 1.0), -1.0)
        best = jnp.argmax(score.ravel())
        n_best, v_best = best // self.v, best % self.v
        goal = cand[n_best, v_best]
        have_view = score.ravel()[best] > 0

        target, f_state, exploring, renew = self.choose(state, ps, key, have_view,
                                                        jnp.concatenate([goal, facing(centroid[n_best], goal)[None]]))
        view = jnp.where(renew & have_view, jnp.stack([n_best, v_best]).astype(jnp.int32), ps.view)
        return target, NBVState(target, seen_from, count, f_state, exploring, view)


def facing(centroid: jax.Array, at: jax.Array) -> jax.Array:
    """(...) the yaw from positions ``at`` (..., 2) towards ``centroid`` (..., 2) (broadcast)."""
    return jnp.arctan2(centroid[..., 1] - at[..., 1], centroid[..., 0] - at[..., 0])
