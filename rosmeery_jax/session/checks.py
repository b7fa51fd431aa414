"""The checks a whole session gets before anything runs: each layer checks its own part of
the configuration (worlds, policies and agents, metrics, mappers, detector), then the
session checks what only it knows (distinct result files, devices, memory).

Called by ``SessionConfig.validate``; every failure is one InputError naming the field.
"""

from __future__ import annotations

import functools

import jax

from rosmeery_jax import metrics
from rosmeery_jax.core import overrides, specs, xla
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.xla import MEMORY_SHARE, memory_bytes
from rosmeery_jax.detector.detections import check_choice
from rosmeery_jax.env import make
from rosmeery_jax.env.config import env_bytes
from rosmeery_jax.gym import agent_class, check_agent
from rosmeery_jax.mapping.protocol import check_entries as check_mappers
from rosmeery_jax.metrics import field, tasks
from rosmeery_jax.policies import check_entry as check_policy
from rosmeery_jax.policies import policy_label
from rosmeery_jax.session import schedule
from rosmeery_jax.session.batch import BLOCK
from rosmeery_jax.world import episodes, load_world
from rosmeery_jax.world.load import check_entry as check_world

LOG_BYTES_PER_OBJECT_STEP = 24  # ObjectLog: six 4-byte fields
SWEEP_BYTES_PER_PIXEL = 12  # a step's depth held for a mapper: float32, on device, on the host, as sent
FRAME_BYTES_PER_PIXEL = 16  # a detector frame held for the worker: RGB, labels, depth, with copies


def check_session(cfg, source: str) -> None:
    """Every check of ``cfg`` (a SessionConfig whose fields have their types) that needs the
    layers: InputErrors from deeper down name ``source``."""
    with _as_source(source):
        names = metrics.resolve(cfg.metrics)
        episodes.check_count(cfg.task_episodes, "config", "task_episodes")
        tasks.check_attempts(cfg.task_attempts, "config")
        maps = field.wanted(names) or tasks.wanted(names)
        if maps and "oracle" in cfg.mappers and any(specs.kind(p) == "agent" for p in cfg.policies):
            raise InputError("config", "metrics", "the map metrics (field, task) score the built-in knowledge's map "
                             "(mapper oracle) of policies, not of agent: runs; score an agent's runs with a mapper "
                             "(mappers = [\"perceived\"]) or evaluate their exported maps")
        env = schedule.env_config(cfg)  # type-checks the overrides
        for w in cfg.worlds:
            check_world(w)
        worlds = [load_world(w) for w in cfg.worlds]
        for w in worlds if tasks.wanted(names) or cfg.task != "none" else ():  # no goal to seek: refused now
            episodes.generated(w, cfg.task_episodes)
        stage = functools.cache(lambda: _plugin_stage(cfg))
        for p in cfg.policies:
            if specs.kind(p) == "agent":
                check_agent(p, cfg.detector, cfg.task)
            else:
                check_policy(p, {w.name for w in worlds}, stage)
        check_mappers(cfg.mappers, env.camera, worlds[0].taxonomy.names)
        schedule.decisions(cfg)
        schedule.sample_steps(cfg)
        if cfg.detector != "off":
            schedule.detector_period(cfg)
    _check_unique(cfg, worlds, source)
    check_choice(cfg.detector, cfg.weights, cfg.detector_runtime, source)
    _check_devices(cfg, worlds, source)
    _check_size(cfg, worlds, source)


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


def run_label(spec: str) -> str:
    """A policy entry's label in results: an agent's class name, else the policy's label."""
    return agent_class(spec).name if specs.kind(spec) == "agent" else policy_label(spec)


def _plugin_stage(cfg) -> tuple:
    """(env, state): the first world's env and one robot's reset, on which every plugin
    policy of ``cfg`` makes its first decision (one env, one reset compile for them all)."""
    env = make(cfg.worlds[0], labels="detections" if cfg.detector != "off" else "observed",
               **overrides.flatten(cfg.env))
    return env, xla.jit(env.reset)(jax.random.key(0))


def _check_unique(cfg, worlds, source: str) -> None:
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


def _check_devices(cfg, worlds, source: str) -> None:
    """At most one device per block of the batch (more would run nothing)."""
    blocks = -(-cfg.seeds // BLOCK) * len(worlds) * len(cfg.policies)
    if cfg.devices > blocks:
        raise InputError(source, "devices", f"{cfg.devices}: this session has {blocks} blocks of {BLOCK} robots, "
                         "and a device runs whole blocks (at most one device per block)")


def _check_size(cfg, worlds, source: str) -> None:
    """Refuse a session whose logs or batch cannot fit in this machine's memory (the whole
    session is one batch: every world x policy x seed, each policy padded to whole blocks)."""
    env = schedule.env_config(cfg)
    steps = cfg.duration / schedule.control_dt(cfg) / schedule.log_every(cfg)  # logged steps; floats: a huge
    # duration must give a huge estimate, not an overflow
    per_policy = -(-cfg.seeds // BLOCK) * BLOCK * len(worlds)
    batch = float(per_policy * len(cfg.policies))
    need_host = batch * steps * max(w.truth.num_objects for w in worlds) * LOG_BYTES_PER_OBJECT_STEP
    cam = env.camera  # every step's depth and labels, and a chunk's detector frames
    frame_steps = schedule.frame_steps(cfg)
    frames = (schedule.per_call(cfg, schedule.decisions(cfg)) * cfg.decide_every // frame_steps
              if cfg.detector != "off" else 0)
    swept = frames * frame_steps if any(m != "oracle" for m in cfg.mappers) else 0  # steps' depth, for mappers
    need_device = batch * (env_bytes(env) + cam.width * cam.height * SWEEP_BYTES_PER_PIXEL * swept
                           + FRAME_BYTES_PER_PIXEL * frames * cam.rgb_width * cam.rgb_height)
    have = memory_bytes()
    for what, need in (("the logs", need_host), ("the batch's device state", need_device)):
        if need > MEMORY_SHARE * have:
            raise InputError(source, _culprit(cfg, what, need, MEMORY_SHARE * have),
                             f"{cfg.seeds} seeds x {len(worlds)} worlds x {len(cfg.policies)} policies x "
                             f"{cfg.duration:g} s: {what} need about {need / 1e9:,.1f} GB, more than this "
                             f"machine's {have / 1e9:.1f} GB allows (fewer seeds, worlds or a shorter duration)")


def _culprit(cfg, what: str, need: float, limit: float) -> str:
    """The field an oversize refusal names: the batch grows with the seeds; the logs with the
    seeds and the duration, so "seeds" where they need too much even at the default duration."""
    if what.startswith("the batch"):
        return "seeds"
    return "seeds" if need * type(cfg)().duration / cfg.duration > limit else "duration"
