"""Sensor and actuation noise (docs/robot.md, "Noise"): what a real robot's sensors add to
the exact rendering, seeded per robot and step, pure JAX inside the step.

- depth: axial noise growing with distance, sigma(z) = a + b (z - z0)^2 (Nguyen, Izadi and
  Lovell 2012, a Kinect); lateral noise (each pixel reads a neighbour's depth, offsets
  ~ N(0, sigma_px) rounded); quantisation in disparity (a structured-light camera of
  focal f_q pixels and baseline B measures disparity f_q B / z in steps of ``disparity_step``
  pixels); no return at depth edges (a jump of more than ``edge_jump`` m to a 4-neighbour,
  with probability ``edge_dropout``) and at grazing incidence (above ``max_incidence``,
  judged from the depth change per pixel on the pixel's own surface: the smaller of the
  one-sided differences on each axis, so that an edge is not taken for a grazing surface);
- laser: Gaussian range noise and dropouts (a dropped beam reads max_range, no return);
- RGB: Gaussian pixel noise (8-bit units), clipped;
- actuation: the executed velocity differs from the command, the velocity motion model of
  Thrun, Burgard and Fox (Probabilistic Robotics, 5.3): v + N(0, a1 v^2 + a2 w^2),
  w + N(0, a3 v^2 + a4 w^2);
- wheel odometry (read when the robot localises itself, :mod:`.localisation`): the
  odometry motion model's ``odom_a1 .. a4`` (5.4).

Every parameter 0 is that noise off; ``NoiseConfig()`` is all off (the exact sensors).
``PRESETS["realistic"]`` is a Kinect-class depth camera, a 2D lidar, a webcam and a
differential drive. Keys: :func:`key` folds the robot's key with the step and a stream
number, so a robot's noise depends on its seed and time only, not on its batch-mates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from rosmeery_jax.core.errors import InputError

DEPTH, LASER, RGB, ACTUATION, SWEEP, ODOMETRY = 1, 2, 3, 4, 5, 6  # key streams (SWEEP: the depth camera of every step)


@dataclass(frozen=True)
class NoiseConfig:
    depth_sigma0: float = 0.0  # m: a of sigma(z) = a + b (z - z0)^2
    depth_sigma2: float = 0.0  # 1/m: b
    depth_z0: float = 0.4  # m: z0
    depth_lateral_px: float = 0.0  # pixels: sigma of the lateral offset
    disparity_step: float = 0.0  # pixels of disparity per step (0: no quantisation)
    disparity_focal: float = 580.0  # pixels: f_q of the quantisation's camera
    disparity_baseline: float = 0.075  # m: B
    edge_jump: float = 0.0  # m: a depth edge (0: none dropped at edges)
    edge_dropout: float = 0.0  # probability a pixel at a depth edge has no return
    max_incidence: float = 0.0  # radians: no return beyond (0: none dropped)
    laser_sigma: float = 0.0  # m
    laser_dropout: float = 0.0  # probability a beam has no return
    rgb_sigma: float = 0.0  # 8-bit units
    motion_a1: float = 0.0  # executed v's variance per v^2
    motion_a2: float = 0.0  # ... per w^2 (m^2 / rad^2)
    motion_a3: float = 0.0  # executed w's variance per v^2 (rad^2 / m^2)
    motion_a4: float = 0.0  # ... per w^2
    odom_a1: float = 0.0  # wheel odometry (sim.localisation): a turn's variance per turn^2
    odom_a2: float = 0.0  # ... per translation^2 (rad^2 / m^2)
    odom_a3: float = 0.0  # a translation's variance per translation^2
    odom_a4: float = 0.0  # ... per turn^2 (m^2 / rad^2)

    @property
    def depth(self) -> bool:
        return bool(self.depth_sigma0 or self.depth_sigma2 or self.depth_lateral_px or self.disparity_step
                    or self.edge_dropout or self.max_incidence)

    @property
    def laser(self) -> bool:
        return bool(self.laser_sigma or self.laser_dropout)

    @property
    def rgb(self) -> bool:
        return bool(self.rgb_sigma)

    @property
    def actuation(self) -> bool:
        return bool(self.motion_a1 or self.motion_a2 or self.motion_a3 or self.motion_a4)


PRESETS = {
    "off": NoiseConfig(),
    # A Kinect-class camera (Nguyen et al. 2012's axial model, 0.5 px lateral, 1/8 px disparity
    # steps, edges and grazing returns dropped), a 2D lidar (1 cm, 1 % dropouts), a webcam's
    # sensor noise (3 of 255), a differential drive executing its command within ~10 %.
    "realistic": NoiseConfig(depth_sigma0=0.0012, depth_sigma2=0.0019, depth_z0=0.4, depth_lateral_px=0.5,
                             disparity_step=0.125, edge_jump=0.1, edge_dropout=0.5, max_incidence=math.radians(80),
                             laser_sigma=0.01, laser_dropout=0.01, rgb_sigma=3.0, motion_a1=0.01, motion_a2=0.001,
                             motion_a3=0.001, motion_a4=0.01, odom_a1=0.0025, odom_a2=0.0025, odom_a3=0.0025,
                             odom_a4=0.0001),
}


def preset(name: str, source: str = "config", where: str = "noise") -> NoiseConfig:
    if name not in PRESETS:
        raise InputError(source, where, f"{name!r} is not a noise preset ({', '.join(PRESETS)})")
    return PRESETS[name]


def key(robot_key: jax.Array, t: jax.Array, stream: int) -> jax.Array:
    """The key of one noise stream at step ``t`` of one robot."""
    return jax.random.fold_in(jax.random.fold_in(robot_key, t), stream)


def depth(k: jax.Array, z: jax.Array, cfg: NoiseConfig, focal: float) -> jax.Array:
    """A noisy depth image (H, W) from the exact one (0: no return); ``focal``: the
    image's focal length in pixels (for the incidence)."""
    h, w = z.shape
    ka, kl, ke = jax.random.split(k, 3)
    valid = z > 0
    if cfg.depth_lateral_px:
        off = jnp.round(cfg.depth_lateral_px * jax.random.normal(kl, (2, h, w))).astype(jnp.int32)
        rows = jnp.clip(jnp.arange(h)[:, None] + off[0], 0, h - 1)
        cols = jnp.clip(jnp.arange(w)[None, :] + off[1], 0, w - 1)
        z, valid = z[rows, cols], valid[rows, cols]
    sigma = cfg.depth_sigma0 + cfg.depth_sigma2 * (z - cfg.depth_z0) ** 2
    noisy = z + sigma * jax.random.normal(ka, z.shape)
    if cfg.disparity_step:
        fb = cfg.disparity_focal * cfg.disparity_baseline
        disparity = jnp.round(fb / jnp.maximum(noisy, 1e-3) / cfg.disparity_step) * cfg.disparity_step
        noisy = fb / jnp.maximum(disparity, cfg.disparity_step)
    drop = ~valid | (noisy <= 0)
    if cfg.edge_dropout and cfg.edge_jump:
        jump = jnp.zeros_like(z, bool)
        padded = jnp.pad(z, 1, mode="edge")  # the border has no neighbour beyond it
        for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            n = padded[1 + dr:1 + dr + h, 1 + dc:1 + dc + w]
            jump |= (jnp.abs(z - n) > cfg.edge_jump) & (n > 0)  # between two returns
        drop |= jump & (jax.random.uniform(ke, z.shape) < cfg.edge_dropout)
    if cfg.max_incidence:
        slope = jnp.hypot(_surface_step(z, valid, 0), _surface_step(z, valid, 1)) * focal / jnp.maximum(z, 1e-3)
        drop |= slope > math.tan(cfg.max_incidence)  # depth change per pixel footprint: tan(incidence)
    return jnp.where(drop, 0.0, noisy).astype(jnp.float32)


