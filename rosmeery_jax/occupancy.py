"""The robot's own 2D occupancy grid, built from its laser (log-odds, vmappable).

The grid has the world's free-space map geometry (origin, resolution, H x W): the robot
is told the map's bounds, nothing else. Each beam marks the cells it crosses as more likely
free and its end cell, when the beam returned, as more likely occupied. Cells are read as
UNKNOWN / FREE / OCCUPIED from the log-odds.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.world import FreeSpace
from rosmeery_jax.world.scene import NOTHING

UNKNOWN, FREE, OCCUPIED = 0, 1, 2


@dataclass(frozen=True)
class MapConfig:
    """Log-odds occupancy mapping. ``max_range`` limits how far a beam clears space (the
    laser's 15 m would cost 300 cells a beam for little gain indoors)."""

    hit: float = 0.85
    miss: float = -0.4
    clamp: float = 4.0
    threshold: float = 0.6  # |log-odds| above this is decided
    max_range: float = 6.0


@dataclass(frozen=True)
class GridGeometry:
    origin: tuple[float, float]
    resolution: float
    shape: tuple[int, int]

    @staticmethod
    def of(fs: FreeSpace) -> "GridGeometry":
        return GridGeometry((float(fs.origin[0]), float(fs.origin[1])), float(fs.resolution), tuple(fs.occupied.shape))

    def cell(self, xy: jax.Array) -> tuple[jax.Array, jax.Array]:
        """(row, col) int32 of world points (..., 2), clipped into the grid."""
        j = jnp.floor((xy[..., 0] - self.origin[0]) / self.resolution).astype(jnp.int32)
        i = jnp.floor((xy[..., 1] - self.origin[1]) / self.resolution).astype(jnp.int32)
        return jnp.clip(i, 0, self.shape[0] - 1), jnp.clip(j, 0, self.shape[1] - 1)

    def center(self, i: jax.Array, j: jax.Array) -> jax.Array:
        """World xy (..., 2) of cell centres."""
        return jnp.stack([self.origin[0] + (j + 0.5) * self.resolution,
                          self.origin[1] + (i + 0.5) * self.resolution], -1)


def empty_map(geo: GridGeometry) -> jax.Array:
    """(H, W) float32 log-odds, all unknown."""
    return jnp.zeros(geo.shape, jnp.float32)


def update(logodds: jax.Array, geo: GridGeometry, cfg: MapConfig, origin_xy: jax.Array,
           angles: jax.Array, ranges: jax.Array, labels: jax.Array) -> jax.Array:
    """Integrate one scan: beams (K,) at world ``angles`` from ``origin_xy`` (2,)."""
    # One sample per cell length along each beam: scatter-adds dominate the cost on CPU, and
    # a cell a beam only grazes is cleared by the next scan.
    n = int(np.ceil(cfg.max_range / geo.resolution))
    steps = (jnp.arange(n, dtype=jnp.float32) + 0.5) * geo.resolution  # (n,)
    reach = jnp.minimum(ranges, cfg.max_range)
    direction = jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1)  # (K, 2)
    pts = origin_xy + steps[None, :, None] * direction[:, None, :]  # (K, n, 2)
    # Cells strictly before the return are free; stop half a cell short so the hit cell stays hit.
    free = steps[None, :] < (reach[:, None] - 0.5 * geo.resolution)
    i, j = geo.cell(pts)
    inside = _inside(geo, pts)
    h, w = geo.shape
    drop = h * w  # out of range: scatter mode="drop" ignores it (a negative index would wrap)
    flat = jnp.where(free & inside, i * w + j, drop).ravel()
    lo = logodds.ravel()
    lo = lo.at[flat].add(cfg.miss, mode="drop")
    returned = (labels != NOTHING) & (ranges <= cfg.max_range)
    end = origin_xy + ranges[:, None] * direction
    hi, hj = geo.cell(end)
    hit_idx = jnp.where(returned & _inside(geo, end), hi * w + hj, drop)
    lo = lo.at[hit_idx].add(cfg.hit, mode="drop")
    return jnp.clip(lo, -cfg.clamp, cfg.clamp).reshape(h, w)


def _inside(geo: GridGeometry, xy: jax.Array) -> jax.Array:
    x0, y0 = geo.origin
    h, w = geo.shape
    r = geo.resolution
    return (xy[..., 0] >= x0) & (xy[..., 0] < x0 + w * r) & (xy[..., 1] >= y0) & (xy[..., 1] < y0 + h * r)


def classify(logodds: jax.Array, cfg: MapConfig) -> jax.Array:
    """(H, W) int8: UNKNOWN, FREE or OCCUPIED."""
    return jnp.where(logodds > cfg.threshold, OCCUPIED, jnp.where(logodds < -cfg.threshold, FREE, UNKNOWN)).astype(jnp.int8)
