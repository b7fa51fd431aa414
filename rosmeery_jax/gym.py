"""Gymnasium interface: any Python agent (numpy, PyTorch, Stable-Baselines3) drives the robots.

``VectorEnv(worlds, num_envs)`` is a ``gymnasium.vector.VectorEnv`` of B robots stepping the
batched engine in one compiled call; ``Env(world)`` a ``gymnasium.Env`` for one robot.
Robot i lives in ``worlds[i % len(worlds)]``; every world compiles into one function
(a world bank).

- **One step is one decision**: the agent's action holds for ``decide_every`` control
  steps (0.1 s each), as in sessions.
- **Action** (``action_mode``): ``"target"`` (default, the paper's interface) the next target
  pose x, y, yaw in the world frame, which the robot's navigator drives to; ``"velocity"``
  the command (v m/s, w rad/s) held for the decision.
- **Observation** (a Dict), what the robot perceives and nothing else: ``rgb`` (H, W, 3) uint8
  and ``depth`` (H, W) float32 metres along the optical axis (0: no return) at the camera's
  ``rgb_width`` x ``rgb_height`` (``env`` overrides set them), ``scan`` (beams,) laser
  ranges, ``pose`` (3,) odometry x, y, yaw (the simulated odometry is exact), ``occupancy``
  (Hg, Wg) int8 the robot's own map (-1 unknown, 0 free, 1 occupied; cells past the
  world's extent stay unknown), ``nav_status`` (1,) int8 its navigator's status (the
  codes of :mod:`rosmeery_jax.sim.navigation`: idle, moving, reached, stuck, unreachable,
  timed out), ``time`` (1,) seconds. ``privileged=True`` adds
  ``privileged_coverage`` (N,): each object's observed share of its surface, ground truth
  for debugging only.
- **Reward**: the increase of ``reward`` ("ori", default, as in :mod:`rosmeery_jax.rl`;
  "cori"; "coverage") over the decision, from ground truth the agent never sees.
- **Seeds**: ``reset(seed=s)`` starts robot i as a session starts seed ``s + i``.
- **Episodes** end at ``duration`` simulated seconds (``truncated``; nothing terminates
  earlier). The vector env resets a finished robot on the next ``step`` (Gymnasium's
  next-step autoreset).
- **Maps**: an agent that maps for itself hands its map to :meth:`VectorEnv.submit_map` at
  any step; it is scored like a ``--mapper`` (:mod:`rosmeery_jax.mapping.protocol`) and the
  metrics come back in a dict.

- **Agents in sessions**: a subclass of :class:`Agent` named ``agent:FILE.py:Name`` in a
  session's policies runs through this vector env, one robot per seed, with the
  session's results files and plots (``rosmeery_jax.session.agents``).

Shapes: B robots, H x W camera pixels, Hg x Wg occupancy cells, N objects.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from rosmeery_jax import metrics
from rosmeery_jax.core import overrides, plugins, specs, xla
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.specs import MAX_SEED
from rosmeery_jax.core.xla import MEMORY_SHARE, memory_bytes
from rosmeery_jax.env import EnvConfig
from rosmeery_jax.env import world_data as wd
from rosmeery_jax.env.config import env_bytes
from rosmeery_jax.env.decision import Decision, decide
from rosmeery_jax.env.world_bank import world_bank
from rosmeery_jax.mapping.protocol import MapState, OnlineScorer, check_map
from rosmeery_jax.metrics.map_score import TOLERANCE
from rosmeery_jax.rl.task import REWARDS, score
from rosmeery_jax.sim import coverage, occupancy
from rosmeery_jax.sim.knowledge import GroundTruthTable


@dataclass(frozen=True)
class GymConfig:
    duration: float = 300.0  # simulated seconds per episode
    decide_every: int = 10  # control steps per decision (1 s)
    action_mode: str = "target"  # or "velocity"
    reward: str = "ori"
    privileged: bool = False
    camera: bool = True  # rgb and depth in the observation: the costliest part of a step on a
    # CPU (a 160 x 128 frame per robot per decision); an agent that does not look sets False
    env: dict = field(default_factory=dict)  # EnvConfig overrides, as in sessions


class VectorEnv(gymnasium.vector.VectorEnv):
    """B robots in one batch (module docstring)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, worlds: list[str] | str, num_envs: int = 1, config: GymConfig = GymConfig(),
                 log_every: int = 0):
        """``log_every`` > 0 also keeps each robot's object log every ``log_every`` control
        steps and its pose and navigation status at every step (``last_logs`` (B, spans, N),
        ``last_track`` an ``env.Track`` of (B, decide_every, ...)), as sessions record them."""
        worlds = [worlds] if isinstance(worlds, str) else list(worlds)
        overrides.check_fields(config, "GymConfig")
        if isinstance(num_envs, bool) or not isinstance(num_envs, int):
            raise ValueError(f"num_envs {num_envs!r} must be a whole number")
        if config.action_mode not in ("target", "velocity"):
            raise ValueError(f"action_mode {config.action_mode!r} is not 'target' or 'velocity'")
        if config.reward not in REWARDS:
            raise ValueError(f"reward {config.reward!r} is not one of {', '.join(REWARDS)}")
        if not 0 < config.duration < math.inf or config.decide_every < 1 or num_envs < 1:
            raise ValueError("duration must be a finite number > 0 s, decide_every and num_envs at least 1")
        env_cfg = EnvConfig().with_overrides("gym", **overrides.flatten({**config.env,
                                                                         "action_mode": config.action_mode}))
        period = env_cfg.robot.control_dt * config.decide_every
        self.horizon = int(round(config.duration / period))  # decisions per episode
        if self.horizon < 1 or abs(self.horizon * period - config.duration) > 1e-6:
            raise ValueError(f"duration {config.duration:g} s is not a whole number of decisions ({period:g} s each)")
        _check_size(num_envs, env_cfg, config.camera)
        self.bank = world_bank(worlds, env_cfg)
        self.config, self.num_envs, self.log_every = config, num_envs, log_every
        if log_every and config.decide_every % log_every:
            raise ValueError(f"log_every {log_every} must divide decide_every {config.decide_every}")
        self.world = np.arange(num_envs) % len(self.bank)
        self.single_observation_space = self._observation_space()
        self.single_action_space = self._action_space()
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._decision = Decision(config.decide_every, log_every, bool(log_every))
        self._reset = xla.jit(jax.vmap(self._reset_one))
        self._step = xla.jit(jax.vmap(self._step_one))
        self._place = xla.jit(jax.vmap(self._place_one))
        self._log = xla.jit(jax.vmap(lambda w, s: self.bank.env_at(w).log(s)))
        self._knowledge = xla.jit(jax.vmap(lambda w, s: self.bank.env_at(w).labelled_knowledge(s)))
        self._scorers = [OnlineScorer(self.bank.worlds[w], TOLERANCE) for w in self.world]
        self.state, self.t, self._done = None, 0, np.zeros(num_envs, bool)

    # -- spaces ---------------------------------------------------------------------------
    def _observation_space(self) -> spaces.Dict:
        env = self.bank.env
        cam, beams = env.config.camera, env.config.laser.beams
        hw = (cam.rgb_height, cam.rgb_width)
        parts = {
            "rgb": spaces.Box(0, 255, (*hw, 3), np.uint8),
            "depth": spaces.Box(0.0, cam.max_range, hw, np.float32),
        } if self.config.camera else {}
        parts |= {
            "scan": spaces.Box(0.0, np.inf, (beams,), np.float32),
            "pose": spaces.Box(-np.inf, np.inf, (3,), np.float32),
            "occupancy": spaces.Box(-1, 1, env.grid.shape, np.int8),
            "nav_status": spaces.Box(0, 127, (1,), np.int8),
            "time": spaces.Box(0.0, np.inf, (1,), np.float32),
        }
        if self.config.privileged:
            parts["privileged_coverage"] = spaces.Box(0.0, 1.0, (env.sizes.objects,), np.float32)
        return spaces.Dict(parts)

    def _action_space(self) -> spaces.Box:
        if self.config.action_mode == "velocity":
            r = self.bank.env.config.robot
            return spaces.Box(np.float32([-r.max_speed, -r.max_turn_rate]), np.float32([r.max_speed, r.max_turn_rate]))
        lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
        for env in self.bank.envs():  # the worlds' extents together
            origin = np.asarray(env.grid.origin, np.float64)
            lo = np.minimum(lo, origin)
            hi = np.maximum(hi, origin + np.asarray(env.grid.extent)[::-1] * env.grid.resolution)
        return spaces.Box(np.float32([*lo, -np.pi]), np.float32([*hi, np.pi]))

    # -- one robot, jitted and vmapped above ------------------------------------------------
    def _reset_one(self, world, key):
        env = self.bank.env_at(world)
        s = env.reset(key)
        return s, self._observe(env, s, jnp.int32(0)), score(env, s, self.config.reward)

    def _step_one(self, world, s, action, t):
        env = self.bank.env_at(world)
        s, out = decide(env, s, action, self._decision)
        kept = (out.logs, out.track) if self.log_every else None
        return s, self._observe(env, s, t), score(env, s, self.config.reward), kept

    def _place_one(self, world, s, pose, t):
        env = self.bank.env_at(world)
        s = env.place(s, pose)
        return s, self._observe(env, s, t)

    def _observe(self, env, s, t) -> dict:
        obs = {}
        if self.config.camera:
            rgb, depth, _ = env.camera_rgbd(s)
            obs = {"rgb": rgb, "depth": depth.astype(jnp.float32)}
        occ = env.occupancy(s)
        grid = jnp.where(occ == occupancy.OCCUPIED, 1, jnp.where(occ == occupancy.FREE, 0, -1)).astype(jnp.int8)
        obs |= {"scan": s.ranges.astype(jnp.float32),
               "pose": s.pose.astype(jnp.float32), "occupancy": grid,
               "nav_status": s.nav.status.astype(jnp.int8)[None],
               "time": (t * self.config.decide_every * env.dt)[None].astype(jnp.float32)}
        if self.config.privileged:
            ps = coverage.per_object(s.knowledge.seen, env.sk.table).astype(jnp.float32)
            real = env.sk.ps_G < wd.NEVER
            obs["privileged_coverage"] = jnp.where(real, ps / jnp.where(real, env.sk.ps_G, 1.0), 0.0)
        return obs

    # -- Gymnasium API ------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """All robots anew; robot i's key is ``seed`` folded with i (the same seed, the same
        episodes)."""
        _check_options(options)
        super().reset(seed=seed)
        top = MAX_SEED + 1 - self.num_envs  # robot i's seed is base + i, as a session's seeds
        base = int(self.np_random.integers(top + 1)) if seed is None else seed
        if base > top:
            raise ValueError(f"seed {base} must be at most 2**31 - num_envs ({top})")
        # robot i as a session's seed base + i (its env key: the seed's key folded with 0)
        self._keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(i), 0))(base + jnp.arange(self.num_envs))
        self._episode = 0
        return self._start(self._keys), {}

    def _start(self, keys) -> dict:
        self.state, obs, self._score = self._reset(jnp.asarray(self.world), keys)
        self.t, self._done[:] = 0, False
        self._scorers = [OnlineScorer(self.bank.worlds[w], TOLERANCE) for w in self.world]
        return _host(obs)

    def step(self, actions):
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        actions = jnp.asarray(_checked(actions, self.action_space.shape, "actions"))  # on a reset step too
        if self._done.any():  # next-step autoreset: every robot finished (one horizon), all start again
            self._episode += 1
            obs = self._start(jax.vmap(jax.random.fold_in, in_axes=(0, None))(self._keys, self._episode))
            zeros = np.zeros(self.num_envs)
            return obs, zeros, zeros.astype(bool), zeros.astype(bool), {}
        self.t += 1
        self.state, obs, new, recorded = self._step(jnp.asarray(self.world), self.state, actions,
                                                    jnp.full(self.num_envs, self.t, jnp.int32))
        if recorded is not None:
            self.last_logs, self.last_track = recorded
        reward = np.asarray(new - self._score, np.float64)
        self._score = new
        truncated = np.full(self.num_envs, self.t >= self.horizon)
        self._done = truncated.copy()
        return _host(obs), reward, np.zeros(self.num_envs, bool), truncated, {}

    # -- a task phase after the episode (a session's task "objectnav", session.agents) ----
    def place(self, poses) -> dict:
        """Put the B robots at ``poses`` (B, 3), each its estimate there too, navigator idle,
        map and knowledge kept (``RobotEnv.place``); their observations."""
        if self.state is None:
            raise RuntimeError("call reset() before place()")
        poses = jnp.asarray(_checked(poses, (self.num_envs, 3), "poses"))
        self.state, obs = self._place(jnp.asarray(self.world), self.state, poses,
                                      jnp.full(self.num_envs, self.t, jnp.int32))
        return _host(obs)

    def advance(self, actions) -> dict:
        """One decision of the B robots outside the episode's clock (no reward, never
        truncated); their observations. With ``log_every``, ``last_track`` holds its steps."""
        if self.state is None:
            raise RuntimeError("call reset() before advance()")
        actions = jnp.asarray(_checked(actions, self.action_space.shape, "actions"))
        self.state, obs, _, recorded = self._step(jnp.asarray(self.world), self.state, actions,
                                                  jnp.full(self.num_envs, self.t, jnp.int32))
        if recorded is not None:
            self.last_logs, self.last_track = recorded
        return _host(obs)

    def submit_map(self, i: int, m: MapState) -> dict:
        """Score robot ``i``'s own map now: {metric: value} (the session's default metrics)."""
        if not 0 <= i < self.num_envs:
            raise ValueError(f"robot {i}: there are {self.num_envs} (0 to {self.num_envs - 1})")
        world = self.bank.worlds[self.world[i]]
        m = check_map("the map", m, len(world.taxonomy.names), ("submit_map", f"robot {i}"))
        log = self._scorers[i].score(m).log
        t = world.truth
        table = GroundTruthTable(np.asarray(t.ps_G), np.asarray(t.num_predicates), np.asarray(t.category_index))
        curves = metrics.compute(type(log)(*(np.asarray(a)[None] for a in log)), table)
        return {k: float(np.asarray(v)[0]) for k, v in curves.items()}

    def log(self):
        """The robots' object logs now: ObjectLog with (B, N) fields."""
        return self._log(jnp.asarray(self.world), self.state)

    def knowledge(self):
        """The robots' labelled knowledge now (batched), for the session's oracle map."""
        return self._knowledge(jnp.asarray(self.world), self.state)

    def poses(self) -> np.ndarray:
        """(B, 3) the robots' poses now."""
        return np.asarray(self.state.pose)


