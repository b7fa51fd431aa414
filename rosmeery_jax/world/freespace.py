"""The ground-truth 2D map: occupied cells, the walled interior, and what the robot reaches.

A cell is occupied when a box that reaches below the robot's height covers it (a table top
at 0.75 m does not block a 0.5 m robot; its legs do). The interior is everything the walls
enclose around the spawn; the reachable area is the free space whose clearance exceeds the
robot radius, connected to the spawn.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import ndimage

from rosmeery_jax.world.scene import WALL, Scene


class FreeSpace(NamedTuple):
    """An H x W grid; cell (i, j) has centre origin + ((j + 0.5) res, (i + 0.5) res).

    origin: (2,) world xy of the grid's lower-left corner; resolution: metres per cell.
    occupied / interior / reachable: (H, W) bool. clearance: (H, W) float32, metres to the
    nearest occupied cell.
    """

    origin: np.ndarray
    resolution: float
    occupied: np.ndarray
    interior: np.ndarray
    reachable: np.ndarray
    clearance: np.ndarray

    def cell(self, xy) -> tuple[int, int]:
        """(row, col) of the cell holding world point ``xy``."""
        j, i = np.floor((np.asarray(xy, float) - self.origin) / self.resolution).astype(int)
        return int(i), int(j)

    def contains(self, xy) -> bool:
        i, j = self.cell(xy)
        return 0 <= i < self.occupied.shape[0] and 0 <= j < self.occupied.shape[1]

    @property
    def reachable_area_m2(self) -> float:
        return float(self.reachable.sum()) * self.resolution ** 2

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) for matplotlib's ``imshow(origin='lower')``."""
        h, w = self.occupied.shape
        x0, y0 = self.origin
        return (x0, x0 + w * self.resolution, y0, y0 + h * self.resolution)


def rasterize(scene: Scene, mask: np.ndarray, origin, shape, res: float) -> np.ndarray:
    """(H, W) bool: cells that boxes[mask] overlap (each box grown by half a cell)."""
    h, w = shape
    xs = origin[0] + (np.arange(w) + 0.5) * res
    ys = origin[1] + (np.arange(h) + 0.5) * res
    gx, gy = np.meshgrid(xs, ys)
    pts = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], -1)
    sub = scene.select(mask)
    grown = sub._replace(half=sub.half + np.array([res / 2, res / 2, 0.0]))
    return grown.inside_any(pts, planar=True).reshape(h, w)


def build_free_space(scene: Scene, spawn_xy, robot_radius: float, robot_height: float,
                     resolution: float = 0.05, pad: float = 0.5) -> FreeSpace:
    corners = scene.footprint_corners()[scene.object_id == WALL].reshape(-1, 2)
    if corners.size == 0:
        corners = scene.footprint_corners().reshape(-1, 2)
    lo = np.minimum(corners.min(0), spawn_xy) - pad
    hi = np.maximum(corners.max(0), spawn_xy) + pad
    origin = np.floor(lo / resolution) * resolution
    shape = tuple(np.ceil((hi - origin) / resolution).astype(int)[::-1])
    low = scene.center[:, 2] - scene.half[:, 2] < robot_height
    occupied = rasterize(scene, low, origin, shape, resolution)
    walls = rasterize(scene, scene.object_id == WALL, origin, shape, resolution)
    fs = FreeSpace(origin, resolution, occupied, occupied, occupied, occupied)
    i, j = fs.cell(spawn_xy)
    interior = _component(~walls, i, j)
    if interior[[0, -1], :].any() or interior[:, [0, -1]].any():
        interior = np.ones_like(walls)  # no closed wall ring: nothing is "outside the walls"
    clearance = (ndimage.distance_transform_edt(~occupied) * resolution).astype(np.float32)
    reachable = _component(clearance > robot_radius, i, j)
    return FreeSpace(origin, resolution, occupied, interior, reachable, clearance)


def _component(mask: np.ndarray, i: int, j: int) -> np.ndarray:
    """The 4-connected component of ``mask`` holding cell (i, j) (empty if (i, j) is not set)."""
    labels, _ = ndimage.label(mask)
    return labels == labels[i, j] if mask[i, j] else np.zeros_like(mask)
