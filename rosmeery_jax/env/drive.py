"""A task's drive (docs/tasks.md, executed tasks): one robot put at an episode's start and
driven by its navigator to a goal pose on its own occupancy map, as it was at the end of
exploring, until the navigator is done with the goal (reached it, or gave up).

The map is frozen: the drive steps the physics, the laser, the localisation and the
navigator (:meth:`RobotEnv.drive`), not the camera or the map, so many drives of one robot
share its map (``vmap`` them with the map unbatched). A drive keeps stepping once done
(the navigator commands no motion then); what it reports stops counting there.

Shapes: H, W the occupancy grid; one drive per call (vmap for S drives of a robot).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from rosmeery_jax.env.environment import RobotEnv, State
from rosmeery_jax.sim.navigation import IDLE, needs_target


class Drive(NamedTuple):
    """One drive: the robot's state (no map, camera or knowledge: ``logodds`` None), the
    true distance driven (m) and the control steps taken toward its goals so far, whether
    the navigator is done with the current goal, and the true pose (3,) where it was then."""

    state: State
    path: jax.Array
    steps: jax.Array
    ended: jax.Array
    stop: jax.Array


def start(env: RobotEnv, pose: jax.Array, logodds: jax.Array, key: jax.Array) -> Drive:
    """A drive from ``pose`` (3,), known to the robot (its estimate starts there), on the
    map ``logodds`` (H, W)."""
    truth = None if env.config.localisation == "ground_truth" else pose
    none = jnp.zeros((0, 0), jnp.float32)
    state = State(env.platform.init(pose), pose, logodds, env.navigator.init(),
                  jnp.zeros(env.config.laser.beams, jnp.float32), none, none.astype(jnp.int32), jnp.int32(0), key,
                  None, truth)
    state = env._localise(state)[0]._replace(logodds=None)
    return Drive(state, jnp.float32(0), jnp.int32(0), jnp.bool_(False), pose)


def advance(env: RobotEnv, drive: Drive, goal: jax.Array, logodds: jax.Array, steps: int) -> Drive:
    """``steps`` control steps toward ``goal`` (3,) x, y, yaw on the map ``logodds``. A goal
    other than the navigator's starts a new navigation (the drive is no longer done)."""
    ended = drive.ended & jnp.all(goal == drive.state.nav.target)

    def step(d: Drive, _):
        s = env.drive(d.state._replace(logodds=logodds), goal)._replace(logodds=None)
        moving = ~d.ended
        moved = jnp.hypot(*(s.true_pose[:2] - d.state.true_pose[:2]))
        ended = d.ended | (needs_target(s.nav) & (s.nav.status != IDLE))
        stop = jnp.where(moving, s.true_pose, d.stop)
        return Drive(s, d.path + jnp.where(moving, moved, 0.0), d.steps + moving, ended, stop), None

    return jax.lax.scan(step, drive._replace(ended=ended), None, length=steps)[0]
