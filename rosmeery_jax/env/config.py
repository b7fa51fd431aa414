"""The env's configuration: one frozen dataclass of sections (robot, laser, camera, mapping,
navigation, knowledge), overridden at any depth as ``section__field=value``."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

from rosmeery_jax.core import overrides as overrides_
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.raycast.sensors import CameraConfig, LaserConfig
from rosmeery_jax.sim.knowledge import KnowledgeConfig
from rosmeery_jax.sim.localisation import MODES
from rosmeery_jax.sim.navigation import NavConfig
from rosmeery_jax.sim.noise import NoiseConfig
from rosmeery_jax.sim.occupancy import MapConfig
from rosmeery_jax.sim.robot import RobotConfig
from rosmeery_jax.world import WorldConfig

MAX_PIXELS = 4096  # image sides and laser beams: larger is never a robot's sensor, and would not fit

# What each numeric setting may be, as (test, what the message says it must be). Sizes,
# rates, gains and times are positive; counts of iterations at least 1; offsets, margins
# and recovery counts may be 0. Image sides, beams and proxies are checked in with_overrides.
_POSITIVE = (lambda v: v > 0, "a number > 0")
_NOT_NEGATIVE = (lambda v: v >= 0, "a number >= 0")
_COUNT = (lambda v: v >= 1, "a whole number >= 1")
LIMITS = {
    **dict.fromkeys(("robot__radius", "robot__height", "robot__mass", "robot__max_speed", "robot__max_turn_rate",
                     "robot__control_dt", "robot__kv_lin", "robot__kv_yaw", "robot__max_piece", "robot__max_force",
                     "laser__max_range", "camera__max_range", "mapping__hit", "mapping__clamp", "mapping__threshold",
                     "mapping__max_range", "nav__plan_resolution", "nav__lookahead", "nav__goal_tolerance",
                     "nav__yaw_tolerance", "nav__k_turn", "nav__stuck_time", "nav__still_time",
                     "nav__still_distance", "nav__timeout", "nav__backoff_time", "nav__backoff_speed",
                     "nav__turn_time", "knowledge__coverage__temperature"), _POSITIVE),
    **dict.fromkeys(("robot__substeps", "robot__solver_iterations", "robot__line_search_iterations",
                     "robot__max_pairs", "nav__sweeps", "nav__flood_cells"), _COUNT),
    **dict.fromkeys(("robot__skin", "laser__min_range", "laser__height", "camera__min_range", "camera__mount_height",
                     "camera__cull", "nav__near_cost", "nav__stuck_progress", "nav__recoveries",
                     "knowledge__coverage__abs_tol", "knowledge__coverage__rel_tol"), _NOT_NEGATIVE),
    "mapping__miss": (lambda v: v < 0, "a number < 0 (the log-odds a free cell's ray adds)"),
    "knowledge__min_fraction": (lambda v: 0 <= v <= 1, "a share in [0, 1]"),
    "laser__fov": (lambda v: 0 < v <= 2 * math.pi, "an angle in (0, 2 pi] radians"),
    "camera__hfov": (lambda v: 0 < v < math.pi, "an angle in (0, pi) radians"),
    "camera__pitch": (lambda v: -math.pi / 2 < v < math.pi / 2, "an angle in (-pi / 2, pi / 2) radians"),
    "camera__mount_x": (lambda v: True, "a number"),  # ahead of the centre or behind it; finite, as every value
    "knowledge__coverage__max_incidence": (lambda v: 0 < v <= math.pi / 2, "an angle in (0, pi / 2] radians"),
    "knowledge__coverage__min_facing": (lambda v: -1 <= v < 1, "a cosine in [-1, 1)"),
    # sensor and actuation noise (sim.noise): 0 is that noise off
    **dict.fromkeys(("noise__depth_sigma0", "noise__depth_sigma2", "noise__depth_z0", "noise__depth_lateral_px",
                     "noise__disparity_step", "noise__edge_jump", "noise__laser_sigma", "noise__rgb_sigma",
                     "noise__motion_a1", "noise__motion_a2", "noise__motion_a3", "noise__motion_a4",
                     "noise__odom_a1", "noise__odom_a2", "noise__odom_a3", "noise__odom_a4"), _NOT_NEGATIVE),
    **dict.fromkeys(("noise__disparity_focal", "noise__disparity_baseline"), _POSITIVE),
    **dict.fromkeys(("noise__edge_dropout", "noise__laser_dropout"), (lambda v: 0 <= v <= 1, "a probability in [0, 1]")),
    "noise__max_incidence": (lambda v: 0 <= v < math.pi / 2, "an angle in [0, pi / 2) radians (0: none dropped)"),
}


@dataclass(frozen=True)
class EnvConfig:
    action_mode: str = "target"
    robot: RobotConfig = field(default_factory=RobotConfig)
    laser: LaserConfig = field(default_factory=LaserConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    mapping: MapConfig = field(default_factory=MapConfig)
    nav: NavConfig = field(default_factory=NavConfig)
    knowledge: KnowledgeConfig = field(default_factory=KnowledgeConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)  # all off: the exact sensors (sim.noise)
    localisation: str = "ground_truth"  # the robot's pose: told (ground_truth), or its own estimate
    # (dead_reckoning, scan_matching: sim.localisation)
    start_yaw: str = "random"  # "random": heading uniform in [-pi, pi) drawn from the reset key,
    # so different keys start differently; "spawn": the world's spawn yaw (teleop, replays)
    labels: str = "observed"  # "observed": ground-truth label once min_fraction is seen
    # (detector off); "detections": only what `RobotEnv.attach` folds in (a detector)

    @classmethod
    def from_table(cls, values: dict, source: str = "config", table: str = "env",
                   base: "EnvConfig | None" = None) -> "EnvConfig":
        """The config a file's ``[env]`` table (nested or ``__`` keys) sets on ``base`` (the
        defaults); an error names the key as the file spells it (``env.robot.max_speed``)."""
        try:
            return (base or cls()).with_overrides(source, **overrides_.flatten(values, source=source))
        except InputError as err:
            raise overrides_.in_table(err, table) from None

    def with_overrides(self, source: str = "config", **overrides: Any) -> "EnvConfig":
        """Override fields at any depth as ``section__sub__field=value`` (type-checked; an
        unknown or badly typed key is one error naming ``source`` and the key)."""
        cfg = overrides_.apply(self, overrides, source)
        _check_limits(cfg, source)
        near, pairs = cfg.robot.near_proxies, cfg.robot.max_pairs
        if near < 0 or 0 < near < pairs:
            raise InputError(source, "robot__near_proxies", f"{near} must be 0 (every proxy) or at least "
                             f"robot__max_pairs ({pairs})")
        for name, value in (("camera__width", cfg.camera.width), ("camera__height", cfg.camera.height),
                            ("camera__rgb_width", cfg.camera.rgb_width), ("camera__rgb_height", cfg.camera.rgb_height),
                            ("laser__beams", cfg.laser.beams)):
            if not 1 <= value <= MAX_PIXELS:
                raise InputError(source, name, f"{value} must be a whole number in [1, {MAX_PIXELS}]")
        for name, value, allowed in (("start_yaw", cfg.start_yaw, ("spawn", "random")),
                                     ("labels", cfg.labels, ("observed", "detections")),
                                     ("localisation", cfg.localisation, MODES),
                                     ("action_mode", cfg.action_mode, ("velocity", "target"))):
            if value not in allowed:
                raise InputError(source, name, f"{value!r} is not one of {', '.join(map(repr, allowed))}")
        return cfg


def _check_limits(cfg: EnvConfig, source: str) -> None:
    """Every numeric setting within :data:`LIMITS`, and each range's near end below its far one."""
    for key, (ok, wanted) in LIMITS.items():
        value = cfg
        for part in key.split("__"):
            value = getattr(value, part)
        if not ok(value):
            raise InputError(source, key, f"{value} must be {wanted}")
    for section in ("laser", "camera"):
        near, far = getattr(cfg, section).min_range, getattr(cfg, section).max_range
        if not near < far:
            raise InputError(source, f"{section}__min_range", f"{near} must be below {section}__max_range ({far})")
    if not cfg.mapping.threshold < cfg.mapping.clamp:
        raise InputError(source, "mapping__threshold", f"{cfg.mapping.threshold} must be below mapping__clamp "
                         f"({cfg.mapping.clamp}): log-odds are clamped there, so no cell would ever be decided")


def body_dimensions(cfg: EnvConfig, world_config: WorldConfig) -> WorldConfig:
    """``world_config`` with the robot's and camera's dimensions taken from ``cfg`` (one source)."""
    cam = None if world_config.camera_height is None else cfg.camera.mount_height
    return replace(world_config, robot_radius=cfg.robot.radius, robot_height=cfg.robot.height, camera_height=cam)


DEVICE_BYTES_PER_ENV = 2.5e6  # measured: 1,024 envs peak at 2.0 GB (docs/performance.md)
CAMERA_BYTES_PER_PIXEL = 64  # depth, labels and the ray kernel's per-pixel work, with headroom


def env_bytes(cfg: EnvConfig) -> float:
    """Device memory one env's state and one step's camera work take (estimate, with headroom)."""
    return DEVICE_BYTES_PER_ENV + cfg.camera.width * cfg.camera.height * CAMERA_BYTES_PER_PIXEL