def _surface_step(z: jax.Array, valid: jax.Array, axis: int) -> jax.Array:
    """(H, W) depth change per pixel along ``axis`` on the surface a pixel sees: the smaller
    of its two one-sided differences to returning neighbours (a slope limiter), so a jump to
    another surface beside it (an edge, judged by the edge test alone) is not taken for a
    steep slope; 0 where neither neighbour returns."""
    pad = [(0, 0), (0, 0)]
    pad[axis] = (1, 1)
    zp, vp = jnp.pad(z, pad), jnp.pad(valid, pad)  # beyond the border: no neighbour
    n = z.shape[axis]
    sides = []
    for start in (0, 2):
        nz = jax.lax.slice_in_dim(zp, start, start + n, axis=axis)
        nv = jax.lax.slice_in_dim(vp, start, start + n, axis=axis)
        sides.append(jnp.where(nv, jnp.abs(z - nz), jnp.inf))
    step = jnp.minimum(*sides)
    return jnp.where(jnp.isfinite(step), step, 0.0)


def ranges(k: jax.Array, r: jax.Array, cfg: NoiseConfig, min_range: float, max_range: float) -> jax.Array:
    """Noisy laser ranges (K,); a dropped beam, like one beyond range, reads max_range."""
    kn, kd = jax.random.split(k)
    hit = r < max_range
    noisy = jnp.clip(r + cfg.laser_sigma * jax.random.normal(kn, r.shape), min_range, max_range)
    drop = jax.random.uniform(kd, r.shape) < cfg.laser_dropout
    return jnp.where(hit & ~drop, noisy, max_range).astype(r.dtype)


def rgb(k: jax.Array, img: jax.Array, cfg: NoiseConfig) -> jax.Array:
    """A noisy 8-bit image (H, W, 3)."""
    noisy = img.astype(jnp.float32) + cfg.rgb_sigma * jax.random.normal(k, img.shape)
    return jnp.clip(jnp.round(noisy), 0, 255).astype(jnp.uint8)


def command(k: jax.Array, cmd: jax.Array, cfg: NoiseConfig) -> jax.Array:
    """The executed (v, w) for the command (v, w): the velocity motion model."""
    v, w = cmd[0], cmd[1]
    sv = jnp.sqrt(cfg.motion_a1 * v * v + cfg.motion_a2 * w * w)
    sw = jnp.sqrt(cfg.motion_a3 * v * v + cfg.motion_a4 * w * w)
    e = jax.random.normal(k, (2,))
    return jnp.stack([v + sv * e[0], w + sw * e[1]]).astype(cmd.dtype)
