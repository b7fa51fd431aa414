"""A session's batch: which env runs which world, policy and seed.

**Worlds are data.** The session's worlds are padded to shared sizes and stacked
(:mod:`rosmeery_jax.env.world_data`); each env gathers its own world inside the compiled
function, so adding a world adds rows, not a compile. A *group* is every entry that shares
one env configuration: all built-in policies share one, so the default and paper sessions
compile one chunk function; replayed recordings run in velocity mode and form a group of
their own.

**Blocks.** XLA compiles a different program for every batch shape, and programs of
different shapes round differently. The batch is therefore cut into blocks of ``BLOCK``
envs, each block one policy and one world (a run's seeds are padded to whole blocks), and
one block program runs them all (:mod:`rosmeery_jax.session.program`): an env's numbers
are the same whatever runs beside it.

Shapes: B envs in a group (a multiple of BLOCK).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import jax
import numpy as np

from rosmeery_jax.env import EnvConfig, RobotEnv, world_bank
from rosmeery_jax.env import world_data as wd
from rosmeery_jax.policies import make_policy, policy_class
from rosmeery_jax.session.schedule import decisions, env_overrides
from rosmeery_jax.world import load_world

BLOCK = 5  # envs per compiled block (module docstring): 5 seeds, the paper's and the default, fill one


class Run(NamedTuple):
    """One (world, policy) pair: its rows in the group's batch (one per seed or recording)."""

    name: str
    world: int
    policy: int
    rows: np.ndarray
    host_policy: Any  # the policy built for this world (recordings, start checks)
    spec: str  # the policy entry, as the config names it
    seeds: range  # one per row: the session's, or a replay's recordings numbered from 0


@dataclass
class Group:
    """Entries that share one env configuration, as one batch of B envs.

    env: the template env (the group's first world at the padded sizes); envs: one per world
    (host side: world, truth); data: the stacked worlds (W, ...); policies: one template per
    policy entry; world / seed / real (B,) per env; blocks (B // BLOCK, 2) the policy and
    world of each block (every run is padded to whole blocks)."""

    config: EnvConfig
    env: RobotEnv
    envs: list[RobotEnv]
    data: wd.WorldData
    policies: list
    world: np.ndarray
    seed: np.ndarray
    real: np.ndarray
    blocks: np.ndarray
    runs: list[Run]
    devices: int = 1

    @property
    def size(self) -> int:
        return len(self.world)


@dataclass
class _Rows:
    """The batch being laid out: per env its world, seed and whether it is real; per block
    its (policy, world)."""

    world: list = field(default_factory=list)
    seed: list = field(default_factory=list)
    real: list = field(default_factory=list)
    blocks: list = field(default_factory=list)

    def add_block_run(self, policy: int, world: int, seeds: range) -> np.ndarray:
        """Rows for one run's ``seeds``, padded to whole blocks; returns the real rows."""
        size = len(seeds)
        rows = np.arange(len(self.world), len(self.world) + size)
        padded = -(-size // BLOCK) * BLOCK
        self.world += [world] * padded
        self.seed += [(seeds.start + i) % 2**31 for i in range(padded)]  # padding continues them (int32 keys)
        self.real += [True] * size + [False] * (padded - size)
        self.blocks += [(policy, world)] * (padded // BLOCK)
        return rows

    def add_padding_block(self) -> None:
        """A copy of the last block with no real env (whole blocks per device)."""
        policy, world = self.blocks[-1]
        self.blocks.append((policy, world))
        self.world += [world] * BLOCK
        self.seed += list(range(BLOCK))
        self.real += [False] * BLOCK


def run_overrides(cfg, world: str, spec: str) -> dict:
    """The EnvConfig overrides of the runs of policy ``spec`` in the world named ``world``:
    the labels the detector implies, the session's noise, localisation and env table, then
    what the policy needs (a replay's recorded settings, velocity commands)."""
    return {"labels": "detections" if cfg.detector != "off" else "observed", **env_overrides(cfg),
            **policy_class(spec).env_overrides(spec, world)}


def build_groups(pairs: list[tuple[str, str]], cfg) -> list[Group]:
    """The groups of (world spec, policy spec) pairs of the session ``cfg`` (a
    SessionConfig); runs with no entries are left out. ``cfg.devices`` 0 uses every device
    JAX has, or one per block when there are fewer blocks; with more than one, padding
    blocks (copies of the last, no real env) make the number of blocks a multiple of it."""
    seeds, decide_every, devices = cfg.seed_range, cfg.decide_every, cfg.devices
    total_steps = decisions(cfg) * decide_every
    by_config: dict[EnvConfig, list] = {}
    for world, spec in pairs:
        config = EnvConfig().with_overrides("config", **run_overrides(cfg, load_world(world).name, spec))
        by_config.setdefault(config, []).append((world, spec))
    groups = [_group(config, members, seeds, decide_every, total_steps, devices) for config, members in by_config.items()]
    return [g for g in groups if g.runs]


def _group(config: EnvConfig, members: list, seeds: range, decide_every: int, total_steps: int,
           devices: int) -> Group:
    """One group: its worlds as one padded bank, its policies, its runs laid out in blocks."""
    specs = list(dict.fromkeys(w for w, _ in members))
    bank = world_bank(specs, config)
    envs = bank.envs()
    policy_specs = list(dict.fromkeys(p for _, p in members))
    policies = [make_policy(p, envs[0], decide_every, total_steps) for p in policy_specs]
    rows, runs = _Rows(), []
    for q, spec in enumerate(policy_specs):
        for world, p in members:
            if p != spec:
                continue
            w = specs.index(world)
            host = make_policy(spec, envs[w], decide_every, total_steps)
            mine = host.seeds(seeds)
            if mine:  # else a replay with no recording in this world
                runs.append(Run(f"{envs[w].world.name}__{policies[q].name}", w, q, rows.add_block_run(q, w, mine),
                                host, spec, mine))
    used = devices or max(1, min(len(jax.devices()), len(rows.blocks)))  # auto: no device without a real block
    for _ in range((-len(rows.blocks)) % used if runs else 0):  # whole blocks per device
        rows.add_padding_block()
    return Group(config, envs[0], envs, bank.data, policies, np.asarray(rows.world, np.int32),
                 np.asarray(rows.seed, np.int32), np.asarray(rows.real), np.asarray(rows.blocks, np.int32), runs, used)

