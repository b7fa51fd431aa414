"""The batched environment: ``env = make(world, **config)``, ``reset(key)``, ``step(state, action)``.

In the style of gymnax / MuJoCo Playground: one small class, pure ``reset`` / ``step`` over
a :class:`State` pytree for a single env; ``jax.vmap`` them over a batch of keys (B envs)
and ``jax.jit`` once per configuration. One step is 0.1 s of simulated time: physics
substeps in one ``lax.scan``, then the laser, the depth + segmentation camera, the
occupancy map and the navigator.

Action modes (``EnvConfig.action_mode``):
- ``"velocity"``: action (2,) = (v, w), clipped to the platform's limits;
- ``"target"``: action (3,) = target pose (x, y, yaw) for the navigator; a pose different
  from the current target starts a new navigation, the same pose keeps driving to it.
"""

from __future__ import annotations

import copy
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.env.config import EnvConfig, body_dimensions
from rosmeery_jax.env.world_data import Sizes, WorldData, near_physics_model, physics_model, truth_table, world_data
from rosmeery_jax.raycast.sensors import depth_seg, laser, laser_dirs, rgb, rgbd
from rosmeery_jax.sim import localisation, noise, occupancy
from rosmeery_jax.sim.knowledge import Knowledge, ObjectLog, SpatialKnowledge
from rosmeery_jax.sim.mjx import mjx
from rosmeery_jax.sim.navigation import IDLE, Navigator, NavState
from rosmeery_jax.sim.robot import Platform, robot_model
from rosmeery_jax.world import World, WorldConfig, load_world


class State(NamedTuple):
    """One env's state (add a leading B axis under vmap).

    physics: MJX data; pose (3,) x, y, yaw; logodds (H, W) the robot's occupancy map;
    nav: navigator state; ranges (K,) laser; depth (h, w) and seg (h, w) camera;
    t int32 control steps since reset; key: PRNG key for stochastic consumers;
    knowledge: the spatial knowledge (coverage of the ground-truth samples, labels);
    truth (3,): the true pose when the robot localises itself (``pose`` is then its
    estimate, what its map, navigator, policies and mappers use), else None (``pose`` is
    the truth).
    """

    physics: mjx.Data
    pose: jax.Array
    logodds: jax.Array
    nav: NavState
    ranges: jax.Array
    depth: jax.Array
    seg: jax.Array
    t: jax.Array
    key: jax.Array
    knowledge: Knowledge
    truth: jax.Array | None = None

    @property
    def true_pose(self) -> jax.Array:
        return self.pose if self.truth is None else self.truth


class Track(NamedTuple):
    """Where the robot was and what its navigator reported at each control step: pose
    (..., 3) the true pose, status (...) int8 (``sim.navigation``'s codes), and estimate
    (..., 3) the robot's own pose estimate when it localises itself (else None)."""

    pose: jax.Array
    status: jax.Array
    estimate: jax.Array | None = None

    @staticmethod
    def of(state: State) -> "Track":
        return Track(state.true_pose, state.nav.status.astype(jnp.int8),
                     None if state.truth is None else state.pose)

    @property
    def believed(self) -> jax.Array:
        """The poses the robot believed it had (its mappers' frames carry these)."""
        return self.pose if self.estimate is None else self.estimate