def _check_options(options) -> None:
    """``reset``'s options: None or a dict (the envs read none of them)."""
    if options is not None and not isinstance(options, dict):
        raise TypeError(f"reset: options must be a dict or None, not {type(options).__name__}")


def _check_size(num_envs: int, env: EnvConfig, camera: bool) -> None:
    """Refuse, before anything is allocated, robots that would not fit in this machine's
    memory (their state, a step's camera work and the observations handed out)."""
    cam = env.camera
    frame = (cam.rgb_width * cam.rgb_height * 8 if camera else 0) + cam.width * cam.height * 8  # rgb, depth; seg
    need = num_envs * (env_bytes(env) + 2 * frame)  # on the device and the host's copy
    have = MEMORY_SHARE * memory_bytes()
    if need > have:
        raise ValueError(f"num_envs {num_envs:,}: that many robots need about {need / 1e9:,.1f} GB, more than "
                         f"this machine's {have / 1e9:.1f} GB allows")


def _checked(actions, shape: tuple, what: str) -> np.ndarray:
    """``actions`` as float32 of ``shape``, every value finite, or a ValueError."""
    actions = np.asarray(actions, np.float32)
    if actions.shape != shape or not np.isfinite(actions).all():
        raise ValueError(f"{what} of shape {actions.shape} must be finite numbers of shape {shape}")
    return actions


