"""Reinforcement learning on the benchmark: an env in which one step is one decision.

A gymnax environment (it subclasses ``gymnax.environments.environment.Environment``):
pure ``reset_env`` / ``step_env`` for one env, with gymnax's ``reset(key, params)`` and
``step(key, state, action, params)`` (auto-reset) on top, jit- and vmap-able end to end (no
host round trip per step). ``params`` (:class:`Params`, also ``default_params``) holds the
world bank as data, so one compiled step serves every world of the bank, and gymnax's
``max_steps_in_episode``. gymnax's wrappers and third-party JAX RL libraries (rejax) run on
it unmodified.

- **Episodes.** A reset draws a world from the bank (uniformly, from the key) and a start
  heading; an episode lasts ``episode_s`` simulated seconds. When it ends, ``step`` returns
  ``done`` and the next episode's first observation (auto-reset onto a new world).
- **Actions.** One discrete action per decision: a cell of a G x G *egocentric goal grid*
  (``goal_grid``, ``goal_spacing`` apart, centred on the robot and turned with its
  heading). Action ``a`` is row ``a // G`` (ahead, from -(G//2) to +(G//2) spacings) and
  column ``a % G`` (to the left, likewise). The target faces away from the robot along
  the offset; the centre cell turns the robot round in place. The navigator then drives
  towards the target for ``decide_every`` control steps (0.1 s each).
- **Observation**: one float32 vector (C*C*4 + 4,), :func:`split_obs` gives its two parts
  (:class:`Obs`): ``maps`` (C, C, 4) egocentric crops of the robot's own
  maps, ``crop_resolution`` per cell, centred on the robot, rows ahead and columns to the
  left: occupied, free (explored), observed object surface, and surface of objects the
  robot holds a label for (samples per cell / 10, capped at 1); ``pose`` (4,) cos and sin
  of the heading, whether the navigator gave up on its last target, and the robot's own
  count of observed object samples / 1000. Nothing in it is hidden ground truth: the
  surface channels count only samples the camera has observed. Episode time is left out,
  so a policy trained on short episodes runs unchanged in a session of any length.
- **Reward** per decision: ``reward_scale`` x the increase of ``reward`` ("ori", "cori" or
  "coverage": the observed share of all object samples), minus ``fail_penalty`` when the
  navigator gives up on the target (stuck, unreachable or timed out). The reward is
  computed from ground truth (the metric); the policy never sees it.

Shapes: C crop cells a side, G goal cells a side, W worlds in the bank, S samples, N objects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from gymnax.environments import environment, spaces

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.env import Env, State
from rosmeery_jax.env import world_data as wd
from rosmeery_jax.env.world_bank import WorldBank
from rosmeery_jax.sim import coverage, occupancy
from rosmeery_jax.sim.grid import wrap_angle
from rosmeery_jax.sim.navigation import STUCK, TIMEOUT, UNREACHABLE

REWARDS = ("ori", "cori", "coverage")


@dataclass(frozen=True)
class RLConfig:
    decide_every: int = 10  # control steps per decision (1 s)
    episode_s: float = 60.0  # simulated seconds per episode
    goal_grid: int = 5  # G: actions are the G x G cells of the egocentric goal grid
    goal_spacing: float = 1.0  # m between goal cells
    crop: int = 32  # C: observation crops are C x C cells
    crop_resolution: float = 0.2  # m per crop cell
    reward: str = "ori"
    reward_scale: float = 10.0
    fail_penalty: float = 0.05

    @property
    def actions(self) -> int:
        return self.goal_grid**2

    def horizon(self, dt: float) -> int:
        """Decisions per episode."""
        return max(1, int(round(self.episode_s / (dt * self.decide_every))))


MAX_CROP = 256  # crop cells a side: larger is no egocentric view and would not fit a batch
MAX_GOAL_GRID = 64


def check_rl(rl: RLConfig, source: str, prefix: str = "rl.") -> None:
    """Every RL setting in range; one InputError naming ``source`` and the field."""
    for name, top in (("goal_grid", MAX_GOAL_GRID), ("crop", MAX_CROP), ("decide_every", None)):
        value = getattr(rl, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1 or (top and value > top):
            raise InputError(source, prefix + name, f"{value!r} must be a whole number in [1, {top or 'inf'}]")
    for name in ("episode_s", "goal_spacing", "crop_resolution"):
        value = getattr(rl, name)
        if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise InputError(source, prefix + name, f"{value!r} must be a finite number > 0")
    for name in ("reward_scale", "fail_penalty"):
        value = getattr(rl, name)
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            raise InputError(source, prefix + name, f"{value!r} must be a finite number")
    if rl.reward not in REWARDS:
        raise InputError(source, prefix + "reward", f"{rl.reward!r} is not one of {', '.join(REWARDS)}")


@struct.dataclass
class Params:
    """worlds: the bank's stacked WorldData (W, ...); max_steps_in_episode: decisions per
    episode (gymnax's name)."""

    worlds: wd.WorldData
    max_steps_in_episode: int = struct.field(pytree_node=False, default=60)


class Obs(NamedTuple):
    """The observation's two parts (module docstring)."""

    maps: jax.Array  # (..., C, C, 4) float32
    pose: jax.Array  # (..., 4) float32


def flat_obs(obs: Obs) -> jax.Array:
    """(..., C*C*4 + 4) float32: the observation as the env returns it."""
    lead = obs.pose.shape[:-1]
    return jnp.concatenate([obs.maps.reshape(*lead, -1), obs.pose], -1)


def split_obs(obs: jax.Array, crop: int) -> Obs:
    """The parts of a flat observation (..., C*C*4 + 4), C = ``crop``."""
    lead = obs.shape[:-1]
    return Obs(obs[..., :-4].reshape(*lead, crop, crop, 4), obs[..., -4:])


class RLState(NamedTuple):
    """env: the robot's state; world int32 bank index; t int32 decisions so far; score: the
    reward quantity after the last decision; ret: the episode's return so far."""

    env: State
    world: jax.Array
    t: jax.Array
    score: jax.Array
    ret: jax.Array


class ExplorationEnv(environment.Environment):
    """Exploration as a decision process over a world bank (module docstring). One env:
    vmap ``reset`` / ``step`` over keys for a batch."""

    def __init__(self, bank: WorldBank, config: RLConfig = RLConfig()):
        if config.reward not in REWARDS:
            raise ValueError(f"reward {config.reward!r} is not one of {', '.join(REWARDS)}")
        if bank.env.config.action_mode != "target":
            raise ValueError("the bank's env must use action_mode 'target' (the navigator drives)")
        self.bank, self.config = bank, config
        self.horizon = config.horizon(bank.env.dt)
        self.offsets, self.crop_xy = goal_offsets(config), crop_offsets(config)

    @property
    def name(self) -> str:
        return "rosmeery-exploration"

    @property
    def num_actions(self) -> int:
        return self.config.actions

    @property
    def default_params(self) -> Params:
        return Params(self.bank.data, self.horizon)

    def action_space(self, params: Params | None = None) -> spaces.Discrete:
        return spaces.Discrete(self.config.actions)

    def observation_space(self, params: Params | None = None) -> spaces.Box:
        c = self.config.crop
        return spaces.Box(-1.0, jnp.inf, (c * c * 4 + 4,), jnp.float32)

    def env_in(self, params: Params, world) -> Env:
        return self.bank.env.with_data(wd.pick(params.worlds, world))

    def reset_env(self, key: jax.Array, params: Params) -> tuple[jax.Array, RLState]:
        k_world, k_env = jax.random.split(key)
        world = jax.random.randint(k_world, (), 0, params.worlds.spawn.shape[0])
        env = self.env_in(params, world)
        s = env.reset(k_env)
        state = RLState(s, world, jnp.int32(0), score(env, s, self.config.reward), jnp.float32(0))
        return flat_obs(observe(env, s, self.crop_xy)), state

    def step_env(self, key: jax.Array, state: RLState, action: jax.Array, params: Params):
        """One decision. Returns obs, state, reward, done and info (the finished episode's
        ``return`` and ``score`` when done, else 0; ``world``); gymnax's ``step`` adds the
        auto-reset."""
        cfg = self.config
        env = self.env_in(params, state.world)
        target = goal(state.env.pose, action, self.offsets)
        s = jax.lax.fori_loop(0, cfg.decide_every, lambda _, s: env.step(s, target), state.env)
        new_score = score(env, s, cfg.reward)
        reward = cfg.reward_scale * (new_score - state.score) - cfg.fail_penalty * gave_up(s)
        t = state.t + 1
        done = t >= params.max_steps_in_episode
        stepped = RLState(s, state.world, t, new_score, state.ret + reward)
        info = {"return": jnp.where(done, stepped.ret, 0.0), "score": jnp.where(done, new_score, 0.0),
                "world": state.world}
        return flat_obs(observe(env, s, self.crop_xy)), stepped, reward, done, info


def goal(pose: jax.Array, action: jax.Array, offsets: jax.Array) -> jax.Array:
    """The target pose (3,) of goal-grid cell ``action`` for a robot at ``pose`` (3,):
    offsets (G*G, 2) (ahead, left) in metres; the target faces away from the robot."""
    ahead, left = offsets[action, 0], offsets[action, 1]
    c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
    xy = pose[:2] + jnp.stack([c * ahead - s * left, s * ahead + c * left])
    still = (ahead == 0) & (left == 0)
    yaw = jnp.where(still, pose[2] + jnp.pi, pose[2] + jnp.arctan2(left, ahead))
    return jnp.concatenate([xy, wrap_angle(yaw)[None]])


def score(env: Env, state: State, kind: str) -> jax.Array:
    """The reward quantity (scalar float32) for one env: ORI or cORI over the world's real
    objects (padding objects left out, as the metrics do), or the observed share of all
    object samples."""
    k = env.labelled_knowledge(state)
    ps = coverage.per_object(k.seen, env.sk.table).astype(jnp.float32)
    ps_G = env.sk.ps_G
    real = ps_G < wd.NEVER
    if kind == "coverage":
        return jnp.sum(jnp.where(real, ps, 0.0)) / jnp.sum(jnp.where(real, ps_G, 0.0))
    weighted = ps * k.conf_true if kind == "cori" else ps
    errors = jnp.where(real, jnp.abs(ps_G - weighted) / ps_G, 0.0)
    return 1.0 - jnp.minimum(1.0, jnp.sum(errors) / jnp.maximum(jnp.sum(real), 1))


def gave_up(state: State) -> jax.Array:
    """bool: the navigator gave up on its target (stuck, unreachable or timed out)."""
    s = state.nav.status
    return (s == STUCK) | (s == UNREACHABLE) | (s == TIMEOUT)


def crop_offsets(cfg: RLConfig) -> jax.Array:
    """(C, C, 2) (ahead, left) in metres of the crop cells' centres in the robot's frame."""
    c = cfg.crop
    along = (np.arange(c) - c / 2 + 0.5) * cfg.crop_resolution
    ahead, left = np.meshgrid(along, along, indexing="ij")
    return jnp.asarray(np.stack([ahead, left], -1), jnp.float32)


def goal_offsets(cfg: RLConfig) -> jax.Array:
    """(G*G, 2) (ahead, left) in metres of the goal cells (module docstring)."""
    g = cfg.goal_grid
    rows, cols = np.divmod(np.arange(g * g), g)
    return jnp.asarray(np.stack([rows - g // 2, cols - g // 2], -1) * cfg.goal_spacing, jnp.float32)


def observe(env: Env, state: State, crop_xy: jax.Array) -> Obs:
    """The observation (module docstring) from the robot's own maps; crop_xy (C, C, 2)
    from :func:`crop_offsets`."""
    pose = state.pose
    c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
    xy = pose[:2] + jnp.stack([c * crop_xy[..., 0] - s * crop_xy[..., 1],
                               s * crop_xy[..., 0] + c * crop_xy[..., 1]], -1)  # (C, C, 2) world
    i, j = env.grid.cell(xy)
    inside = occupancy.in_extent(env.grid, xy)
    occ = env.occupancy(state)[i, j]
    k = env.labelled_knowledge(state)
    surface, labelled = surface_maps(env, k)
    layers = [occ == occupancy.OCCUPIED, occ == occupancy.FREE, surface[i, j], labelled[i, j]]
    maps = jnp.stack([jnp.where(inside, a.astype(jnp.float32), 0.0) for a in layers], -1)
    observed = jnp.sum(k.seen.astype(jnp.float32)) / 1000.0
    feats = jnp.stack([c, s, gave_up(state).astype(jnp.float32), observed])
    return Obs(maps, feats)


def surface_maps(env: Env, k) -> tuple[jax.Array, jax.Array]:
    """(H, W) each on the robot's grid, from its labelled knowledge ``k``: observed object
    samples per cell, and those of objects it holds a label for, divided by 10 and capped
    at 1. Only observed samples count (a sample's position is what the depth camera
    measured)."""
    table = env.sk.table
    seen = k.seen.astype(jnp.float32)
    held = seen * (k.label >= 0)[table.object]
    i, j = env.grid.cell(jnp.stack([table.points[0], table.points[1]], -1))
    h, w = env.grid.shape
    flat = i * w + j
    count = jax.ops.segment_sum(jnp.stack([seen, held], -1), flat, h * w)  # (H*W, 2)
    count = jnp.minimum(count / 10.0, 1.0).reshape(h, w, 2)
    return count[..., 0], count[..., 1]
