"""A session's clock: how its duration is cut into decisions, detector frames, log rows
and jitted calls (:class:`Plan`), from a :class:`~rosmeery_jax.session.config.SessionConfig`.
Each function raises one InputError naming the field when the durations do not divide."""

from __future__ import annotations

import math
from dataclasses import fields
from typing import NamedTuple

import numpy as np

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.overrides import flatten
from rosmeery_jax.env import EnvConfig
from rosmeery_jax.env.decision import Decision
from rosmeery_jax.mapping.built_ins import mapper_for
from rosmeery_jax.metrics import field, tasks
from rosmeery_jax.metrics.indices import expand
from rosmeery_jax.rl.task import STEP_LIMIT
from rosmeery_jax.sim import noise


def _session_overrides(cfg) -> dict:
    """The noise preset's parameters and the localisation, where they are not the defaults."""
    preset = noise.preset(cfg.noise)
    out = {f"noise__{f.name}": getattr(preset, f.name) for f in fields(preset)
           if getattr(preset, f.name) != f.default}
    if cfg.localisation != EnvConfig.localisation:
        out["localisation"] = cfg.localisation
    return out


def env_overrides(cfg) -> dict:
    """The EnvConfig overrides of a session, flat: its noise preset's parameters and its
    localisation, then its ``env`` table (which may set any of them again)."""
    return {**_session_overrides(cfg), **flatten(cfg.env)}


def env_config(cfg) -> EnvConfig:
    """The env configuration of the session's robots (:func:`env_overrides` applied; an
    error in the ``env`` table names its key as the file spells it)."""
    return EnvConfig.from_table(cfg.env, base=EnvConfig().with_overrides("config", **_session_overrides(cfg)))


def control_dt(cfg) -> float:
    """The control period in seconds (one env step): the robot's, never restated here."""
    return env_config(cfg).robot.control_dt


def decisions(cfg) -> int:
    """Policy decisions in one run; the duration must be a whole number of them."""
    dt = control_dt(cfg)
    period = dt * cfg.decide_every
    if not math.isfinite(cfg.duration):
        raise InputError("config", "duration", f"{cfg.duration} must be a finite number of seconds")
    if cfg.duration / dt > STEP_LIMIT:  # steps are counted in int32 (and 1e308 s hung the checks below)
        raise InputError("config", "duration", f"{cfg.duration:g} s is more control steps of {dt:g} s than "
                         f"a session counts ({STEP_LIMIT}): at most {STEP_LIMIT * dt:g} s")
    n = int(round(cfg.duration / period))
    if n < 1 or abs(n * period - cfg.duration) > 1e-6:
        raise InputError("config", "duration", f"{cfg.duration} s is not a whole number of decision periods "
                         f"({period:g} s = decide_every x {dt:g} s)")
    return n


def detector_period(cfg) -> int:
    """Decisions per detector period, whose boundaries the label schedule is cut at: a
    whole number of them that divides the run's (a period as long as the run or longer is
    the run), or one InputError naming the nearest periods that are."""
    dt = control_dt(cfg)
    total, period = decisions(cfg), dt * cfg.decide_every
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


def per_call(cfg, total: int) -> int:
    """Decisions per jitted call: the detector period with a detector (the label schedule
    is cut at its boundaries), else ``chunk_s`` (progress granularity only, so the largest
    that divides the run), so one compiled function serves."""
    dt = control_dt(cfg)
    if cfg.detector != "off":
        return detector_period(cfg)
    want = max(1, int(round(cfg.chunk_s / (dt * cfg.decide_every))))
    return max(d for d in _divisors(total) if d <= want)


def frame_steps(cfg) -> int:
    """Control steps between detector frames."""
    return cfg.detect_every or cfg.decide_every


def log_every(cfg) -> int:
    """Steps between the engine's per-object logs: a divisor of ``sample_s`` in steps (the
    rows metrics.csv keeps) and of the frame period (the chunk function logs within each
    frame's steps; it divides ``decide_every``)."""
    return math.gcd(sample_steps(cfg), frame_steps(cfg))


