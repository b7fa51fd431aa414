"""Worlds: MJCF files with semantics, loaded into an immutable :class:`World` (SK-GP)."""

from rosmeery_jax.world.freespace import FreeSpace
from rosmeery_jax.world.load import (
    PAPER_WORLDS,
    WORLDS_DIR,
    GroundTruth,
    World,
    WorldConfig,
    load_world,
    resolve_world_path,
    world_names,
)
from rosmeery_jax.world.scene import FLOOR, NOTHING, WALL, Scene
from rosmeery_jax.world.surface import SurfaceSamples

__all__ = [
    "FLOOR", "NOTHING", "PAPER_WORLDS", "WALL", "WORLDS_DIR", "FreeSpace", "GroundTruth",
    "Scene", "SurfaceSamples", "World", "WorldConfig", "load_world", "resolve_world_path",
    "world_names",
]