class Env(gymnasium.Env):
    """One robot (module docstring): a :class:`VectorEnv` of one, unbatched."""

    metadata = {"render_modes": []}

    def __init__(self, world: str = "small_office", config: GymConfig = GymConfig()):
        self.vec = VectorEnv([world], 1, config)
        self.observation_space = self.vec.single_observation_space
        self.action_space = self.vec.single_action_space

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        _check_options(options)
        super().reset(seed=seed)
        obs, info = self.vec.reset(seed=seed if seed is not None else int(self.np_random.integers(MAX_SEED + 1)))
        return _first(obs), info

    def step(self, action):
        if self.vec.state is not None and self.vec._done.any():  # Gymnasium: an episode that ended needs a reset
            raise RuntimeError("Env.step after the episode was truncated: call reset() first")
        action = _checked(action, self.action_space.shape, "an action")
        obs, reward, terminated, truncated, info = self.vec.step(action[None])
        return _first(obs), float(reward[0]), bool(terminated[0]), bool(truncated[0]), info

    def submit_map(self, m: MapState) -> dict:
        return self.vec.submit_map(0, m)


class Agent(ABC):
    """A host-side agent (numpy, PyTorch, anything): give ``name`` (a plain name, its
    results' label) and implement :meth:`act`. Built once per run with the
    :class:`VectorEnv` of its robots (one per seed)."""

    name = "agent"
    camera = True  # False: no rgb and depth in its observations (much faster on a CPU)

    def __init__(self, env: VectorEnv):
        self.env = env

    @abstractmethod
    def act(self, obs: dict) -> np.ndarray:
        """The B robots' next actions (B, 3) target poses (or (B, 2) velocities) from their
        observations (each (B, ...))."""

    def seek(self, obs: dict, goal: str) -> tuple[np.ndarray, np.ndarray]:
        """A session's task phase (task "objectnav", docs/tasks.md): the B robots' actions
        (as :meth:`act`'s) toward an object of category ``goal``, and ``stop`` (B,) bool:
        True ends a robot's episode where it stands, judged there. Called once per
        decision; an agent that does not override it has no task phase."""
        raise NotImplementedError


