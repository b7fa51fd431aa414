"""The environment layer: one robot in one world as a pure ``reset`` / ``step`` over a
:class:`State` pytree, its configuration, and worlds as padded data (one compiled function
serves many worlds)."""

from rosmeery_jax.env.config import EnvConfig, body_dimensions
from rosmeery_jax.env.environment import RobotEnv, State, Track, make
from rosmeery_jax.env.world_bank import WorldBank, world_bank
from rosmeery_jax.env.world_data import Sizes, WorldData

__all__ = ["RobotEnv", "EnvConfig", "State", "Track", "make", "body_dimensions", "WorldBank", "world_bank", "Sizes", "WorldData"]
