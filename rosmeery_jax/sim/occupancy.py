"""The robot's own 2D occupancy grid, built from its laser (log-odds, vmappable).

The grid has the world's free-space map geometry (origin, resolution, H x W): the robot
is told the map's bounds, nothing else. Each beam marks the cells it crosses as more likely
free and its end cell, when the beam returned, as more likely occupied. Cells are read as
UNKNOWN / FREE / OCCUPIED from the log-odds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

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


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class GridGeometry:
    """An H x W grid as data: ``origin`` (2,) float32 world xy of the lower-left corner and
    ``extent`` (2,) int32 the world's own rows and columns. ``shape`` (static) may be larger:
    a session pads every world's grid to its largest, and the rows and columns beyond
    ``extent`` are padding that nothing reads or writes (points clip into the extent)."""

    origin: jax.Array
    extent: jax.Array
    resolution: float = field(metadata=dict(static=True))
    shape: tuple[int, int] = field(metadata=dict(static=True))

    @staticmethod
    def of(fs: FreeSpace, shape: tuple[int, int] | None = None) -> "GridGeometry":
        own = tuple(fs.occupied.shape)
        return GridGeometry(jnp.asarray(fs.origin, jnp.float32), jnp.asarray(own, jnp.int32), float(fs.resolution),
                            tuple(shape or own))

    def coarse(self, f: int) -> "GridGeometry":
        """The grid of f x f blocks (partial blocks at the far edges count)."""
        h, w = self.shape
        return GridGeometry(self.origin, -(-self.extent // f), self.resolution * f, (-(-h // f), -(-w // f)))

    def cell(self, xy: jax.Array) -> tuple[jax.Array, jax.Array]:
        """(row, col) int32 of world points (..., 2), clipped into the world's extent."""
        j = jnp.floor((xy[..., 0] - self.origin[0]) / self.resolution).astype(jnp.int32)
        i = jnp.floor((xy[..., 1] - self.origin[1]) / self.resolution).astype(jnp.int32)
        return jnp.clip(i, 0, self.extent[0] - 1), jnp.clip(j, 0, self.extent[1] - 1)

    def center(self, i: jax.Array, j: jax.Array) -> jax.Array:
        """World xy (..., 2) of cell centres."""
        return jnp.stack([self.origin[0] + (j + 0.5) * self.resolution,
                          self.origin[1] + (i + 0.5) * self.resolution], -1)

    def centers(self) -> jax.Array:
        """(H, W, 2) world xy of every cell centre (padding cells included)."""
        i, j = jnp.meshgrid(jnp.arange(self.shape[0]), jnp.arange(self.shape[1]), indexing="ij")
        return self.center(i, j)

    def inside(self) -> jax.Array:
        """(H, W) bool: the world's own cells (False on padding)."""
        i, j = jnp.meshgrid(jnp.arange(self.shape[0]), jnp.arange(self.shape[1]), indexing="ij")
        return (i < self.extent[0]) & (j < self.extent[1])


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
    inside = in_extent(geo, pts)
    h, w = geo.shape
    drop = h * w  # out of range: scatter mode="drop" ignores it (a negative index would wrap)
    flat = jnp.where(free & inside, i * w + j, drop).ravel()
    lo = logodds.ravel()
    lo = lo.at[flat].add(cfg.miss, mode="drop")
    returned = (labels != NOTHING) & (ranges <= cfg.max_range)
    end = origin_xy + ranges[:, None] * direction
    hi, hj = geo.cell(end)
    hit_idx = jnp.where(returned & in_extent(geo, end), hi * w + hj, drop)
    lo = lo.at[hit_idx].add(cfg.hit, mode="drop")
    return jnp.clip(lo, -cfg.clamp, cfg.clamp).reshape(h, w)


def in_extent(geo: GridGeometry, xy: jax.Array) -> jax.Array:
    """(...,) bool: world points (..., 2) on the world's own cells."""
    r = geo.resolution
    return ((xy[..., 0] >= geo.origin[0]) & (xy[..., 0] < geo.origin[0] + geo.extent[1] * r)
            & (xy[..., 1] >= geo.origin[1]) & (xy[..., 1] < geo.origin[1] + geo.extent[0] * r))


def classify(logodds: jax.Array, cfg: MapConfig) -> jax.Array:
    """(H, W) int8: UNKNOWN, FREE or OCCUPIED."""
    return jnp.where(logodds > cfg.threshold, OCCUPIED, jnp.where(logodds < -cfg.threshold, FREE, UNKNOWN)).astype(jnp.int8)
