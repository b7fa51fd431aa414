"""The robot's sensors as ray bundles: planar laser, depth + segmentation camera, RGB camera.

All functions take a robot pose (x, y, yaw) and are pure; vmap them over envs. The camera
looks along the robot's heading from ``(mount_x, 0, height)`` in the robot frame, tilted
down by ``pitch``; depth is the distance along the optical axis (as depth cameras report).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.core import grid
from rosmeery_jax.raycast.kernel import RayScene, cast, cast_columns, index_bits, materialized, padded_boxes
from rosmeery_jax.world.scene import NOTHING


@dataclass(frozen=True)
class LaserConfig:
    """Planar laser. Defaults: the original robot's 180 deg FOV and 0.2-15 m range; 90 beams
    (the original had 512) keeps mapping cheap at 2 deg resolution."""

    beams: int = 90
    fov: float = np.pi
    min_range: float = 0.2
    max_range: float = 15.0
    height: float = 0.3


@dataclass(frozen=True)
class CameraConfig:
    """RGB-D camera (docs/robot.md): 60 deg horizontal FOV, 0.02-8 m, mounted 0.5 m high.

    width x height is the depth/segmentation resolution used every step; rgb_width x
    rgb_height the detector's resolution, rendered only on detector frames.
    """

    width: int = 64
    height: int = 48
    rgb_width: int = 160
    rgb_height: int = 128
    hfov: float = np.deg2rad(60.0)
    min_range: float = 0.02
    max_range: float = 8.0
    mount_height: float = 0.5
    mount_x: float = 0.1
    pitch: float = 0.0
    cull: int = 128  # boxes cast per frame: the nearest ones that can appear in the frustum
    # (0 = all). Exact whenever no more than this many boxes lie in the frustum and range;
    # beyond that the farthest are dropped (they are nearly always hidden behind nearer
    # ones: `rosmeery bench` reports the share of pixels that differ from casting all).

    def focal(self, width: int) -> float:
        return 0.5 * width / np.tan(0.5 * self.hfov)


def laser_dirs(cfg: LaserConfig) -> np.ndarray:
    """Beam angles (beams,) in the robot frame, from -fov/2 to +fov/2."""
    return np.linspace(-cfg.fov / 2, cfg.fov / 2, cfg.beams).astype(np.float32)


def camera_rays(cfg: CameraConfig, width: int, height: int) -> np.ndarray:
    """Unit ray directions (H * W, 3) in the camera frame (x forward, y left, z up), row-major
    from the top-left pixel."""
    f = cfg.focal(width)
    u = np.arange(width) + 0.5 - width / 2
    v = np.arange(height) + 0.5 - height / 2
    uu, vv = np.meshgrid(u, v)
    d = np.stack([np.full_like(uu, f), -uu, -vv], -1).reshape(-1, 3)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    cp, sp = np.cos(cfg.pitch), np.sin(cfg.pitch)
    tilt = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])  # pitch down for positive pitch
    return (d @ tilt.T).astype(np.float32)


def _yaw_rotate(d: jax.Array, yaw: jax.Array) -> jax.Array:
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    return jnp.stack([c * d[..., 0] - s * d[..., 1], s * d[..., 0] + c * d[..., 1], d[..., 2]], -1)


def camera_pose(cfg: CameraConfig, pose: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Camera origin (3,) and optical axis (3,) in the world for a robot pose (x, y, yaw)."""
    x, y, yaw = pose[0], pose[1], pose[2]
    origin = jnp.stack([x + cfg.mount_x * jnp.cos(yaw), y + cfg.mount_x * jnp.sin(yaw), jnp.float32(cfg.mount_height)])
    axis = _yaw_rotate(jnp.array([np.cos(cfg.pitch), 0.0, -np.sin(cfg.pitch)], jnp.float32), yaw)
    return origin, axis


def half_angle(cfg: CameraConfig, width: int, height: int) -> float:
    """Largest horizontal angle (rad) between a camera ray and the optical axis' heading."""
    d = camera_rays(cfg, width, height)
    if np.any(d[:, 0] <= 0):
        return float(np.pi)
    return float(np.max(np.abs(np.arctan2(d[:, 1], d[:, 0]))))


def frustum_boxes(rs: RayScene, cfg: CameraConfig, origin: jax.Array, yaw: jax.Array,
                  width: int, height: int) -> RayScene:
    """The ``cfg.cull`` boxes nearest the camera among those whose plan-view bounding circle
    meets the camera's horizontal field of view within range, nearest first (all boxes when
    ``cull`` is 0). Conservative per box: a box left out cannot be hit unless more than
    ``cull`` boxes pass the test. The order depends only on the boxes that pass, so padding
    boxes (far away) change nothing."""
    if cfg.cull <= 0:
        return rs
    k = min(padded_boxes(cfg.cull), rs.num_boxes)
    rel = rs.center[:, :2] - origin[:2]
    dist = jnp.linalg.norm(rel, axis=-1)
    radius = jnp.linalg.norm(rs.half[:, :2], axis=-1)
    near = dist - radius
    off = jnp.abs(grid.wrap_angle(jnp.arctan2(rel[:, 1], rel[:, 0]) - yaw))
    spread = jnp.arcsin(jnp.clip(radius / jnp.maximum(dist, 1e-6), 0.0, 1.0))
    seen = (near <= cfg.max_range) & ((off <= half_angle(cfg, width, height) + spread) | (dist <= radius))
    _, idx = jax.lax.top_k(-jnp.where(seen, near, jnp.inf), k)
    return RayScene(rs.center[idx], rs.half[idx], rs.cos[idx], rs.sin[idx], rs.label[idx], rs.rgb[idx], rs.floor_rgb)


