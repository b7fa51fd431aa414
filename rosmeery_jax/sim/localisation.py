"""The robot's own pose estimate (docs/robot.md, "Localisation"), pure JAX inside the step.

- ``ground_truth``: the robot is told its pose (the benchmark's default).
- ``dead_reckoning``: wheel odometry integrated: each step's true motion in the robot's
  frame (forward, sideways, turn), each with noise growing with the motion
  (``NoiseConfig.odom_a1 .. a4``, the parameters of the odometry motion model of Thrun,
  Burgard and Fox, Probabilistic Robotics 5.4, applied to the frame's increment rather
  than to its turn-translation-turn decomposition, whose first turn is arbitrary when a
  robot turns on the spot), composed onto the last estimate. It drifts without bound.
- ``scan_matching``: dead reckoning's prediction refined by a correlative scan matcher
  against the robot's own occupancy map, as a 2D SLAM front end does: the laser's hit
  points are scored on the map's occupancy (bilinear in the log-odds, occupied side only)
  over a grid of poses around the prediction, coarse to fine (three stages of 3 x 3 x 3,
  each around the last's best), and the best pose is kept when it scores better than the
  prediction. It runs only on steps where the odometry reports motion (:func:`moved`), a
  motion filter as GMapping's and Cartographer's: at rest the map holds no information the
  last match lacked, and on the worlds' grid-aligned walls (their hits on cell corners) the
  bilinear score moved a resting robot by half a cell.

Shapes: K laser beams, C candidate poses.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from rosmeery_jax.sim.noise import NoiseConfig
from rosmeery_jax.sim.occupancy import GridGeometry

MODES = ("ground_truth", "dead_reckoning", "scan_matching")
# (step xy m, step yaw rad) of the matcher's stages; each searches +-1 step on every axis
STAGES = ((0.04, math.radians(1.0)), (0.02, math.radians(0.5)), (0.01, math.radians(0.25)))
STILL = (1e-3, math.radians(0.05))  # m, rad: an odometry step below both is a robot at rest


def wrap(a: jax.Array) -> jax.Array:
    return (a + jnp.pi) % (2 * jnp.pi) - jnp.pi


def odometry(key: jax.Array, before: jax.Array, after: jax.Array, estimate: jax.Array,
             cfg: NoiseConfig) -> jax.Array:
    """The estimate (3,) after one step of odometry: the true motion ``before`` -> ``after``
    (3,) x, y, yaw, measured in the robot's frame (forward, sideways, turn) with noise
    (forward: N(0, a3 f^2 + a4 turn^2), turn: N(0, a1 turn^2 + a2 f^2)), composed onto
    ``estimate``."""
    c, s = jnp.cos(before[2]), jnp.sin(before[2])
    d = after[:2] - before[:2]
    fwd, side, turn = c * d[0] + s * d[1], -s * d[0] + c * d[1], wrap(after[2] - before[2])
    e = jax.random.normal(key, (3,))
    fwd_m = fwd + e[0] * jnp.sqrt(cfg.odom_a3 * fwd ** 2 + cfg.odom_a4 * turn ** 2)
    side_m = side + e[1] * jnp.sqrt(cfg.odom_a3 * side ** 2)
    turn_m = turn + e[2] * jnp.sqrt(cfg.odom_a1 * turn ** 2 + cfg.odom_a2 * fwd ** 2)
    ce, se = jnp.cos(estimate[2]), jnp.sin(estimate[2])
    return jnp.stack([estimate[0] + ce * fwd_m - se * side_m, estimate[1] + se * fwd_m + ce * side_m,
                      wrap(estimate[2] + turn_m)]).astype(estimate.dtype)


def moved(before: jax.Array, after: jax.Array) -> jax.Array:
    """Whether the odometry's step ``before`` -> ``after`` (3,) is motion (the matcher runs)."""
    return (jnp.hypot(*(after[:2] - before[:2])) > STILL[0]) | (jnp.abs(wrap(after[2] - before[2])) > STILL[1])


def _occupancy(logodds: jax.Array, geo: GridGeometry, xy: jax.Array) -> jax.Array:
    """Bilinear positive log-odds (occupied evidence) at world points (..., 2); 0 outside."""
    occ = jnp.maximum(logodds, 0.0)
    u = (xy[..., 0] - geo.origin[0]) / geo.resolution - 0.5
    v = (xy[..., 1] - geo.origin[1]) / geo.resolution - 0.5
    j0, i0 = jnp.floor(u), jnp.floor(v)
    fu, fv = u - j0, v - i0
    h, w = geo.extent[0], geo.extent[1]

    def at(i, j):
        ok = (i >= 0) & (j >= 0) & (i < h) & (j < w)
        return jnp.where(ok, occ[jnp.clip(i, 0, occ.shape[0] - 1).astype(jnp.int32),
                                 jnp.clip(j, 0, occ.shape[1] - 1).astype(jnp.int32)], 0.0)

    return ((1 - fu) * (1 - fv) * at(i0, j0) + fu * (1 - fv) * at(i0, j0 + 1)
            + (1 - fu) * fv * at(i0 + 1, j0) + fu * fv * at(i0 + 1, j0 + 1))


def _offsets(step_xy: float, step_yaw: float) -> jax.Array:
    """(27, 3) offsets of +-1 step per axis, the zero offset first (a tie keeps it)."""
    r = jnp.arange(-1, 2, dtype=jnp.float32)
    g = jnp.stack(jnp.meshgrid(r * step_xy, r * step_xy, r * step_yaw, indexing="ij"), -1).reshape(-1, 3)
    zero = jnp.argmin(jnp.sum(jnp.abs(g), -1))
    return jnp.concatenate([g[zero][None], jnp.delete(g, zero, axis=0, assume_unique_indices=True)])


def match(logodds: jax.Array, geo: GridGeometry, prediction: jax.Array, angles: jax.Array, ranges: jax.Array,
          max_range: float) -> jax.Array:
    """The pose (3,) near ``prediction`` whose laser hit points (``ranges`` (K,) at beam
    ``angles`` (K,) in the robot frame; max_range: none) best fit the map's occupancy."""
    hit = ranges < max_range
    local = jnp.stack([ranges * jnp.cos(angles), ranges * jnp.sin(angles)], -1)  # (K, 2)

    def score(p):
        c, s = jnp.cos(p[2]), jnp.sin(p[2])
        world = p[:2] + jnp.stack([c * local[:, 0] - s * local[:, 1], s * local[:, 0] + c * local[:, 1]], -1)
        return jnp.sum(jnp.where(hit, _occupancy(logodds, geo, world), 0.0))

    pose = prediction
    for step_xy, step_yaw in STAGES:
        cands = pose + _offsets(step_xy, step_yaw)
        scores = jax.vmap(score)(cands)
        pose = cands[jnp.argmax(scores)]  # the zero offset first: no evidence keeps the prediction
    return pose.at[2].set(wrap(pose[2]))
