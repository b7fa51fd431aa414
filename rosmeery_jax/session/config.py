"""A session's configuration: which worlds, policies and seeds, for how long, with which
detector and mappers; loaded from defaults, a TOML file and the command line, and checked
whole before anything runs or is written."""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import jax
import numpy as np

from rosmeery_jax.core import config as config_loader
from rosmeery_jax.core import overrides, plugins, xla
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.xla import MEMORY_SHARE, memory_bytes
from rosmeery_jax.detector import runtime as runtimes
from rosmeery_jax.detector.detections import WEIGHTS, weights_file
from rosmeery_jax.env import EnvConfig, make
from rosmeery_jax.gym import AGENT, agent_class
from rosmeery_jax.policies import POLICIES, REPLAY_PREFIX, LearnedPolicy, policy_class, policy_label
from rosmeery_jax.policies.learned import policy_file
from rosmeery_jax.policies.plugin import check_plugin
from rosmeery_jax.policies.teleop_replay import recordings_by_world
from rosmeery_jax.rl.network import load_policy
from rosmeery_jax.rl.task import STEP_LIMIT
from rosmeery_jax import metrics
from rosmeery_jax.mapping.protocol import BUILT_IN, check_mapper, mapper_label
from rosmeery_jax.results.tables import MAX_SEED
from rosmeery_jax.session.batch import BLOCK
from rosmeery_jax.world import load_world, world_names
from rosmeery_jax.world.procedural import PREFIX as PROCEDURAL, expand_names

DETECTORS = ("yolo", "oracle", "off")
LIST_FIELDS = ("worlds", "policies", "metrics", "mappers")
LOG_BYTES_PER_OBJECT_STEP = 24  # ObjectLog: six 4-byte fields
DEVICE_BYTES_PER_ENV = 2.5e6  # measured: 1,024 envs peak at 2.0 GB (docs/performance.md)
CAMERA_BYTES_PER_PIXEL = 64  # depth, labels and the ray kernel's per-pixel work, with headroom
SWEEP_BYTES_PER_PIXEL = 12  # a step's depth held for a mapper: float32, on device, on the host, as sent
FRAME_BYTES_PER_PIXEL = 16  # a detector frame held for the worker: RGB, labels, depth, with copies
# Settings that change results: resume refuses a change to any of them.
RESULT_FIELDS = ("seeds", "first_seed", "duration", "detector", "conf_threshold", "decide_every", "detect_every",
                 "detector_period_s", "sample_s", "metrics", "env", "mappers", "detector_runtime")


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
    detector_runtime: str = runtimes.DEFAULT  # where YOLO's network runs: torch, onnxruntime, openvino
    metrics: tuple[str, ...] = metrics.DEFAULT_METRICS
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
    # rosmeery_jax.mapping.perceived)
    out: str = "results/session"
    digest: bool = False  # write a digest of each robot's state per chunk (runs/*.digest.csv), to
    # find where two runs part (rosmeery diff); it waits for every chunk, so it is slower
    env: dict = field(default_factory=dict)  # EnvConfig overrides, e.g. {"camera__cull": 0}
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
    def env_config(self) -> EnvConfig:
        """The env configuration of the session's robots (its ``env`` overrides applied)."""
        return EnvConfig.from_table(self.env)

    @property
    def seed_range(self) -> range:
        """The seeds of every run: first_seed .. first_seed + seeds - 1."""
        return range(self.first_seed, self.first_seed + self.seeds)

    @property
    def dt(self) -> float:
        """The control period in seconds (one env step): the robot's, never restated here."""
        return self.env_config.robot.control_dt

    def validate(self, source: str = "config") -> "SessionConfig":
        """Every check that can be made before a run starts; one InputError naming ``source``.
        Pure but for a mark that it passed (``validated``); devices are set up by the runner."""
        _check_values(self, source)
        for name in LIST_FIELDS:
            if not getattr(self, name):
                raise InputError(source, name, "is empty: name at least one")
        with _as_source(source):
            metrics.resolve(self.metrics)
            self.env_config  # noqa: B018  (type-checks the overrides)
            for w in self.worlds:
                _check_world_name(w)
            worlds = [load_world(w) for w in self.worlds]
            stage = functools.cache(lambda: _plugin_stage(self))
            for p in self.policies:
                _check_policy(p, worlds, self, stage)
            _check_mappers(self, worlds)
            decisions(self)
            sample_steps(self)
            if self.detector != "off":
                detector_period(self)
        _check_unique(self, worlds, source)
        if self.weights and self.detector != "yolo":
            raise InputError(source, "weights", f"{self.weights!r} is for --detector yolo, not {self.detector!r}")
        if self.weights and not weights_file(self.weights).is_file():
            raise InputError(source, "weights", f"{self.weights!r}: no such file (or a name: {', '.join(WEIGHTS)})")
        _check_devices(self, worlds, source)
        if self.detector == "yolo":  # its packages found, not imported
            runtimes.check(self.detector_runtime, source, "detector", "'yolo'", " (or use --detector oracle / off)")
        _check_size(self, worlds, source)
        object.__setattr__(self, "_validated", True)  # not a field: a changed copy is checked again
        return self

    @property
    def validated(self) -> bool:
        """Whether :meth:`validate` passed on this very object (a Session checks it otherwise)."""
        return getattr(self, "_validated", False)


