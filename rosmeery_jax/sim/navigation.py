"""Drive to a target pose on the robot's own map: a wavefront planner, a local controller
and recovery, in the manner of move_base / Nav2.

Planner: a cost-to-go field on a coarse grid (``plan_resolution``) over the robot's own
occupancy map, where unknown counts as traversable, occupied cells grown by one coarse cell
are blocked and cells next to them cost more. The field is refined by a few Bellman sweeps
every control step (``sweeps``) instead of being solved from scratch: the wave outruns the
robot, costs rise again where new obstacles appear, and every env does the same fixed work,
so the whole thing vmaps with no data-dependent loop.

Reachability: the open cells connected to the robot (``NavState.reach``): a flood from the
robot grows ``flood_cells`` cells per step; once it stops growing it is complete, replaces
``reach`` and a new one starts from the robot. A target outside it is enclosed on the map
the flood ran over (and so on later maps, which only gain obstacles) and is declared
UNREACHABLE at once, not after the wave has had time to cross the world.

Controller: head for the lowest cost-to-go on a ring around the robot, slow down for sharp
turns, and at the target position turn to the target yaw.

Recovery: no progress for ``stuck_time``, or no motion (within ``still_distance``) for
``still_time``, away from the goal, starts a recovery
(RECOVERING): the planning cells across the robot's front are marked blocked (``bumps``, kept
for the rest of the run: what a bumper reports, for obstacles the laser's plane misses, such
as chair feet and seats), then the robot backs off (``backoff_time`` at ``backoff_speed``), turns towards the new plan (at most
``turn_time``) and drives on. After ``recoveries`` of them without reaching the target the
navigator gives up: STUCK. A recovery that could not back the robot off (it ends within
``still_distance`` of where it began) is the last: a robot that cannot move at all drives
at most about 7.5 s (2 s still, 2.8 s of recovery, 2 s still) before it says so. The
no-motion clock runs on when the policy sends a new target mid-drive, so a policy that
re-targets every second cannot keep a wedged robot pushing without a recovery.

Status, reported in the state so policies can react: MOVING, RECOVERING, REACHED, STUCK,
UNREACHABLE (target off the map or not a finite pose, blocked or enclosed, or no path
once the wave had time to arrive),
TIMEOUT (``timeout`` seconds without reaching). IDLE before any target.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.core import grid
from rosmeery_jax.sim.occupancy import GridGeometry, in_extent

IDLE, MOVING, REACHED, STUCK, UNREACHABLE, TIMEOUT, RECOVERING = range(7)
STATUS_NAMES = ("idle", "moving", "reached", "stuck", "unreachable", "timeout", "recovering")
BIG = 1e6


def gave_up(nav) -> jax.Array:
    """bool: the navigator of ``nav`` (a NavState) gave up on its target (stuck, unreachable or timed out)."""
    return (nav.status == STUCK) | (nav.status == UNREACHABLE) | (nav.status == TIMEOUT)


def needs_target(nav) -> jax.Array:
    """bool: the navigator is done with its target (reached, gave up, or none yet)."""
    return gave_up(nav) | (nav.status == REACHED) | (nav.status == IDLE)


@dataclass(frozen=True)
class NavConfig:
    plan_resolution: float = 0.1
    sweeps: int = 3
    lookahead: float = 0.3
    goal_tolerance: float = 0.15
    yaw_tolerance: float = 0.15
    near_cost: float = 4.0
    k_turn: float = 2.5
    stuck_time: float = 3.0
    stuck_progress: float = 0.15
    still_time: float = 2.0  # driving yet within still_distance of one spot this long: wedged
    still_distance: float = 0.1  # as navigation.csv's still and longest-stuck measures
    timeout: float = 60.0
    recoveries: int = 2  # back-off-and-turn attempts per target before STUCK
    backoff_time: float = 0.8
    backoff_speed: float = 0.5  # at 0.25 m/s the velocity servo's force cap cannot break a wedged contact
    turn_time: float = 2.0
    flood_cells: int = 2  # cells the reachability flood grows per control step


class NavState(NamedTuple):
    """Per env. target (3,); field (Hc, Wc) cost-to-go in coarse cells; status int32;
    elapsed / since_progress int32 control steps; best float32 best cost-to-go so far;
    recovery int32 steps into the current recovery; tries int32 recoveries for this
    target; reach (Hc, Wc) bool the last finished reachability flood, flood (Hc, Wc) bool
    the one growing; bumps (Hc, Wc) bool cells found blocked by
    driving into them; trail (Hc, Wc) bool cells the robot's centre has been in; anchor (2,)
    where the robot last moved to, still int32 steps since; origin (2,) where the last
    recovery began."""

    target: jax.Array
    field: jax.Array
    status: jax.Array
    elapsed: jax.Array
    since_progress: jax.Array
    best: jax.Array
    recovery: jax.Array
    tries: jax.Array
    reach: jax.Array
    flood: jax.Array
    bumps: jax.Array
    trail: jax.Array
    anchor: jax.Array
    still: jax.Array
    origin: jax.Array


class Control(NamedTuple):
    """The controller's output for one step: cmd (2,) (v, w), yaw_err, at_goal and reached
    (bool), here: the cost-to-go at the robot's cell."""

    cmd: jax.Array
    yaw_err: jax.Array
    at_goal: jax.Array
    reached: jax.Array
    here: jax.Array