class RobotEnv:
    """The semantic-mapping robot in one world.

    The world enters every pure method as data (:class:`WorldData`, ``env.data``); a session
    compiles one function for several worlds by padding them to shared ``sizes`` and
    calling ``env.with_data(world)`` on each env's world inside it.
    """

    def __init__(self, world: World, config: EnvConfig, sizes: Sizes | None = None):
        self.world, self.config = world, config
        self.sizes = sizes or Sizes.of(world, config)
        self.truth = truth_table(world)
        self.model = physics_model(world, config.robot, self.sizes)  # a constant in compiled code
        self.near_model = near_physics_model(world, config.robot, self.sizes)  # likewise
        self.beam_angles = jnp.asarray(laser_dirs(config.laser))
        self.dt = config.robot.control_dt
        self._bind(world_data(world, config, self.sizes, self.model))

    def _bind(self, data: WorldData) -> None:
        c, r = self.config, self.config.robot
        self.data = data
        self.platform = Platform(r, self.model.replace(**data.physics), data.spawn[:2], self.near_model)
        self.rays, self.laser_rays, self.grid = data.rays, data.laser_rays, data.grid
        self.navigator = Navigator(self.grid, c.nav, r.control_dt, r.max_speed, r.max_turn_rate, r.radius)
        self.sk = SpatialKnowledge(c.knowledge, c.camera, data, self.truth)

    def with_data(self, data: WorldData) -> "RobotEnv":
        """This env in the world ``data`` (same config and padded sizes; e.g. traced arrays
        inside a jitted function)."""
        env = copy.copy(self)
        env._bind(data)
        return env

    @property
    def mj_model(self):
        """The C MuJoCo physics model of this env's own world (unpadded), for the bench."""
        return robot_model(self.world, self.config.robot)

    def reset(self, key: jax.Array) -> State:
        pose = self.data.spawn
        if self.config.start_yaw == "random":
            key, sub = jax.random.split(key)
            pose = pose.at[2].set(jax.random.uniform(sub, (), minval=-jnp.pi, maxval=jnp.pi))
        state = State(self.platform.init(pose), pose, occupancy.empty_map(self.grid), self.navigator.init(),
                      jnp.zeros(self.config.laser.beams, jnp.float32),
                      jnp.zeros((self.config.camera.height, self.config.camera.width), jnp.float32),
                      jnp.zeros((self.config.camera.height, self.config.camera.width), jnp.int32),
                      jnp.int32(0), key, self.sk.init(),
                      None if self.config.localisation == "ground_truth" else pose)  # the start is known
        return self._sense(state)

    def place(self, state: State, pose: jax.Array) -> State:
        """The robot put at ``pose`` (3,) (its estimate there too: the start of a task's
        episode is known), its navigator idle, its map and knowledge kept; it senses there."""
        state = state._replace(physics=self.platform.init(pose), pose=pose, nav=self.navigator.init(),
                               truth=None if state.truth is None else pose)
        return self._sense(state)

    def step(self, state: State, action: jax.Array) -> State:
        """0.1 s: the stages below in order (the bench times each alone, ``stage_chain``)."""
        return self._sense(*self._motion(state, action))

    def drive(self, state: State, action: jax.Array) -> State:
        """0.1 s of a task's drive (:mod:`rosmeery_jax.env.drive`): :meth:`step` without the
        camera, the knowledge and the map update; the robot localises itself on its map as
        it is."""
        return self._localise(*self._motion(state, action))[0]

    def _motion(self, state: State, action: jax.Array) -> tuple[State, jax.Array | bool]:
        """The navigator's command executed; the state moved and whether the odometry
        reported motion (only then does the scan matcher refine the estimate)."""
        nav, cmd = self.navigate(state, action)
        if self.config.noise.actuation:  # the drive executes the command imperfectly
            cmd = noise.command(noise.key(state.key, state.t, noise.ACTUATION), cmd, self.config.noise)
        physics, pose = self.move(state.physics, cmd)
        if state.truth is None:
            return state._replace(physics=physics, pose=pose, nav=nav, t=state.t + 1), False
        # the robot's estimate follows its odometry; the truth, the physics
        estimate = localisation.odometry(noise.key(state.key, state.t, noise.ODOMETRY), state.truth, pose,
                                         state.pose, self.config.noise)
        moving = localisation.moved(state.pose, estimate)
        return state._replace(physics=physics, pose=estimate, truth=pose, nav=nav, t=state.t + 1), moving

    def _localise(self, state: State, moving: jax.Array | bool = False) -> tuple[State, jax.Array]:
        """The laser at the new pose (``ranges`` set) and, with scan matching and
        ``moving``, the estimate refined on the map so far; also what each beam hit."""
        ranges, labels = self.scan(state.true_pose)
        if self.config.noise.laser:  # the robot's own map and what policies read come from the noisy laser
            las = self.config.laser
            ranges = noise.ranges(noise.key(state.key, state.t, noise.LASER), ranges, self.config.noise,
                                  las.min_range, las.max_range)
        if self.config.localisation == "scan_matching":  # the prediction refined on the map so far
            matched = localisation.match(state.logodds, self.grid, state.pose, self.beam_angles, ranges,
                                         self.config.laser.max_range)
            state = state._replace(pose=jnp.where(moving, matched, state.pose))
        return state._replace(ranges=ranges), labels

    def _sense(self, state: State, moving: jax.Array | bool = False) -> State:
        """The sensors at the new pose (:meth:`_localise`), the map, the camera and what it saw."""
        state, labels = self._localise(state, moving)
        logodds = self.update_map(state.logodds, state.pose, state.ranges, labels)  # in the robot's own frame
        depth, seg = self.look(state.true_pose)
        knowledge = self.sk.observe(state.knowledge, state.true_pose, depth)  # what was in view: the truth
        return state._replace(logodds=logodds, depth=depth, seg=seg, knowledge=knowledge)

    # The step's stages, one concept each; ``step`` composes them.

    def navigate(self, state: State, action: jax.Array) -> tuple[NavState, jax.Array]:
        """The velocity command (v, w) for ``action``: a target pose for the navigator (its
        state updated; a new pose starts a new navigation), or the command itself."""
        nav, action = state.nav, self._action(action)
        if self.config.action_mode != "target":
            return nav, action
        target = action
        new = (nav.status == IDLE) | jnp.any(target != nav.target)
        nav = self.navigator.set_target(nav, target, new)
        occupied = occupancy.classify(state.logodds, self.config.mapping) == occupancy.OCCUPIED
        return self.navigator.step(nav, state.pose, occupied)

    def _action(self, action) -> jax.Array:
        """``action`` as float32 of its mode's shape, or a TypeError when tracing (a (1,) or
        scalar action broadcast over the target pose, a (3,) one ran as a velocity)."""
        size = 3 if self.config.action_mode == "target" else 2
        array = None if action is None else jnp.asarray(action, jnp.float32)  # a list (of tracers too), a scalar
        if array is None or array.shape != (size,):
            what = "(x, y, yaw)" if size == 3 else "(v, w)"
            raise TypeError(f"RobotEnv.step: a {self.config.action_mode!r} action is {what}, shape ({size},) per env "
                            f"(vmap for a batch), not {'None' if array is None else array.shape}")
        return array

    def move(self, physics: mjx.Data, cmd: jax.Array) -> tuple[mjx.Data, jax.Array]:
        """The physics substeps under ``cmd``; the new MJX data and pose (3,)."""
        physics = self.platform.step(physics, cmd)
        return physics, self.platform.pose(physics)

    def scan(self, pose: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The laser at ``pose``: ranges (K,) and what each beam hit."""
        return laser(self.laser_rays, self.config.laser, pose)

    def update_map(self, logodds: jax.Array, pose: jax.Array, ranges: jax.Array, labels: jax.Array) -> jax.Array:
        """The occupancy map (H, W) with one scan folded in."""
        return occupancy.update(logodds, self.grid, self.config.mapping, pose[:2], pose[2] + self.beam_angles,
                                ranges, labels)

    def look(self, pose: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The camera at ``pose``: depth (h, w) and segmentation (h, w)."""
        return depth_seg(self.rays, self.config.camera, pose)

    def camera_rgb(self, state: State) -> tuple[jax.Array, jax.Array]:
        """The detector's frame: RGB (Hr, Wr, 3) uint8 and object labels (Hr, Wr) int32."""
        return rgb(self.rays, self.config.camera, state.true_pose)

    def camera_rgbd(self, state: State) -> tuple[jax.Array, jax.Array, jax.Array]:
        """The detector's frame with its depth: RGB (Hr, Wr, 3) uint8, depth (Hr, Wr) (0 = no
        return) and object labels (Hr, Wr) int32."""
        return rgbd(self.rays, self.config.camera, state.true_pose)

    def sensed(self, state: State, depth: jax.Array | None = None, image: jax.Array | None = None,
               stream: int = noise.DEPTH):
        """What the robot's cameras report of an exact ``depth`` (h, w) and ``image`` (H, W,
        3) at ``state``: with the config's noise (sim.noise), else as they are (``stream``:
        the detector frame's depth, or the depth camera of every step, ``noise.SWEEP``). The
        knowledge's coverage reads the exact depth: it scores what was in view."""
        cfg = self.config.noise
        if depth is not None and cfg.depth:
            depth = noise.depth(noise.key(state.key, state.t, stream), depth, cfg,
                                self.config.camera.focal(depth.shape[1]))
        if image is not None and cfg.rgb:
            image = noise.rgb(noise.key(state.key, state.t, noise.RGB), image, cfg)
        return depth, image

    def attach(self, state: State, obj: jax.Array, label: jax.Array, conf: jax.Array) -> State:
        """Fold detections (D,) object index / category / confidence into the knowledge."""
        return state._replace(knowledge=self.sk.attach(state.knowledge, obj, label, conf))

    def labelled_knowledge(self, state: State) -> Knowledge:
        """The knowledge with the label rule of ``config.labels`` applied."""
        if self.config.labels == "observed":
            return self.sk.label_observed(state.knowledge)
        return state.knowledge

    def log(self, state: State) -> ObjectLog:
        """Per-object row for the metrics (one env; vmap for a batch)."""
        return self.sk.log(self.labelled_knowledge(state))

    def rollout(self, state: State, actions: jax.Array) -> tuple[State, ObjectLog]:
        """Step through actions (T, A) in one ``lax.scan``, logging every step: returns the
        final state and the per-object logs with (T, N) fields. One env; vmap for B."""

        def body(s, a):
            s = self.step(s, a)
            return s, self.log(s)

        return jax.lax.scan(body, state, actions)

    def occupancy(self, state: State) -> jax.Array:
        """(…, H, W) int8 UNKNOWN / FREE / OCCUPIED of the robot's own map."""
        return occupancy.classify(state.logodds, self.config.mapping)


def make(world: str | World, world_config: WorldConfig | None = None, source: str = "config",
         sizes: Sizes | None = None, **overrides: Any) -> RobotEnv:
    """An env for a built-in world name, an MJCF path or a loaded :class:`World`.

    Keyword overrides set :class:`EnvConfig` fields at any depth as ``section__field``
    (e.g. ``make("kitchen", action_mode="velocity", knowledge__coverage__soft=True)``).
    ``sizes`` pads the world's data to a session's shared sizes (default: its own).
    The robot's radius and height and the camera's mounting height are set here only
    (``robot__radius``, ``robot__height``, ``camera__mount_height``): the world's free-space
    map and observable samples are built with the same values.
    """
    cfg = EnvConfig().with_overrides(source, **overrides)
    body = body_dimensions(cfg, world_config or (world.config if isinstance(world, World) else WorldConfig()))
    if isinstance(world, World):
        if world.config != body:
            raise InputError(world.name, "world config", "was loaded with other robot or camera dimensions "
                             "than the env's; load it with env.body_dimensions(...) or pass its name")
        return RobotEnv(world, cfg, sizes)
    return RobotEnv(load_world(world, body), cfg, sizes)