class _as_source:
    """Name ``source`` in InputErrors that checks deeper down raise with the generic source
    "config" (they do not know which file the value came from)."""

    def __init__(self, source: str):
        self.source = source

    def __enter__(self):
        return self

    def __exit__(self, kind, err, tb):
        if isinstance(err, InputError) and err.source == "config":
            raise InputError(self.source, err.where, err.problem) from None
        return False


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
    if cfg.devices < 0:
        raise InputError(source, "devices", f"{cfg.devices!r} must be a whole number >= 0 (0: every device)")
    for name in ("duration", "chunk_s", "sample_s", "detector_period_s"):
        if not getattr(cfg, name) > 0:
            raise InputError(source, name, f"{getattr(cfg, name)!r} must be a number > 0")
    for m in cfg.mappers:
        if m not in BUILT_IN and not plugins.is_plugin(m):
            raise InputError(source, "mappers", f"{m!r} is not a mapper ({', '.join(BUILT_IN)}, or a plugin: "
                             "FILE.py:Name or package.module:Name)")
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


def _check_devices(cfg: SessionConfig, worlds, source: str) -> None:
    """At most one device per block of the batch (more would run nothing)."""
    blocks = -(-cfg.seeds // BLOCK) * len(worlds) * len(cfg.policies)
    if cfg.devices > blocks:
        raise InputError(source, "devices", f"{cfg.devices}: this session has {blocks} blocks of {BLOCK} robots, "
                         "and a device runs whole blocks (at most one device per block)")


def _check_world_name(name: str) -> None:
    """A name that is neither a built-in world nor an existing file is the config's error."""
    if name not in world_names() and not Path(name).is_file() and not name.startswith(PROCEDURAL):
        raise InputError("config", "worlds", f"{name!r} is neither a built-in world ({', '.join(world_names())}) "
                         "nor an MJCF file nor procedural:KIND:SEED")


def _check_mappers(cfg: SessionConfig, worlds) -> None:
    """Each plugin mapper runs on a test frame; the mappers' labels are distinct."""
    for m in cfg.mappers:
        if m not in BUILT_IN:
            check_mapper(m, cfg.env_config.camera, worlds[0].taxonomy.names)
    labels = [mapper_label(m) for m in cfg.mappers]
    twice = next((m for m, name in zip(cfg.mappers, labels) if labels.count(name) > 1), None)
    if twice is not None:
        raise InputError("config", "mappers", f"{twice!r}: two mappers are named {mapper_label(twice)!r}")


def run_label(spec: str) -> str:
    """A policy entry's label in results: an agent's class name, else the policy's label."""
    return agent_class(spec).name if spec.startswith(AGENT) else policy_label(spec)


def _plugin_stage(cfg: SessionConfig) -> tuple:
    """(env, state): the first world's env and one robot's reset, on which every plugin
    policy of ``cfg`` makes its first decision (one env, one reset compile for them all)."""
    env = make(cfg.worlds[0], labels="detections" if cfg.detector != "off" else "observed",
               **overrides.flatten(cfg.env))
    return env, xla.jit(env.reset)(jax.random.key(0))


def _check_policy(spec: str, worlds, cfg: SessionConfig, stage) -> None:
    if spec.startswith(AGENT):
        agent_class(spec)
        if cfg.detector != "off":
            raise InputError("config", "policies", f"{spec!r}: a Python agent runs with --detector off (its "
                             "robots label what they observe)")
        return
    if plugins.is_plugin(spec) and not spec.startswith((REPLAY_PREFIX, "learned:")):
        check_plugin(spec, *stage())
    if policy_class(spec) is LearnedPolicy:
        load_policy(policy_file(spec))  # one line naming the file if it is not a policy file
    if spec.startswith(REPLAY_PREFIX):
        recorded = recordings_by_world(spec)
        if not set(recorded) & {w.name for w in worlds}:
            raise InputError("config", "policies", f"no recording in {spec!r} is of a session world "
                             f"(recorded in: {', '.join(sorted(recorded))})")
        for recs in recorded.values():  # one batch per world: one set of env settings
            for rec in recs:
                EnvConfig.from_table(rec.header.get("env", {}), f"{rec.path}: line 1")
                if rec.header.get("env", {}) != recs[0].header.get("env", {}):
                    raise InputError(str(rec.path), "line 1: env", f"differs from {recs[0].path}'s: recordings "
                                     "replayed together need the same env settings")


def _check_unique(cfg: SessionConfig, worlds, source: str) -> None:
    """Two entries that would write the same run files are refused, not merged or overwritten."""
    seen: dict[str, str] = {}
    for spec, w in zip(cfg.worlds, worlds):
        if w.name in seen:
            raise InputError(source, "worlds", f"{seen[w.name]!r} and {spec!r} are both named {w.name!r}: their "
                             "results would share files (rename one file)")
        seen[w.name] = spec
    labels = [run_label(p) for p in cfg.policies]
    for label in labels:
        if labels.count(label) > 1:
            raise InputError(source, "policies", f"{label!r} appears twice (join replay files with '+' in one entry)")


def env_bytes(env: EnvConfig) -> float:
    """Device memory one env's state and one step's camera work take (estimate, with headroom)."""
    return DEVICE_BYTES_PER_ENV + env.camera.width * env.camera.height * CAMERA_BYTES_PER_PIXEL


def _check_size(cfg: SessionConfig, worlds, source: str) -> None:
    """Refuse a session whose logs or batch cannot fit in this machine's memory (the whole
    session is one batch: every world x policy x seed, each policy padded to whole blocks)."""
    steps = cfg.duration / cfg.dt / log_every(cfg)  # logged steps; floats: a huge duration must give
    # a huge estimate, not an overflow
    per_policy = -(-cfg.seeds // BLOCK) * BLOCK * len(worlds)
    batch = float(per_policy * len(cfg.policies))
    need_host = batch * steps * max(w.truth.num_objects for w in worlds) * LOG_BYTES_PER_OBJECT_STEP
    cam = cfg.env_config.camera  # every step's depth and labels, and a chunk's detector frames
    frames = per_call(cfg, decisions(cfg)) * cfg.decide_every // frame_steps(cfg) if cfg.detector != "off" else 0
    swept = frames * frame_steps(cfg) if any(m != "oracle" for m in cfg.mappers) else 0  # steps' depth, for mappers
    need_device = batch * (env_bytes(cfg.env_config) + cam.width * cam.height * SWEEP_BYTES_PER_PIXEL * swept
                           + FRAME_BYTES_PER_PIXEL * frames * cam.rgb_width * cam.rgb_height)
    have = memory_bytes()
    for what, need in (("the logs", need_host), ("the batch's device state", need_device)):
        if need > MEMORY_SHARE * have:
            raise InputError(source, _culprit(cfg, what, need, MEMORY_SHARE * have),
                             f"{cfg.seeds} seeds x {len(worlds)} worlds x {len(cfg.policies)} policies x "
                             f"{cfg.duration:g} s: {what} need about {need / 1e9:,.1f} GB, more than this "
                             f"machine's {have / 1e9:.1f} GB allows (fewer seeds, worlds or a shorter duration)")


def _culprit(cfg: SessionConfig, what: str, need: float, limit: float) -> str:
    """The field an oversize refusal names: the batch grows with the seeds; the logs with the
    seeds and the duration, so "seeds" where they need too much even at the default duration."""
    if what.startswith("the batch"):
        return "seeds"
    return "seeds" if need * SessionConfig().duration / cfg.duration > limit else "duration"


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
        given["worlds"] = tuple(expand_names(given["worlds"]))
    if "policies" in given:
        given["policies"] = _group_replay(given["policies"])
    if "env" in values:
        if not isinstance(values["env"], dict):
            raise InputError(source, "env", f"{values['env']!r} must be a table of EnvConfig overrides")
        given["env"] = values.pop("env")
    return given


def _group_replay(tokens: tuple[str, ...]) -> tuple[str, ...]:
    """``replay:a.jsonl,b.jsonl,random`` splits on commas: re-attach the files to their entry."""
    out: list[str] = []
    for tok in tokens:
        if out and out[-1].startswith(REPLAY_PREFIX) and tok not in POLICIES and not tok.startswith(REPLAY_PREFIX):
            out[-1] += "+" + tok
        else:
            out.append(tok)
    return tuple(out)


def decisions(cfg: SessionConfig) -> int:
    """Policy decisions in one run; the duration must be a whole number of them."""
    period = cfg.dt * cfg.decide_every
    if not math.isfinite(cfg.duration):
        raise InputError("config", "duration", f"{cfg.duration} must be a finite number of seconds")
    if cfg.duration / cfg.dt > STEP_LIMIT:  # steps are counted in int32 (and 1e308 s hung the checks below)
        raise InputError("config", "duration", f"{cfg.duration:g} s is more control steps of {cfg.dt:g} s than "
                         f"a session counts ({STEP_LIMIT}): at most {STEP_LIMIT * cfg.dt:g} s")
    n = int(round(cfg.duration / period))
    if n < 1 or abs(n * period - cfg.duration) > 1e-6:
        raise InputError("config", "duration", f"{cfg.duration} s is not a whole number of decision periods "
                         f"({period:g} s = decide_every x {cfg.dt:g} s)")
    return n


def detector_period(cfg: SessionConfig) -> int:
    """Decisions per detector period, whose boundaries the label schedule is cut at: a
    whole number of them that divides the run's (a period as long as the run or longer is
    the run), or one InputError naming the nearest periods that are."""
    total, period = decisions(cfg), cfg.dt * cfg.decide_every
    if cfg.detector_period_s >= cfg.duration - 1e-6:
        return total
    k = int(round(cfg.detector_period_s / period))
    if k < 1 or abs(k * period - cfg.detector_period_s) > 1e-6 or total % k:
        fits = [d * period for d in _divisors(total)]
        nearest = [f for f in fits if f < cfg.detector_period_s][-1:] + [f for f in fits if f > cfg.detector_period_s][:1]
        raise InputError("config", "detector_period_s", f"{cfg.detector_period_s:g} s must be a whole number of "
                         f"decision periods ({period:g} s) that divides the duration ({cfg.duration:g} s), as "
                         f"labels are folded in at its boundaries: the nearest, {' or '.join(f'{f:g} s' for f in nearest)}")
    return k


def _divisors(n: int) -> list[int]:
    """The divisors of ``n`` in increasing order, found up to its square root (a session may
    count 10^8 decisions)."""
    small = [d for d in range(1, math.isqrt(n) + 1) if n % d == 0]
    return small + [n // d for d in reversed(small) if d * d != n]


def per_call(cfg: SessionConfig, total: int) -> int:
    """Decisions per jitted call: the detector period with a detector (the label schedule
    is cut at its boundaries), else ``chunk_s`` (progress granularity only, so the largest
    that divides the run), so one compiled function serves."""
    if cfg.detector != "off":
        return detector_period(cfg)
    want = max(1, int(round(cfg.chunk_s / (cfg.dt * cfg.decide_every))))
    return max(d for d in _divisors(total) if d <= want)


def frame_steps(cfg: SessionConfig) -> int:
    """Control steps between detector frames."""
    return cfg.detect_every or cfg.decide_every


def log_every(cfg: SessionConfig) -> int:
    """Steps between the engine's per-object logs: a divisor of ``sample_s`` in steps (the
    rows metrics.csv keeps) and of the frame period (the chunk function logs within each
    frame's steps; it divides ``decide_every``)."""
    return math.gcd(sample_steps(cfg), frame_steps(cfg))


def sample_steps(cfg: SessionConfig) -> int:
    """Control steps between the rows of metrics.csv: ``sample_s`` must be a whole number
    of control periods."""
    n = int(round(cfg.sample_s / cfg.dt))
    if n < 1 or abs(n * cfg.dt - cfg.sample_s) > 1e-6:
        raise InputError("config", "sample_s", f"{cfg.sample_s:g} s is not a whole number of control periods "
                         f"({cfg.dt:g} s)")
    return n


def sampled_rows(cfg: SessionConfig) -> np.ndarray:
    """(K,) the engine's log rows (one every ``log_every`` steps) that metrics.csv keeps:
    one every ``sample_s`` and the last."""
    every_log = log_every(cfg)
    rows = decisions(cfg) * cfg.decide_every // every_log + 1
    return np.unique(np.r_[np.arange(0, rows, sample_steps(cfg) // every_log), rows - 1])


def frames_before(cfg: SessionConfig, steps: np.ndarray) -> np.ndarray:
    """Detector frames that count at each step (a frame taken at its period's last step
    counts from the step after it, as labels do)."""
    return np.maximum(np.asarray(steps) - 1, 0) // frame_steps(cfg)
