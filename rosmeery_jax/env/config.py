"""The env's configuration: one frozen dataclass of sections (robot, laser, camera, mapping,
navigation, knowledge), overridden at any depth as ``section__field=value``."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from rosmeery_jax.core import overrides as overrides_
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.sim.knowledge import KnowledgeConfig
from rosmeery_jax.sim.navigation import NavConfig
from rosmeery_jax.sim.occupancy import MapConfig
from rosmeery_jax.sim.robot import RobotConfig
from rosmeery_jax.sim.sensors import CameraConfig, LaserConfig
from rosmeery_jax.world import WorldConfig


MAX_PIXELS = 4096  # image sides and laser beams: larger is never a robot's sensor, and would not fit


@dataclass(frozen=True)
class EnvConfig:
    action_mode: str = "target"
    robot: RobotConfig = field(default_factory=RobotConfig)
    laser: LaserConfig = field(default_factory=LaserConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    mapping: MapConfig = field(default_factory=MapConfig)
    nav: NavConfig = field(default_factory=NavConfig)
    knowledge: KnowledgeConfig = field(default_factory=KnowledgeConfig)
    start_yaw: str = "random"  # "random": heading uniform in [-pi, pi) drawn from the reset key,
    # so different keys start differently; "spawn": the world's spawn yaw (teleop, replays)
    labels: str = "observed"  # "observed": ground-truth label once min_fraction is seen
    # (detector off); "detections": only what `Env.attach` folds in (a detector)

    def with_overrides(self, source: str = "config", **overrides: Any) -> "EnvConfig":
        """Override fields at any depth as ``section__sub__field=value`` (type-checked; an
        unknown or badly typed key is one error naming ``source`` and the key)."""
        cfg = overrides_.apply(self, overrides, source)
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
                                     ("action_mode", cfg.action_mode, ("velocity", "target"))):
            if value not in allowed:
                raise InputError(source, name, f"{value!r} is not one of {', '.join(map(repr, allowed))}")
        return cfg


def body_dimensions(cfg: EnvConfig, world_config: WorldConfig) -> WorldConfig:
    """``world_config`` with the robot's and camera's dimensions taken from ``cfg`` (one source)."""
    cam = None if world_config.camera_height is None else cfg.camera.mount_height
    return replace(world_config, robot_radius=cfg.robot.radius, robot_height=cfg.robot.height, camera_height=cam)
