"""Drive to a target pose on the robot's own map: a wavefront planner and a local controller.

Planner: a cost-to-go field on a coarse grid (``plan_resolution``) over the robot's own
occupancy map, where unknown counts as traversable, occupied cells grown by one coarse cell
are blocked and cells next to them cost more. The field is refined by a few Bellman sweeps
every control step (``sweeps``) instead of being solved from scratch: the wave outruns the
robot, costs rise again where new obstacles appear, and every env does the same fixed work,
so the whole thing vmaps with no data-dependent loop.

Controller: head for the lowest cost-to-go on a ring around the robot, slow down for sharp
turns, and at the target position turn to the target yaw.

Status, reported in the state so policies can react: MOVING, REACHED, STUCK (no progress
for ``stuck_time``), UNREACHABLE (target blocked, or no path once the wave had time to
arrive), TIMEOUT (``timeout`` seconds without reaching). IDLE before any target.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.sim import grid
from rosmeery_jax.sim.occupancy import GridGeometry

IDLE, MOVING, REACHED, STUCK, UNREACHABLE, TIMEOUT = range(6)
STATUS_NAMES = ("idle", "moving", "reached", "stuck", "unreachable", "timeout")
BIG = 1e6


@dataclass(frozen=True)
class NavConfig:
    plan_resolution: float = 0.1
    sweeps: int = 3
    lookahead: float = 0.3
    goal_tolerance: float = 0.15
    yaw_tolerance: float = 0.15
    near_cost: float = 4.0
    k_turn: float = 2.5
    stuck_time: float = 4.0
    stuck_progress: float = 0.15
    timeout: float = 60.0


class NavState(NamedTuple):
    """Per env. target (3,); field (Hc, Wc) cost-to-go in coarse cells; status int32;
    elapsed / since_progress int32 control steps; best float32 best cost-to-go so far."""

    target: jax.Array
    field: jax.Array
    status: jax.Array
    elapsed: jax.Array
    since_progress: jax.Array
    best: jax.Array


class Navigator:
    """Pure functions over :class:`NavState`; vmap over envs."""

    def __init__(self, geo: GridGeometry, cfg: NavConfig, control_dt: float, max_speed: float, max_turn: float):
        self.geo, self.cfg = geo, cfg
        self.factor = max(1, int(round(cfg.plan_resolution / geo.resolution)))
        self.coarse = geo.coarse(self.factor)
        self.coarse_shape = self.coarse.shape
        self.dt, self.vmax, self.wmax = control_dt, max_speed, max_turn
        self.stuck_steps = int(round(cfg.stuck_time / control_dt))
        self.timeout_steps = int(round(cfg.timeout / control_dt))
        # Steps for the wave to cross the world's grid: only then is "no path" believed.
        self.settle_steps = -(-jnp.sum(self.coarse.extent) // cfg.sweeps) + 2
        ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        self.ring = jnp.asarray(np.stack([np.cos(ang), np.sin(ang)], -1) * cfg.lookahead, jnp.float32)

    def init(self) -> NavState:
        z = jnp.int32(0)
        return NavState(jnp.zeros(3, jnp.float32), jnp.full(self.coarse_shape, BIG, jnp.float32),
                        jnp.int32(IDLE), z, z, jnp.float32(BIG))

    def set_target(self, nav: NavState, target: jax.Array, new: jax.Array) -> NavState:
        """Start driving to ``target`` (3,) when ``new`` (bool) is set; else keep going."""
        fresh = NavState(target.astype(jnp.float32), jnp.full(self.coarse_shape, BIG, jnp.float32),
                         jnp.int32(MOVING), jnp.int32(0), jnp.int32(0), jnp.float32(BIG))
        return jax.tree.map(lambda a, b: jnp.where(new, a, b), fresh, nav)

    def costs(self, occupied: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Coarse (blocked bool, step cost float32) from the fine occupied map (H, W) bool."""
        blocked = grid.grow(grid.block_any(occupied, self.factor))
        near = grid.grow(blocked)
        return blocked, 1.0 + self.cfg.near_cost * near.astype(jnp.float32)

    def sweep(self, field, blocked, cost, goal_ij):
        """Bellman sweeps over the 8-neighbourhood (diagonals cost sqrt 2); cells beyond the
        world's extent (session padding) stay unreachable, as cells off the grid are."""
        hc, wc = self.coarse_shape
        blocked = blocked | ~self.coarse.inside()

        def one(field, _):
            pad = jnp.pad(field, 1, constant_values=BIG)
            best = jnp.full_like(field, BIG)
            for di in (-1, 0, 1):
                for dj in (-1, 0, 1):
                    if di == 0 and dj == 0:
                        continue
                    step = cost * (1.41421356 if di and dj else 1.0)
                    nb = jax.lax.dynamic_slice(pad, (1 + di, 1 + dj), (hc, wc))
                    best = jnp.minimum(best, nb + step)
            best = jnp.where(blocked, BIG, jnp.minimum(best, BIG))
            return best.at[goal_ij].set(0.0), None

        field, _ = jax.lax.scan(one, field, None, length=self.cfg.sweeps)
        return field

    def step(self, nav: NavState, pose: jax.Array, occupied: jax.Array) -> tuple[NavState, jax.Array]:
        """One control step: refine the plan, pick (v, w), update status. Returns (nav, cmd)."""
        cfg = self.cfg
        blocked, cost = self.costs(occupied)
        goal_ij = self.coarse.cell(nav.target[:2])
        # The robot's own cell is never treated as blocked (it may hug a wall).
        ri, rj = self.coarse.cell(pose[:2])
        blocked = blocked.at[ri, rj].set(False)
        target_blocked = blocked[goal_ij]
        field = self.sweep(nav.field, blocked, cost, goal_ij)

        to_goal = nav.target[:2] - pose[:2]
        dist = jnp.linalg.norm(to_goal)
        at_goal = dist < cfg.goal_tolerance
        # Lowest cost-to-go on the lookahead ring (straight at the goal when it is that close).
        ring = pose[:2] + self.ring
        ci, cj = self.coarse.cell(ring)
        vals = field[ci, cj]
        aim = jnp.where(dist < cfg.lookahead * 1.5, jnp.arctan2(to_goal[1], to_goal[0]),
                        jnp.arctan2(self.ring[jnp.argmin(vals), 1], self.ring[jnp.argmin(vals), 0]))
        here = field[ri, rj]
        yaw_err = grid.wrap_angle(jnp.where(at_goal, nav.target[2], aim) - pose[2])
        w = jnp.clip(cfg.k_turn * yaw_err, -self.wmax, self.wmax)
        v = jnp.where(at_goal, 0.0, self.vmax * jnp.clip(jnp.cos(yaw_err), 0.0, 1.0) ** 2 * jnp.clip(dist / 0.5, 0.3, 1.0))

        moving = nav.status == MOVING
        progress = here * self.coarse.resolution < nav.best - cfg.stuck_progress
        best = jnp.where(progress, here * self.coarse.resolution, nav.best)
        # Before the wave reaches the robot there is nothing to make progress on.
        since = jnp.where(progress | (here >= BIG), 0, nav.since_progress + 1)
        elapsed = nav.elapsed + 1
        reached = at_goal & (jnp.abs(yaw_err) < cfg.yaw_tolerance)
        no_path = (here >= BIG) & (elapsed > self.settle_steps)
        status = jnp.select(
            [~moving, reached, target_blocked | no_path, since > self.stuck_steps, elapsed > self.timeout_steps],
            [nav.status, REACHED, UNREACHABLE, STUCK, TIMEOUT], MOVING).astype(jnp.int32)
        cmd = jnp.where(moving & (status == MOVING), jnp.stack([v, w]), 0.0)
        # Reaching the position may still need the final turn.
        cmd = jnp.where(moving & at_goal & ~reached, jnp.stack([0.0, w]), cmd)
        return NavState(nav.target, field, status, elapsed, since, best), cmd