class Navigator:
    """Pure functions over :class:`NavState`; vmap over envs."""

    def __init__(self, geo: GridGeometry, cfg: NavConfig, control_dt: float, max_speed: float, max_turn: float,
                 robot_radius: float):
        self.geo, self.cfg, self.robot_radius = geo, cfg, robot_radius
        self.factor = max(1, int(round(cfg.plan_resolution / geo.resolution)))
        self.coarse = geo.coarse(self.factor)
        self.coarse_shape = self.coarse.shape
        self.dt, self.vmax, self.wmax = control_dt, max_speed, max_turn
        self.stuck_steps = int(round(cfg.stuck_time / control_dt))
        self.timeout_steps = int(round(cfg.timeout / control_dt))
        self.backoff_steps = int(round(cfg.backoff_time / control_dt))
        self.still_steps = int(round(cfg.still_time / control_dt))
        self.recovery_steps = self.backoff_steps + int(round(cfg.turn_time / control_dt))
        # Steps for the wave to cross the world's grid: only then is "no path" believed.
        self.settle_steps = -(-jnp.sum(self.coarse.extent) // cfg.sweeps) + 2
        ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        self.ring = jnp.asarray(np.stack([np.cos(ang), np.sin(ang)], -1) * cfg.lookahead, jnp.float32)

    def init(self) -> NavState:
        z = jnp.int32(0)
        everywhere = self.coarse.inside()  # before the first flood ends, nothing is known enclosed
        return NavState(jnp.zeros(3, jnp.float32), jnp.full(self.coarse_shape, BIG, jnp.float32),
                        jnp.int32(IDLE), z, z, jnp.float32(BIG), z, z, everywhere, jnp.zeros_like(everywhere),
                        jnp.zeros_like(everywhere), jnp.zeros_like(everywhere), jnp.zeros(2, jnp.float32), z,
                        jnp.zeros(2, jnp.float32))

    def set_target(self, nav: NavState, target: jax.Array, new: jax.Array) -> NavState:
        """Start driving to ``target`` (3,) when ``new`` (bool) is set; else keep going."""
        z = jnp.int32(0)
        fresh = nav._replace(target=target.astype(jnp.float32), field=jnp.full(self.coarse_shape, BIG, jnp.float32),
                             status=jnp.int32(MOVING), elapsed=z, since_progress=z, best=jnp.float32(BIG),
                             recovery=z, tries=z)
        return jax.tree.map(lambda a, b: jnp.where(new, a, b), fresh, nav)

    def open_cells(self, nav: NavState, pose: jax.Array, occupied: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Coarse (open bool (Hc, Wc), step cost float32) for the robot at ``pose`` on the
        fine occupied map (H, W) bool: open = inside the world and neither blocked nor
        bumped, or on the robot's trail and its own cell (it got there: growing obstacles
        by a cell must not wall it in where it has driven)."""
        blocked, cost = self.costs(occupied, nav.bumps)
        ri, rj = self.coarse.cell(pose[:2])
        open_ = ((~blocked | nav.trail) & self.coarse.inside()).at[ri, rj].set(True)
        return open_, cost

    def reachable(self, nav: NavState, pose: jax.Array, occupied: jax.Array) -> jax.Array:
        """(Hc, Wc) bool: the open cells connected to the robot at ``pose`` on this map."""
        open_, _ = self.open_cells(nav, pose, occupied)
        return grid.connected(self._here(pose), open_)

    def draw_reachable(self, nav: NavState, pose: jax.Array, occupied: jax.Array, key: jax.Array, k: int) -> jax.Array:
        """(k, 3) target poses: cells drawn uniformly, with replacement, over those reachable
        on this map (never none: the robot's own cell is one), each with a uniform yaw."""
        k_cell, k_yaw = jax.random.split(key)
        reach = self.reachable(nav, pose, occupied)  # (Hc, Wc)
        cells = grid.draw(k_cell, reach, k)
        xy = self.coarse.center(cells // reach.shape[1], cells % reach.shape[1])
        return jnp.concatenate([xy, jax.random.uniform(k_yaw, (k, 1), minval=-jnp.pi, maxval=jnp.pi)], -1)

    def _here(self, pose: jax.Array) -> jax.Array:
        ri, rj = self.coarse.cell(pose[:2])
        return jnp.zeros(self.coarse_shape, bool).at[ri, rj].set(True)

    def _flood(self, nav: NavState, pose: jax.Array, open_: jax.Array) -> NavState:
        """One step of the reachability flood (plain dilation: a row-and-column pass of
        ``grid.spread`` costs 16 dilations here); a flood that stopped growing is complete,
        becomes ``reach``, and a new one starts from the robot."""
        start = (nav.flood | self._here(pose)) & open_
        flood = start
        for _ in range(self.cfg.flood_cells):
            flood = grid.grow(flood) & open_
        done = jnp.all(flood == start)
        return nav._replace(reach=jnp.where(done, flood, nav.reach), flood=jnp.where(done, False, flood))

    def costs(self, occupied: jax.Array, bumps: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Coarse (blocked bool, step cost float32) from the fine occupied map (H, W) bool and
        the bumped coarse cells (Hc, Wc), grown alike."""
        blocked = grid.grow(grid.block_any(occupied, self.factor) | bumps)
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
        open_, cost = self.open_cells(nav, pose, occupied)
        nav = self._flood(nav, pose, open_)
        goal_ij = self.coarse.cell(nav.target[:2])  # clipped into the map: an off-map goal needs its own test
        enclosed = ~open_[goal_ij] | ~nav.reach[goal_ij]
        # Off the planner's map (its partial blocks at the far edges count: targets are drawn
        # at their centres), or not finite (NaN xy is in no extent).
        off_map = ~(in_extent(self.coarse, nav.target[:2]) & jnp.isfinite(nav.target[2]))
        field = self.sweep(nav.field, ~open_, cost, goal_ij)
        c = self._control(nav, pose, field)

        active = (nav.status == MOVING) | (nav.status == RECOVERING)
        recovering = nav.status == RECOVERING
        progress = c.here * self.coarse.resolution < nav.best - cfg.stuck_progress
        best = jnp.where(progress, c.here * self.coarse.resolution, nav.best)
        # Before the wave reaches the robot there is nothing to make progress on: the clock
        # waits (a robot nudged into a cell the plan has not reached keeps its count).
        since = jnp.where(progress, 0, nav.since_progress + (c.here < BIG))
        moved = jnp.linalg.norm(pose[:2] - nav.anchor) > cfg.still_distance
        # Counted while driving away from the goal, across a new target sent mid-drive; paused
        # while the plan has not reached the robot (a new target's plan starts afresh).
        still = jnp.where(moved | recovering | ~active | c.at_goal, 0, nav.still + (c.here < BIG))
        elapsed = nav.elapsed + 1
        no_path = (c.here >= BIG) & (elapsed > self.settle_steps)
        recovery = jnp.where(recovering, nav.recovery + 1, 0)
        # A recovery ends after its steps, or once turned towards the plan after backing off.
        recovered = recovering & ((recovery >= self.recovery_steps)
                                  | ((recovery > self.backoff_steps) & (jnp.abs(c.yaw_err) < cfg.yaw_tolerance)))
        no_progress = ~recovering & ~c.at_goal & ((since > self.stuck_steps) | (still > self.still_steps))
        boxed = self._boxed(open_, pose)
        retry = nav.tries < cfg.recoveries
        status = jnp.select(
            [~active, off_map, c.reached, recovering & ~recovered, boxed & retry, boxed, enclosed | no_path,
             elapsed > self.timeout_steps, no_progress & retry, no_progress],
            [nav.status, UNREACHABLE, REACHED, RECOVERING, RECOVERING, STUCK, UNREACHABLE, TIMEOUT, RECOVERING, STUCK],
            MOVING).astype(jnp.int32)
        starts = (status == RECOVERING) & (~recovering | recovered)
        recovery = jnp.where((status == RECOVERING) & ~starts, recovery, 0)
        # A recovery (and the drive after it) measures its progress afresh.
        afresh = starts | recovered
        # A recovery that could not back the robot off leaves no retry: pushing on gains nothing.
        freed = jnp.linalg.norm(pose[:2] - nav.origin) > cfg.still_distance
        tries = jnp.where(recovered & ~freed, cfg.recoveries, nav.tries + starts)
        cmd = jnp.where(status == MOVING, c.cmd, 0.0)
        cmd = jnp.where(status == RECOVERING, self._recover(recovery, c.cmd[1]), cmd)
        return nav._replace(field=field, status=status, elapsed=elapsed, since_progress=jnp.where(afresh, 0, since),
                            best=jnp.where(recovered, BIG, best), recovery=recovery, tries=tries,
                            bumps=self._bump(nav.bumps, pose, starts, boxed),
                            trail=nav.trail.at[self.coarse.cell(pose[:2])].set(True),
                            anchor=jnp.where(moved, pose[:2], nav.anchor), still=jnp.where(afresh, 0, still),
                            origin=jnp.where(starts, pose[:2], nav.origin)), cmd

    def _bump(self, bumps: jax.Array, pose: jax.Array, starts: jax.Array, boxed: jax.Array) -> jax.Array:
        """The bumped cells after this step: a recovery from no progress marks the cells
        across the robot's front; one from being boxed in clears them all, as Nav2's first
        recovery clears its costmap (the robot's own bumps may be what boxed it in)."""
        bumps = jnp.where(starts & boxed, False, bumps)
        return bumps.at[self.coarse.cell(self._front(pose))].max(starts & ~boxed)

    def _control(self, nav: NavState, pose: jax.Array, field: jax.Array) -> "Control":
        """The local controller: head for the lowest cost-to-go on the lookahead ring
        (straight at the goal when it is that close), slow for sharp turns, and at the goal
        position turn to the target yaw."""
        cfg = self.cfg
        to_goal = nav.target[:2] - pose[:2]
        dist = jnp.linalg.norm(to_goal)
        at_goal = dist < cfg.goal_tolerance
        ci, cj = self.coarse.cell(pose[:2] + self.ring)
        best = self.ring[jnp.argmin(field[ci, cj])]
        aim = jnp.where(dist < cfg.lookahead * 1.5, jnp.arctan2(to_goal[1], to_goal[0]), jnp.arctan2(best[1], best[0]))
        yaw_err = grid.wrap_angle(jnp.where(at_goal, nav.target[2], aim) - pose[2])
        w = jnp.clip(cfg.k_turn * yaw_err, -self.wmax, self.wmax)
        v = jnp.where(at_goal, 0.0, self.vmax * jnp.clip(jnp.cos(yaw_err), 0.0, 1.0) ** 2 * jnp.clip(dist / 0.5, 0.3, 1.0))
        ri, rj = self.coarse.cell(pose[:2])
        return Control(jnp.stack([v, w]), yaw_err, at_goal, at_goal & (jnp.abs(yaw_err) < cfg.yaw_tolerance),
                       field[ri, rj])

    def _boxed(self, open_: jax.Array, pose: jax.Array) -> jax.Array:
        """Wedged with no open cell around the robot's: no plan can start, so back off first."""
        ri, rj = self.coarse.cell(pose[:2])
        return ~jnp.any(jax.lax.dynamic_slice(jnp.pad(open_, 1), (ri, rj), (3, 3)).at[1, 1].set(False))

    def _front(self, pose: jax.Array) -> jax.Array:
        """(3, 2) points just ahead of the robot: in front of its centre and of either side."""
        c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
        ahead = pose[:2] + (self.robot_radius + 0.5 * self.coarse.resolution) * jnp.stack([c, s])
        side = 0.75 * self.robot_radius * jnp.stack([-s, c])
        return jnp.stack([ahead - side, ahead, ahead + side])

    def _recover(self, recovery: jax.Array, w: jax.Array) -> jax.Array:
        """(v, w) in a recovery: back straight off, then turn. Backing off is not checked
        against the map: what wedged the robot is often missing from it, and the physics
        stops a robot that backs into a wall without harm."""
        return jnp.where(recovery <= self.backoff_steps, jnp.stack([-self.cfg.backoff_speed, 0.0]), jnp.stack([0.0, w]))
