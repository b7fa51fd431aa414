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
- **Observation**: one float32 vector ((K+1) * F + G,), :func:`.task.split_obs` gives its parts:
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

from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import struct
from gymnax.environments import environment, spaces

from rosmeery_jax.env import RobotEnv, State
from rosmeery_jax.env import world_data as wd
from rosmeery_jax.env.decision import Decision, decide
from rosmeery_jax.env.world_bank import WorldBank
from rosmeery_jax.rl.candidates import Offer, driving, gave_up, offer
from rosmeery_jax.rl.task import RLConfig, check_rl, flat_obs, score


@struct.dataclass
class Params:
    """worlds: the bank's stacked WorldData (W, ...); max_steps_in_episode: control steps
    per episode (gymnax's name)."""

    worlds: wd.WorldData
    max_steps_in_episode: int = struct.field(pytree_node=False, default=1200)


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
        for arg, kind, what in ((bank, WorldBank, "a WorldBank (world_bank(names))"),
                                (config, RLConfig, "an RLConfig")):
            if not isinstance(arg, kind):
                raise TypeError(f"ExplorationEnv takes {what}, not {type(arg).__name__}")
        check_rl(config, "ExplorationEnv", "config.")  # an InputError, a ValueError
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

    def env_in(self, params: Params, world) -> RobotEnv:
        return self.bank.env.with_data(wd.pick(params.worlds, world))

    def offer(self, env: RobotEnv, s: State, key: jax.Array) -> Offer:
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

        s, out = decide(env, state.env, target, Decision(cfg.decide_every),
                        until=lambda i, s: (s.t < end) & ((i == 0) | driving(s)))
        steps = out.steps
        new_score = score(env, s, cfg.reward)
        reward = cfg.reward_scale * (new_score - state.score) - cfg.fail_penalty * gave_up(s)
        done = s.t >= end
        o = self.offer(env, s, key)
        stepped = RLState(s, state.world, o.targets, new_score, state.ret + reward)
        info = {"return": jnp.where(done, stepped.ret, 0.0), "score": jnp.where(done, new_score, 0.0),
                "world": state.world, "steps": steps}
        return flat_obs(o), stepped, reward, done, info