def sample_steps(cfg) -> int:
    """Control steps between the rows of metrics.csv: ``sample_s`` must be a whole number
    of control periods."""
    dt = control_dt(cfg)
    n = int(round(cfg.sample_s / dt))
    if n < 1 or abs(n * dt - cfg.sample_s) > 1e-6:
        raise InputError("config", "sample_s", f"{cfg.sample_s:g} s is not a whole number of control periods "
                         f"({dt:g} s)")
    return n


def sampled_rows(cfg) -> np.ndarray:
    """(K,) the engine's log rows (one every ``log_every`` steps) that metrics.csv keeps:
    one every ``sample_s`` and the last."""
    every_log = log_every(cfg)
    rows = decisions(cfg) * cfg.decide_every // every_log + 1
    return np.unique(np.r_[np.arange(0, rows, sample_steps(cfg) // every_log), rows - 1])


def frames_before(cfg, steps: np.ndarray) -> np.ndarray:
    """Detector frames that count at each step (a frame taken at its period's last step
    counts from the step after it, as labels do)."""
    return np.maximum(np.asarray(steps) - 1, 0) // frame_steps(cfg)


def task_query(cfg) -> tasks.TaskQuery | None:
    """The task metrics ``cfg`` scores, with its episodes and attempts (None: none)."""
    names = tasks.wanted(expand(cfg.metrics))
    return tasks.TaskQuery(names, cfg.task_episodes, cfg.task_attempts) if names else None


class Plan(NamedTuple):
    """How a group is stepped: ``total`` decisions, ``per_call`` of them per jitted call,
    ``decide_every`` control steps per decision, a detector frame every ``frame_steps``
    steps (a divisor of ``decide_every``), a log row every ``log_every`` steps (a divisor of
    ``frame_steps``); ``mappers``: the mapper entries fed every detector frame per env
    (needs detectors), their maps scored after each frame count in ``score_at``; ``field``:
    the field map metrics scored on their maps; ``task``: the task metrics too (None: none);
    ``stamp``: the samples' first-observed steps are kept (the built-in knowledge's map over
    time, for those metrics)."""

    total: int
    per_call: int
    decide_every: int
    frame_steps: int
    log_every: int = 1
    mappers: tuple[str, ...] = ()
    score_at: frozenset = frozenset()
    digest: bool = False  # a digest of each env's state after every chunk (session.digest)
    field: tuple[str, ...] = ()
    stamp: bool = False
    task: tasks.TaskQuery | None = None
    drives: tasks.TaskQuery | None = None  # task "objectnav": the episodes the robots drive after exploring

    @staticmethod
    def of(cfg) -> "Plan":
        """The plan of a session configuration's runs (the same for every group)."""
        total = decisions(cfg)
        names = field.wanted(expand(cfg.metrics))
        task = task_query(cfg)
        return Plan(total, per_call(cfg, total), cfg.decide_every, frame_steps(cfg), log_every(cfg),
                    tuple(m for m in cfg.mappers if m != "oracle"),
                    frozenset(frames_before(cfg, sampled_rows(cfg) * log_every(cfg)).tolist()), cfg.digest,
                    names, bool(names or task) and "oracle" in cfg.mappers, task,
                    tasks.TaskQuery((), cfg.task_episodes, cfg.task_attempts) if cfg.task == "objectnav" else None)

    @property
    def frames_per(self) -> int:
        """Detector frames per decision."""
        return self.decide_every // self.frame_steps

    @property
    def frames_per_call(self) -> int:
        """Detector frames per jitted call."""
        return self.per_call * self.frames_per

    @property
    def perceive(self) -> bool:
        """Whether frames carry their depth (a mapper reads it)."""
        return bool(self.mappers)

    @property
    def sweep(self) -> bool:
        """Whether frames carry the depth of every step (a mapper overrides ``add_depth``)."""
        return any(mapper_for(spec).reads_depth() for spec in self.mappers)

    def decision(self, capture: bool, per_step: bool = False) -> Decision:
        """What each decision keeps: logs and track always; frames with ``capture``."""
        return Decision(self.decide_every, self.log_every, True, self.frame_steps if capture else 0,
                        self.perceive, capture and self.sweep, per_step, self.stamp)
