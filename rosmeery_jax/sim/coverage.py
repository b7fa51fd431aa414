"""Per-object surface coverage: which ground-truth samples the depth camera has observed.

A sample is observed in a frame (docs/metrics.md) when it projects inside the image, lies
within the camera's range, faces the camera, and is not occluded: its depth along the
optical axis is at most the rendered depth at its pixel plus a tolerance

    tol = abs_tol + z * (rel_tol + tan(incidence) / f)

where z is the sample's depth, f the focal length in pixels (so z / f is one pixel's
footprint and tan(incidence) how much a slanted surface's depth changes across it), and
incidence is capped at ``max_incidence``. Coverage accumulates over frames:
``seen |= observed``.

The soft variant (``CoverageConfig.soft``) replaces each test by a sigmoid of its margin
(pixels for the image bounds, metres for range and depth, cosine for facing), multiplies
them into an observation probability p, and accumulates ``seen = 1 - (1 - seen)(1 - p)``:
differentiable in the camera pose and the rendered depth, for gradient-based explorers.
It tends to the hard test as ``temperature`` goes to 0.

Shapes: S samples, N objects, (h, w) the depth image. All functions act on one env; vmap.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.raycast.sensors import CameraConfig, camera_pose

FAR = 1e4  # where padding samples stand: beyond every camera's range


@dataclass(frozen=True)
class CoverageConfig:
    abs_tol: float = 0.02  # m
    rel_tol: float = 0.01  # of depth
    max_incidence: float = np.deg2rad(80.0)  # grazing views beyond this count as this
    min_facing: float = 0.0  # cos(incidence) must exceed this ("faces the camera")
    soft: bool = False
    enabled: bool = True  # False: coverage stays empty (platform-only benchmarks, teleop)
    temperature: float = 0.05  # soft mode: margin scale (in each test's unit, times 20 for pixels)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SampleTable:
    """Ground-truth samples on device, one array per coordinate: points (3, S), normals
    (3, S), object (S,) int32 (sorted), and the object count N (static). (Coordinates first:
    with (S, 3) XLA's CPU loops under vmap ran over 100x slower.)

    Padded to a session's sizes, the extra samples stand far away (never observed) on the
    last object, and the extra objects have no samples."""

    points: jax.Array
    normals: jax.Array
    object: jax.Array
    num_objects: int = field(metadata=dict(static=True))

    @staticmethod
    def of(truth, samples: int | None = None, objects: int | None = None) -> "SampleTable":
        s = truth.samples
        n, pad = int(truth.num_objects), (samples or len(s.object)) - len(s.object)
        objects = objects or n
        points = np.concatenate([np.asarray(s.points, np.float32).T, np.full((3, pad), FAR, np.float32)], 1)
        normals = np.concatenate([np.asarray(s.normals, np.float32).T, np.tile([[0], [0], [1]], pad)], 1)
        obj = np.concatenate([np.asarray(s.object, np.int32), np.full(pad, objects - 1, np.int32)])
        return SampleTable(jnp.asarray(points, jnp.float32), jnp.asarray(normals, jnp.float32),
                           jnp.asarray(obj, jnp.int32), objects)


def _project(table: SampleTable, cam: CameraConfig, pose: jax.Array):
    """Per sample: pixel (u, v) float, depth z along the axis, range, cos(incidence)."""
    origin, axis = camera_pose(cam, pose)
    yaw = pose[2]
    rx, ry, rz = (table.points[i] - origin[i] for i in range(3))  # (S,) each
    dist = jnp.sqrt(rx * rx + ry * ry + rz * rz)
    # Camera frame: x forward (axis), y left, z up (pitch about the camera's y axis).
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    fx = c * rx + s * ry
    ly = -s * rx + c * ry
    cp, sp = np.cos(cam.pitch), np.sin(cam.pitch)
    z = cp * fx - sp * rz  # depth along the optical axis
    up = sp * fx + cp * rz
    f = cam.focal(cam.width)
    zs = jnp.where(z > 1e-6, z, 1e-6)
    u = cam.width / 2 - f * ly / zs
    v = cam.height / 2 - f * up / zs
    n = table.normals
    facing = -(n[0] * rx + n[1] * ry + n[2] * rz) / jnp.maximum(dist, 1e-9)
    return u, v, z, dist, facing


def _tolerance(cfg: CoverageConfig, cam: CameraConfig, z, facing):
    cos_inc = jnp.maximum(facing, np.cos(cfg.max_incidence))
    tan_inc = jnp.sqrt(jnp.maximum(1.0 - cos_inc**2, 0.0)) / cos_inc
    return cfg.abs_tol + z * (cfg.rel_tol + tan_inc / cam.focal(cam.width))


def observed(table: SampleTable, cfg: CoverageConfig, cam: CameraConfig, pose: jax.Array,
             depth: jax.Array) -> jax.Array:
    """(S,) bool: samples observed in this frame. pose (3,), depth (h, w) from ``depth_seg``."""
    u, v, z, dist, facing = _project(table, cam, pose)
    inside = (z > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    in_range = (dist >= cam.min_range) & (dist <= cam.max_range)
    i = jnp.clip(v.astype(jnp.int32), 0, cam.height - 1)
    j = jnp.clip(u.astype(jnp.int32), 0, cam.width - 1)
    rendered = depth[i, j]
    visible = z <= rendered + _tolerance(cfg, cam, z, facing)
    return inside & in_range & (facing > cfg.min_facing) & visible


def observed_soft(table: SampleTable, cfg: CoverageConfig, cam: CameraConfig, pose: jax.Array,
                  depth: jax.Array) -> jax.Array:
    """(S,) float32 in [0, 1]: a differentiable observation probability per sample."""
    u, v, z, dist, facing = _project(table, cam, pose)
    k = cfg.temperature
    sig = jax.nn.sigmoid
    px = 20.0 * k  # pixels
    inside = sig(u / px) * sig((cam.width - u) / px) * sig(v / px) * sig((cam.height - v) / px) * sig(z / k)
    in_range = sig((dist - cam.min_range) / k) * sig((cam.max_range - dist) / k)
    i = jnp.clip(v.astype(jnp.int32), 0, cam.height - 1)
    j = jnp.clip(u.astype(jnp.int32), 0, cam.width - 1)
    rendered = depth[i, j]
    visible = sig((rendered + _tolerance(cfg, cam, z, facing) - z) / k)
    facing_p = sig((facing - cfg.min_facing) / k)
    return inside * in_range * visible * facing_p


def accumulate(seen: jax.Array, table: SampleTable, cfg: CoverageConfig, cam: CameraConfig,
               pose: jax.Array, depth: jax.Array) -> jax.Array:
    """New coverage (S,): bool ``seen | observed`` or, soft, float ``1 - (1-seen)(1-p)``."""
    if not cfg.enabled:
        return seen
    if cfg.soft:
        return 1.0 - (1.0 - seen) * (1.0 - observed_soft(table, cfg, cam, pose, depth))
    return seen | observed(table, cfg, cam, pose, depth)


def empty(table: SampleTable, cfg: CoverageConfig) -> jax.Array:
    """(S,) nothing seen yet."""
    s = table.points.shape[1]
    return jnp.zeros(s, jnp.float32) if cfg.soft else jnp.zeros(s, bool)


def per_object(seen: jax.Array, table: SampleTable) -> jax.Array:
    """(N,) ps_t(n): observed samples per object (float32 sums in soft mode)."""
    dtype = jnp.float32 if seen.dtype != jnp.bool_ else jnp.int32
    return jax.ops.segment_sum(seen.astype(dtype), table.object, table.num_objects, indices_are_sorted=True)
