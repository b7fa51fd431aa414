"""A session's configuration: which worlds, policies and seeds, for how long, with which
detector and mappers; loaded from defaults, a TOML file and the command line, and checked
whole before anything runs or is written (each layer checks its own part:
:mod:`rosmeery_jax.session.checks`; the clock it sets: :mod:`rosmeery_jax.session.schedule`)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from rosmeery_jax.core import config as config_loader
from rosmeery_jax.core import overrides, specs
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.specs import MAX_SEED
from rosmeery_jax.detector.detections import DETECTORS
from rosmeery_jax.detector.runtime import DEFAULT as DEFAULT_RUNTIME
from rosmeery_jax.metrics import DEFAULT_METRICS
from rosmeery_jax.session.checks import check_session

LIST_FIELDS = ("worlds", "policies", "metrics", "mappers")
TASKS = ("none", "objectnav")  # what the robots do after exploring (docs/tasks.md)
# Settings that change results: resume refuses a change to any of them.
RESULT_FIELDS = ("seeds", "first_seed", "duration", "detector", "conf_threshold", "decide_every", "detect_every",
                 "detector_period_s", "sample_s", "metrics", "env", "mappers", "detector_runtime", "noise",
                 "localisation", "task_episodes", "task_attempts", "task")


@dataclass(frozen=True)
class SessionConfig:
    worlds: tuple[str, ...] = ("kitchen", "laboratory", "small_office", "large_office")
    policies: tuple[str, ...] = ("frontier", "random")
    seeds: int = 5
    first_seed: int = 0  # the runs are seeds first_seed .. first_seed + seeds - 1; a seed's run is the
    # same whatever else runs, so a sweep can be split over machines (seeds 0-4 here, 5-9 there)
    duration: float = 300.0  # simulated seconds per run
    detector: str = "yolo"  # "yolo" (YOLO-v5n), "oracle" (simulated from ground truth), "off"
    conf_threshold: float = 0.25  # detections below it are dropped
    weights: str = ""  # YOLO-v5 weights for "yolo": a file, or "procedural" ("": the default) / "paper_worlds"
    detector_runtime: str = DEFAULT_RUNTIME  # where YOLO's network runs: torch, onnxruntime, openvino
    metrics: tuple[str, ...] = DEFAULT_METRICS
    decide_every: int = 10  # control steps between policy decisions (10 = 1 s)
    detect_every: int = 0  # control steps between detector frames, a divisor of decide_every
    # (0: one frame per decision, at its end); more frames feed the labels and mappers, not the policy's pace
    chunk_s: float = 30.0  # simulated seconds per jitted call without a detector (progress
    # granularity only: results do not depend on it)
    detector_period_s: float = 10.0  # labels from the frames of one period reach the robot's
    # knowledge (what policies see) at the start of the period after next
    sample_s: float = 1.0  # seconds between rows of metrics.csv
    mappers: tuple[str, ...] = ("oracle",)  # who builds the scored map: "oracle" (the built-in
    # knowledge: detections tied to objects by the ground-truth segmentation) and/or
    # "perceived" (detector frames' depth cut to the detected objects, no ground truth:
    # rosmeery_jax.mapping.perceived), "fused" (voxels and labels fused over frames, for
    # noisy sensing: rosmeery_jax.mapping.fused)
    out: str = "results/session"
    digest: bool = False  # write a digest of each robot's state per chunk (runs/*.digest.csv), to
    # find where two runs part (rosmeery diff); it waits for every chunk, so it is slower
    env: dict = field(default_factory=dict)  # EnvConfig overrides, e.g. {"camera__cull": 0}
    noise: str = "off"  # sensor and actuation noise preset: "off" (exact sensors) or "realistic"
    # (rosmeery_jax.sim.noise; each parameter also as env noise__NAME)
    localisation: str = "ground_truth"  # the robot's pose: told (ground_truth), or estimated by itself:
    # dead_reckoning (odometry integrated) or scan_matching (odometry refined on its own map): sim.localisation
    task_episodes: int = 50  # the task metrics' object-goal episodes per world (its generated
    # set, seed 0: rosmeery tasks; docs/tasks.md), when metrics name them
    task_attempts: int = 3  # map instances a task episode tries at most
    task: str = "none"  # "objectnav": after exploring, each robot drives its world's task episodes in the
    # simulation, once per mapper, with that mapper's final map (tasks.csv; docs/tasks.md)
    devices: int = 0  # split each batch over this many devices (speed only: results are the same);
    # 0 = every device JAX has (on a CPU one host device per core, less one for torch when
    # the YOLO detector runs), at most one per block

    def __post_init__(self):
        # The Python API's natural spellings: a list for a tuple, a Path for the folder
        for name in LIST_FIELDS:
            if isinstance(getattr(self, name), list):
                object.__setattr__(self, name, tuple(getattr(self, name)))
        if isinstance(self.out, os.PathLike):
            object.__setattr__(self, "out", os.fspath(self.out))

    @property
    def seed_range(self) -> range:
        """The seeds of every run: first_seed .. first_seed + seeds - 1."""
        return range(self.first_seed, self.first_seed + self.seeds)

    def validate(self, source: str = "config") -> "SessionConfig":
        """Every check that can be made before a run starts; one InputError naming ``source``.
        Pure but for a mark that it passed (``validated``); devices are set up by the runner."""
        _check_values(self, source)
        for name in LIST_FIELDS:
            if not getattr(self, name):
                raise InputError(source, name, "is empty: name at least one")
        check_session(self, source)
        object.__setattr__(self, "_validated", True)  # not a field: a changed copy is checked again
        return self

    @property
    def validated(self) -> bool:
        """Whether :meth:`validate` passed on this very object (a Session checks it otherwise)."""
        return getattr(self, "_validated", False)


def _check_types(cfg: SessionConfig, source: str) -> None:
    """Each field has its type (a file or the command line is checked as it is read; a
    SessionConfig built in Python is checked here)."""
    overrides.check_fields(cfg, source)
    for name in LIST_FIELDS:
        value = getattr(cfg, name)
        if not isinstance(value, tuple) or not all(isinstance(x, str) for x in value):
            hint = f" (one name: ({value!r},))" if isinstance(value, str) else ""
            raise InputError(source, name, f"{value!r} must be a tuple of names{hint}")
    if not isinstance(cfg.env, dict):
        raise InputError(source, "env", f"{cfg.env!r} must be a dict of EnvConfig overrides")


def _check_values(cfg: SessionConfig, source: str) -> None:
    _check_types(cfg, source)
    if cfg.detector not in DETECTORS:
        raise InputError(source, "detector", f"{cfg.detector!r} is not available (available: {', '.join(DETECTORS)})")
    if not 0 <= cfg.conf_threshold <= 1:
        raise InputError(source, "conf_threshold", f"{cfg.conf_threshold!r} must be a number in [0, 1]")
    for name in ("seeds", "decide_every"):
        if getattr(cfg, name) < 1:
            raise InputError(source, name, f"{getattr(cfg, name)!r} must be a whole number >= 1")
    if not 0 <= cfg.first_seed <= MAX_SEED + 1 - cfg.seeds:
        raise InputError(source, "first_seed", f"{cfg.first_seed!r} must be a whole number in [0, "
                         f"{MAX_SEED + 1 - cfg.seeds}] (the last seed, first_seed + seeds - 1, at most 2**31 - 1)")
    if cfg.detect_every < 0 or cfg.decide_every % max(cfg.detect_every, 1):
        raise InputError(source, "detect_every", f"{cfg.detect_every!r} must be 0 (one frame per decision) or a "
                         f"divisor of decide_every ({cfg.decide_every})")
    if cfg.task not in TASKS:
        raise InputError(source, "task", f"{cfg.task!r} is not a task (tasks: {', '.join(TASKS)})")
    if cfg.devices < 0:
        raise InputError(source, "devices", f"{cfg.devices!r} must be a whole number >= 0 (0: every device)")
    for name in ("duration", "chunk_s", "sample_s", "detector_period_s"):
        if not getattr(cfg, name) > 0:
            raise InputError(source, name, f"{getattr(cfg, name)!r} must be a number > 0")
    for name in ("mappers", "metrics"):
        values = getattr(cfg, name)
        twice = next((v for v in values if values.count(v) > 1), None)
        if twice is not None:
            raise InputError(source, name, f"{twice!r} appears twice")
    if cfg.detect_every and cfg.detector == "off":
        raise InputError(source, "detect_every", f"{cfg.detect_every!r} sets the detector's frames: use --detector "
                         "yolo or oracle")
    fed = next((m for m in cfg.mappers if m != "oracle"), None)
    if fed and cfg.detector == "off":
        raise InputError(source, "mappers", f"{fed!r} builds its map from detector frames: use --detector yolo "
                         "or oracle")


def load_config(path: str | Path | None, **cli) -> SessionConfig:
    """Built-in defaults, then the TOML file (its top level or a ``[session]`` table), then
    command-line values (None = unset); validated."""
    source = str(path) if path is not None else "command line"
    return config_loader.load(SessionConfig(), path, cli, table="session", prepare=_prepare).validate(source)


def _prepare(values: dict, source: str) -> dict:
    """The lists (a TOML list or a comma-separated string) and the ``env`` table, taken out
    of ``values`` and normalised: procedural ranges expanded, replay files re-joined."""
    given = {}
    for key in LIST_FIELDS:
        if key not in values:
            continue
        value = values.pop(key)
        if isinstance(value, str):
            value = [x.strip() for x in value.split(",") if x.strip()]
        if not isinstance(value, (list, tuple)) or not all(isinstance(x, str) for x in value):
            raise InputError(source, key, f"{value!r} must be a list of names or a comma-separated string")
        given[key] = tuple(value)
    if "worlds" in given:  # procedural:KIND:A-B is one world per seed
        given["worlds"] = specs.expand_ranges(given["worlds"])
    if "policies" in given:
        given["policies"] = specs.regroup(given["policies"])
    if "env" in values:
        if not isinstance(values["env"], dict):
            raise InputError(source, "env", f"{values['env']!r} must be a table of EnvConfig overrides")
        given["env"] = values.pop("env")
    return given