def _camera_cast(rs: RayScene, cfg: CameraConfig, pose: jax.Array, width: int, height: int):
    """(hit, world ray directions (H*W, 3), culled scene) for a camera image of width x height."""
    o, _ = camera_pose(cfg, pose)
    d = _yaw_rotate(jnp.asarray(camera_rays(cfg, width, height)), pose[2])
    rs = frustum_boxes(rs, cfg, o, pose[2], width, height)
    # The key's index bits follow the cull size (fixed), not the culled scene's padded size.
    bits = index_bits(padded_boxes(cfg.cull)) if cfg.cull > 0 else None
    if cfg.pitch == 0.0:  # a level camera: its columns are vertical fans (cast_columns)
        hit = cast_columns(rs, o, d.reshape(height, width, 3), cfg.max_range, bits)
    else:
        hit = cast(rs, o, d, cfg.max_range, bits)
    return hit, d, rs


def laser(rs: RayScene, cfg: LaserConfig, pose: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Ranges (beams,) and labels (beams,) for a robot pose (3,). No return: max_range, NOTHING."""
    ang = pose[2] + jnp.asarray(laser_dirs(cfg))
    d = jnp.stack([jnp.cos(ang), jnp.sin(ang), jnp.zeros_like(ang)], -1)
    o = jnp.stack([pose[0], pose[1], jnp.float32(cfg.height)])
    hit = cast(rs, o, d, cfg.max_range)
    valid = hit.dist >= cfg.min_range
    return jnp.where(valid, hit.dist, cfg.max_range), jnp.where(valid, hit.label, NOTHING)


def depth_seg(rs: RayScene, cfg: CameraConfig, pose: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Depth (H, W) along the optical axis (max_range where nothing) and labels (H, W)."""
    _, axis = camera_pose(cfg, pose)
    hit, d, _ = _camera_cast(rs, cfg, pose, cfg.width, cfg.height)
    depth = materialized(jnp.where(hit.label == NOTHING, cfg.max_range, hit.dist * (d @ axis)))
    return depth.reshape(cfg.height, cfg.width), hit.label.reshape(cfg.height, cfg.width)


def rgb(rs: RayScene, cfg: CameraConfig, pose: jax.Array) -> tuple[jax.Array, jax.Array]:
    """RGB image (Hr, Wr, 3) uint8 and labels (Hr, Wr) at the detector's resolution."""
    img, _, label = rgbd(rs, cfg, pose)
    return img, label


def rgbd(rs: RayScene, cfg: CameraConfig, pose: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """RGB (Hr, Wr, 3) uint8, depth (Hr, Wr) along the optical axis (0 where nothing is hit
    in range, as depth cameras report a missing return) and labels (Hr, Wr), from one cast
    at the RGB resolution ``rgb_width`` x ``rgb_height``.

    Lambert shading with a light at the camera plus ambient, a faint floor grid and a
    distance fade, so shapes read as they would in a plain rendered scene.
    """
    o, axis = camera_pose(cfg, pose)
    hit, d, rs = _camera_cast(rs, cfg, pose, cfg.rgb_width, cfg.rgb_height)
    base = jnp.where((hit.box >= 0)[..., None], rs.rgb[jnp.maximum(hit.box, 0)], rs.floor_rgb)
    p = o + hit.dist[..., None] * d
    grid = (jnp.abs(p[..., 0] - jnp.round(p[..., 0])) < 0.01) | (jnp.abs(p[..., 1] - jnp.round(p[..., 1])) < 0.01)
    base = jnp.where(((hit.box < 0) & grid)[..., None], base * 0.85, base)
    lambert = jnp.abs(jnp.sum(hit.normal * d, -1))
    shade = 0.35 + 0.65 * lambert
    fade = 1.0 - 0.25 * hit.dist / cfg.max_range
    color = base * (shade * fade)[..., None]
    sky = jnp.array([0.93, 0.93, 0.95])  # ceiling-less worlds: a flat bright background
    color = jnp.where((hit.label == NOTHING)[..., None], sky, color)
    img = jnp.clip(color * 255.0 + 0.5, 0, 255).astype(jnp.uint8)
    depth = jnp.where(hit.label == NOTHING, 0.0, hit.dist * (d @ axis))
    shape = (cfg.rgb_height, cfg.rgb_width)
    return img.reshape(*shape, 3), depth.reshape(shape), hit.label.reshape(shape)
