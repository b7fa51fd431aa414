"""A world bank: many worlds padded to common sizes and stacked along a world axis, so one
compiled function steps any of them (training on many procedural scenes, sweeps over
held-out ones, a session's worlds).

    bank = world_bank(["procedural:office:0-15"])
    step = rosmeery_jax.jit(jax.vmap(lambda i, s, a: bank.env_at(i).step(s, a)))   # W worlds, one compile

``bank.env_at(i)`` is the env in world ``i`` (``i`` may be traced: inside jit it is a
gather). Indices follow ``bank.names``.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

from rosmeery_jax.core.specs import expand_ranges
from rosmeery_jax.env import world_data as wd
from rosmeery_jax.env.config import EnvConfig, body_dimensions
from rosmeery_jax.env.environment import RobotEnv
from rosmeery_jax.world import World, WorldConfig, load_world


class WorldBank(NamedTuple):
    """names, worlds: (W,); env: world 0's env at the bank's padded sizes (the template);
    data: every world's WorldData stacked (W, ...)."""

    names: tuple[str, ...]
    worlds: tuple[World, ...]
    env: RobotEnv
    data: wd.WorldData

    def __len__(self) -> int:
        return len(self.names)

    def env_at(self, index) -> RobotEnv:
        """The env in world ``index`` (an int or a traced int32 scalar)."""
        return self.env.with_data(wd.pick(self.data, index))

    def envs(self) -> list[RobotEnv]:
        """One host-side env per world at the bank's padded sizes (its world, truth and
        model), for code that needs more than the world's data."""
        return [self.env] + [RobotEnv(w, self.env.config, self.env.sizes) for w in self.worlds[1:]]


def world_bank(names, config: EnvConfig | None = None) -> WorldBank:
    """Load ``names`` (a list of built-in names, paths or ``procedural:KIND:A-B`` ranges)
    into a bank."""
    if isinstance(names, (str, Path)):  # else a name's letters would be read as names
        raise TypeError(f"world_bank: names must be a list of worlds (one world: [{str(names)!r}])")
    if config is not None and not isinstance(config, EnvConfig):
        raise TypeError(f"world_bank: config must be an EnvConfig, not {type(config).__name__}")
    config = config or EnvConfig()
    names = expand_ranges(list(names))
    if not names:
        raise ValueError("a world bank needs at least one world")
    worlds = tuple(load_world(n, body_dimensions(config, WorldConfig())) for n in names)
    sizes = wd.Sizes.union([wd.Sizes.of(w, config) for w in worlds])
    env = RobotEnv(worlds[0], config, sizes)
    data = [env.data] + [wd.world_data(w, config, sizes) for w in worlds[1:]]
    return WorldBank(names, worlds, env, wd.stack(data))

