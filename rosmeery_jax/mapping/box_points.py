"""A box's points, for the perceived mapper (:mod:`rosmeery_jax.mapping.perceived`): of a
frame's depth segments, the box's object and its parts (rule 2), binned into voxels and
coarse cells (rules 3-4). Shapes: k the cloud's points, S segments, V voxels, C cells."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rosmeery_jax.mapping.config import PerceivedConfig
from rosmeery_jax.mapping.voxel_table import cube_keys


class Cloud(NamedTuple):
    """F frames' depth pixels above the floor: valid (F, H, W) which pixels; per point (k,),
    in row-major order: depth, world x, y, z, and its depth segment part; size (S,) each
    segment's points."""

    valid: np.ndarray
    depth: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    part: np.ndarray
    size: np.ndarray


class Boxed(NamedTuple):
    """One box's points in a frame (rules 1-3): keys (V,) their voxels' keys, ascending; cells
    (C,) their coarse cells' keys; points (V, 3) the first point in each voxel; core (K,) the
    coarse cells of the object's own depth segment, by which rule 4 associates the box."""

    keys: np.ndarray
    cells: np.ndarray
    points: np.ndarray
    core: np.ndarray


def box_points(cloud: Cloud, mine: np.ndarray, cfg: PerceivedConfig) -> Boxed:
    """Rule 2 for one box, its points ``mine`` (n,) (indices into the cloud, ascending): of
    the segments with at least ``inside`` of their pixels in the box, the nearest holding
    ``min_share`` of the box's points, unless one holding ``front_share`` stands ``behind``
    nearer; with its parts, those holding ``part_share`` at most ``part_behind`` behind it."""
    n = len(mine)
    part = cloud.part[mine]
    size = np.bincount(part, minlength=len(cloud.size))  # each segment's pixels in the box
    inside = (size > 0) & (size >= cfg.inside * cloud.size)
    fit = inside & (size >= cfg.min_share * n)
    if not fit.any():
        return _boxed(cloud, mine[:0], cfg)
    near = np.full(len(cloud.size), np.inf, cloud.depth.dtype)  # each segment's nearest point in the box
    np.minimum.at(near, part, cloud.depth[mine])  # (an accumulator of another dtype is 18x slower)
    front = inside & (size >= min(cfg.front_share, cfg.min_share) * n)  # the fit, and thin things
    obj = int(np.flatnonzero(fit)[np.argmin(near[fit])])
    if near[obj] > near[front].min() + cfg.behind:  # a thin thing in front: the fit is what shows through it
        return _boxed(cloud, mine[:0], cfg)
    parts = inside & (size >= cfg.part_share * n) & (near >= near[obj]) & (near <= near[obj] + cfg.part_behind)
    parts[obj] = True
    core = mine[part == obj] if parts.sum() > 1 else None  # None: the object's segment alone
    return _boxed(cloud, mine[parts[part]], cfg, core)


def _boxed(cloud: Cloud, take: np.ndarray, cfg: PerceivedConfig, core: np.ndarray | None = None) -> Boxed:
    """A box's points: the cloud's points ``take`` (indices), of which ``core`` (all if
    None) are the object's own segment."""
    keys, cells, points = _voxels(cloud, take, cfg)
    return Boxed(keys, cells, points, cells if core is None else _cells(cloud, core, cfg.cell))


def _voxels(cloud: Cloud, take: np.ndarray, cfg: PerceivedConfig) -> tuple:
    """The distinct voxel keys (V,) ascending of the cloud's points ``take`` (indices), their coarse
    cell keys, and the first of the points in each voxel, (V, 3) (rule 3)."""
    x, y, z = cloud.x[take], cloud.y[take], cloud.z[take]
    keys, first = np.unique(cube_keys((x, y, z), cfg.voxel), return_index=True)
    cells = keys if cfg.cell == cfg.voxel else _cells(cloud, take, cfg.cell)
    return keys, cells, np.stack([x[first], y[first], z[first]], -1)


def _cells(cloud: Cloud, take: np.ndarray, size: float) -> np.ndarray:
    """The distinct coarse cell keys (C,) ascending of the cloud's points ``take`` (indices) (rule 4),
    cells ``size`` on a side."""
    return np.unique(cube_keys((cloud.x[take], cloud.y[take], cloud.z[take]), size))