def agent_class(spec: str, source: str = "config") -> type[Agent]:
    """The class an ``agent:FILE.py:Name`` entry names, checked as a class."""
    cls = plugins.load(specs.parse(spec).body, source, "policies")
    if not (isinstance(cls, type) and issubclass(cls, Agent)):
        raise InputError(source, "policies", f"{spec!r} is not an Agent class (subclass rosmeery_jax.gym.Agent "
                         "and implement act)")
    if getattr(cls.act, "__isabstractmethod__", False):
        raise InputError(source, "policies", f"{spec!r} lacks an act(obs) method")
    if cls.name == Agent.name or not specs.label_name(cls.name):
        raise InputError(source, "policies", f"{spec!r} needs a class attribute name that labels its results: a "
                         f"plain name ({specs.LABEL_RULE})")
    return cls


def check_agent(spec: str, detector: str, task: str = "none") -> None:
    """A session's ``agent:`` entry: an Agent class, in a session with the detector off,
    with a ``seek`` method where the session has a task phase."""
    cls = agent_class(spec)
    if detector != "off":
        raise InputError("config", "policies", f"{spec!r}: a Python agent runs with --detector off (its "
                         "robots label what they observe)")
    if task != "none" and cls.seek is Agent.seek:
        raise InputError("config", "task", f"{task!r}: agent {spec!r} has no task phase (implement "
                         "seek(obs, goal) -> (actions, stop))")


def _host(obs: dict) -> dict:
    return {k: np.array(v) for k, v in obs.items()}  # copies: the agent may write to them


def _first(obs: dict) -> dict:
    return {k: v[0] for k, v in obs.items()}
