"""Reinforcement learning on the benchmark: an env in which one step is one decision.

A gymnax environment (it subclasses ``gymnax.environments.environment.Environment``):
pure ``reset_env`` / ``step_env`` for one env, with gymnax's ``reset(key, params)`` and
``step(key, state, action, params)`` (auto-reset) on top, jit- and vmap-able end to end (no
host round trip per step). ``params`` (:class:`Params`, also ``default_params``) holds the
world bank as data, so one compiled step serves every world of the bank, and gymnax's
``max_steps_in_episode`` (control steps). gymnax's wrappers and third-party JAX RL
libraries (rejax) run on it unmodified.

- **Episodes.** A reset draws a world from the bank (uniformly, from the key) and a start
  heading; an episode lasts ``episode_s`` simulated seconds. When it ends, ``step`` returns
  ``done`` and the next episode's first observation (auto-reset onto a new world).
- **Actions.** One discrete action per decision: one of the K + 1 candidate targets of
  :mod:`.candidates` (action 0 keeps the current target; 1..K are drawn over the cells the
  robot can reach on its own map). The navigator then drives to it until it is done with
  it (reached, or gave up) or ``decide_every`` control steps (0.1 s each) have passed,
  whichever comes first: a decision lasts as long as the drive, as a baseline's target
  does, so the robot never waits for the policy. In a batch the envs whose decision ended
  wait (their state is left as it is) until the longest one's ends.
- **Observation**: one float32 vector ((K+1) * F + G,), :func:`split_obs` gives its parts:
  the candidates' features (K+1, F) and the robot's (G,) (:mod:`.candidates`). Nothing in
  it is hidden ground truth. Episode time is left out, so a policy trained on short
  episodes runs unchanged in a session of any length.
- **Reward** per decision: ``reward_scale`` x the increase of ``reward`` ("ori", "cori" or
  "coverage": the observed share of all object samples), minus ``fail_penalty`` when the
  navigator gives up on the target (stuck, unreachable or timed out). The reward is
  computed from ground truth (the metric); the policy never sees it.

Shapes: K candidates, F features per candidate, G robot features, W worlds in the bank,
S samples, N objects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import struct
from gymnax.environments import environment, spaces

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.env import Env, State
from rosmeery_jax.env import world_data as wd
from rosmeery_jax.env.world_bank import WorldBank
from rosmeery_jax.rl.candidates import FEATURES, GLOBALS, Offer, driving, gave_up, offer
from rosmeery_jax.sim import coverage

REWARDS = ("ori", "cori", "coverage")
MAX_CANDIDATES = 256  # K: more would not fit a batch's observations


@dataclass(frozen=True)
class RLConfig:
    decide_every: int = 30  # at most this many control steps per decision (3 s)
    episode_s: float = 120.0  # simulated seconds per episode
    candidates: int = 16  # K: new candidate targets per decision (actions: K + 1, 0 keeps the target)
    radius: float = 1.5  # m: half the side of the window a candidate's features describe
    reward: str = "ori"
    reward_scale: float = 10.0
    fail_penalty: float = 0.05

    @property
    def actions(self) -> int:
        return self.candidates + 1

    @property
    def obs_size(self) -> int:
        return self.actions * len(FEATURES) + len(GLOBALS)

    def horizon(self, dt: float) -> int:
        """Control steps per episode."""
        return max(1, int(round(self.episode_s / dt)))


def check_rl(rl: RLConfig, source: str, prefix: str = "rl.") -> None:
    """Every RL setting in range; one InputError naming ``source`` and the field."""
    for name, top in (("candidates", MAX_CANDIDATES), ("decide_every", None)):
        value = getattr(rl, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1 or (top and value > top):
            raise InputError(source, prefix + name, f"{value!r} must be a whole number in [1, {top or 'inf'}]")
    for name in ("episode_s", "radius"):
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
    """worlds: the bank's stacked WorldData (W, ...); max_steps_in_episode: control steps
    per episode (gymnax's name)."""

    worlds: wd.WorldData
    max_steps_in_episode: int = struct.field(pytree_node=False, default=1200)


class Obs(NamedTuple):
    """The observation's two parts (module docstring)."""

    candidates: jax.Array  # (..., K+1, F) float32
    robot: jax.Array  # (..., G) float32


def flat_obs(o: Offer) -> jax.Array:
    """(..., (K+1) * F + G) float32: an offer's observation as the env returns it."""
    lead = o.globals.shape[:-1]
    return jnp.concatenate([o.features.reshape(*lead, -1), o.globals], -1).astype(jnp.float32)


def split_obs(obs: jax.Array) -> Obs:
    """The parts of a flat observation (..., (K+1) * F + G)."""
    lead, g, f = obs.shape[:-1], len(GLOBALS), len(FEATURES)
    return Obs(obs[..., :-g].reshape(*lead, -1, f), obs[..., -g:])


class RLState(NamedTuple):
    """env: the robot's state (``env.t`` counts the episode's control steps); world int32
    bank index; targets (K+1, 3) the candidates on offer; score: the reward quantity after
    the last decision; ret: the episode's return so far."""

    env: State
    world: jax.Array
    targets: jax.Array
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
        return spaces.Box(-1.0, jnp.inf, (self.config.obs_size,), jnp.float32)

    def env_in(self, params: Params, world) -> Env:
        return self.bank.env.with_data(wd.pick(params.worlds, world))

    def offer(self, env: Env, s: State, key: jax.Array) -> Offer:
        return offer(env, s, s.nav.target, key, self.config.candidates, self.config.radius)

    def reset_env(self, key: jax.Array, params: Params) -> tuple[jax.Array, RLState]:
        k_world, k_env, k_offer = jax.random.split(key, 3)
        world = jax.random.randint(k_world, (), 0, params.worlds.spawn.shape[0])
        env = self.env_in(params, world)
        s = env.reset(k_env)
        o = self.offer(env, s, k_offer)
        state = RLState(s, world, o.targets, score(env, s, self.config.reward), jnp.float32(0))
        return flat_obs(o), state

    def step_env(self, key: jax.Array, state: RLState, action: jax.Array, params: Params):
        """One decision. Returns obs, state, reward, done and info (the finished episode's
        ``return`` and ``score`` when done, else 0; ``world``; ``steps``: control steps the
        decision took); gymnax's ``step`` adds the auto-reset."""
        cfg, end = self.config, params.max_steps_in_episode
        env = self.env_in(params, state.world)
        target = state.targets[action]

        def more(carry):
            i, s = carry
            return (i < cfg.decide_every) & (s.t < end) & ((i == 0) | driving(s))

        steps, s = jax.lax.while_loop(more, lambda c: (c[0] + 1, env.step(c[1], target)), (jnp.int32(0), state.env))
        new_score = score(env, s, cfg.reward)
        reward = cfg.reward_scale * (new_score - state.score) - cfg.fail_penalty * gave_up(s)
        done = s.t >= end
        o = self.offer(env, s, key)
        stepped = RLState(s, state.world, o.targets, new_score, state.ret + reward)
        info = {"return": jnp.where(done, stepped.ret, 0.0), "score": jnp.where(done, new_score, 0.0),
                "world": state.world, "steps": steps}
        return flat_obs(o), stepped, reward, done, info


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
