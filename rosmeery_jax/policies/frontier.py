"""``frontier``: frontier-based exploration on the robot's own occupancy map.

Frontier cells are known-free cells next to unknown ones, on a coarse grid
(``resolution``, default 0.2 m: a coarse cell is free when it holds a free fine cell and no
occupied one, unknown when it holds neither). Frontiers are the 8-connected groups of
frontier cells (label propagation, a ``lax.while_loop``), groups smaller than ``min_size``
cells are ignored, and the robot goes to:

- ``biggest`` (the paper's definition): the largest frontier, at its cell nearest to the
  frontier's centroid;
- ``nearest``: the frontier cell nearest to the robot (straight-line distance).

A target faces the unknown cells next to its frontier cell, so reaching it looks into the
unknown (the cell under the robot is often a frontier cell, with unknown space behind it:
the target then turns the robot round).

It keeps its target while the target is still a frontier cell and the navigator is moving,
remembers targets the navigator gave up on (stuck, unreachable, timeout) or reached while
they stayed frontier (nothing more can be seen from there), and avoids frontier cells
within ``blacklist_radius`` of them. When no frontier is left it stops where it is.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from rosmeery_jax.core import grid
from rosmeery_jax.policies.base import Policy, needs_target
from rosmeery_jax.sim import occupancy as occ_map
from rosmeery_jax.sim.navigation import REACHED, STUCK, TIMEOUT, UNREACHABLE


class FrontierState(NamedTuple):
    target: jax.Array  # (3,)
    failed: jax.Array  # (K, 2) targets given up on (far away when unused)
    nfailed: jax.Array  # int32, ring-buffer write count
    done: jax.Array  # bool: no frontier left


class FrontierPolicy(Policy):
    def __init__(self, env, choose: str = "biggest", resolution: float = 0.2, min_size: int = 3,
                 blacklist: int = 16, blacklist_radius: float = 0.6):
        super().__init__(env)
        self.name = "frontier" if choose == "biggest" else f"frontier_{choose}"
        self.choose = choose
        self.f = max(1, int(round(resolution / env.grid.resolution)))
        self.shape = env.grid.coarse(self.f).shape
        self.min_size, self.k, self.radius = min_size, blacklist, blacklist_radius

    @property
    def coarse(self):
        """The coarse grid of the env's world (read when deciding: the world is data)."""
        return self.env.grid.coarse(self.f)

    def init(self, key):
        return FrontierState(jnp.zeros(3, jnp.float32), jnp.full((self.k, 2), 1e6, jnp.float32),
                             jnp.int32(0), jnp.bool_(False))

    def frontier_cells(self, occupancy: jax.Array) -> jax.Array:
        """(Hc, Wc) bool frontier cells from the robot's (H, W) UNKNOWN/FREE/OCCUPIED map."""
        return self._frontier(occupancy)[0]

    def _frontier(self, occupancy: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Frontier cells (Hc, Wc) bool and, per cell, the heading (Hc, Wc) towards its
        unknown 4-neighbours (their mean direction). Cells beyond the world's extent (session
        padding) are neither free nor unknown, like cells off the grid."""
        any_occ = grid.block_any(occupancy == occ_map.OCCUPIED, self.f)
        any_free = grid.block_any(occupancy == occ_map.FREE, self.f)
        free = any_free & ~any_occ
        unknown = ~any_free & ~any_occ & self.coarse.inside()
        p = jnp.pad(unknown, 1)
        down, up, left, right = p[:-2, 1:-1], p[2:, 1:-1], p[1:-1, :-2], p[1:-1, 2:]  # rows grow with y
        near_unknown = down | up | left | right
        toward = jnp.arctan2(up.astype(jnp.float32) - down, right.astype(jnp.float32) - left)
        return free & near_unknown, toward

    def components(self, frontier: jax.Array) -> jax.Array:
        """(Hc, Wc) int32 component label (0 = not frontier) by max-label propagation."""
        hc, wc = self.shape
        start = jnp.where(frontier, jnp.arange(1, hc * wc + 1, dtype=jnp.int32).reshape(hc, wc), 0)

        def spread(lab):
            p = jnp.pad(lab, 1)
            rows = jnp.maximum(jnp.maximum(p[:-2], p[1:-1]), p[2:])
            m = jnp.maximum(jnp.maximum(rows[:, :-2], rows[:, 1:-1]), rows[:, 2:])
            return jnp.where(frontier, m, 0)

        def cond(c):
            return c[1]

        def body(c):
            new = spread(c[0])
            return new, jnp.any(new != c[0])

        return jax.lax.while_loop(cond, body, (start, jnp.bool_(True)))[0]

    def decide(self, state, ps: FrontierState, key):
        hc, wc = self.shape
        n = hc * wc + 1
        coarse = self.coarse
        centers = coarse.centers()
        frontier, toward = self._frontier(self.env.occupancy(state))
        # Cells near targets the navigator gave up on are not candidates.
        d_fail = jnp.linalg.norm(centers[:, :, None, :] - ps.failed[None, None], axis=-1).min(-1)
        frontier = frontier & (d_fail > self.radius)
        labels = self.components(frontier)
        flat = labels.ravel()
        size = jax.ops.segment_sum(jnp.ones_like(flat), flat, n).at[0].set(0)
        valid = frontier & (size[labels] >= self.min_size)
        xy = centers.reshape(-1, 2)
        pose = state.pose
        if self.choose == "biggest":
            best = jnp.argmax(size)
            cx = jax.ops.segment_sum(xy, flat, n)[best] / jnp.maximum(size[best], 1)
            score = jnp.where(valid.ravel() & (flat == best), jnp.linalg.norm(xy - cx, axis=-1), jnp.inf)
        else:
            score = jnp.where(valid.ravel(), jnp.linalg.norm(xy - pose[:2], axis=-1), jnp.inf)
        cell = jnp.argmin(score)
        any_left = jnp.isfinite(score[cell])
        goal = xy[cell]
        heading = toward.ravel()[cell]
        fresh = jnp.where(any_left, jnp.concatenate([goal, heading[None]]), pose)

        status = state.nav.status
        still_frontier = valid[coarse.cell(ps.target[:2])]
        gave_up = (status == STUCK) | (status == UNREACHABLE) | (status == TIMEOUT) | (
            (status == REACHED) & still_frontier)
        failed = jnp.where(gave_up, ps.failed.at[ps.nfailed % self.k].set(ps.target[:2]), ps.failed)
        nfailed = ps.nfailed + gave_up.astype(jnp.int32)
        renew = needs_target(state) | ~still_frontier
        target = jnp.where(renew, fresh, ps.target)
        return target, FrontierState(target, failed, nfailed, ~any_left)


class ViewPolicy(Policy):
    """A policy that plans views of its own and, with none worth taking, explores like
    ``frontier`` (the biggest frontier): the fallback the two NBV policies share. Its state
    has ``target``, ``frontier`` (a :class:`FrontierState`) and ``exploring``."""

    def __init__(self, env):
        super().__init__(env)
        self.frontier = FrontierPolicy(env, choose="biggest")

    def bind(self, env) -> "ViewPolicy":
        policy = super().bind(env)
        policy.frontier = self.frontier.bind(env)
        return policy

    def choose(self, state, ps, key, have_view: jax.Array, view: jax.Array):
        """The next target (3,): a view is driven to until the navigator is done with it; at a
        renewal the planned ``view`` if ``have_view``, else the frontier's target. Returns
        (target, frontier state, exploring, renew)."""
        f_target, f_state = self.frontier.decide(state, ps.frontier._replace(target=ps.target), key)
        renew = needs_target(state) | ps.exploring
        target = jnp.where(renew, jnp.where(have_view, view, f_target), ps.target)
        exploring = jnp.where(renew, ~have_view, ps.exploring)
        return target, f_state, exploring, renew


def blocked_within(occupied: jax.Array, cells: int) -> jax.Array:
    """(H, W) bool: occupied cells grown by ``cells`` (4-neighbourhood), where a view would
    stand too close to an obstacle."""
    for _ in range(cells):
        occupied = grid.grow(occupied, diagonal=False)
    return occupied
