"""One decision of one robot: up to ``steps`` control steps toward one action, keeping what
the caller asks for (the per-object log, the track, camera frames).

This is the package's only loop over control steps: a session's chunk function, the
gymnax ``ExplorationEnv`` and the Gymnasium envs each call :func:`decide` once per
decision (a policy's ``decide``, an agent's ``act`` or an RL action gives the action), and
``vmap`` it over their robots. Shapes: F frames, L log rows, N objects, per decision.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from rosmeery_jax.env.environment import RobotEnv, State, Track
from rosmeery_jax.sim import noise
from rosmeery_jax.sim.knowledge import ObjectLog


class Decision(NamedTuple):
    """What one decision keeps (static: a compiled function is built for one).

    ``steps`` control steps; a per-object log row every ``log_every`` of them (0: none);
    ``track``: the pose and navigation status of every step; an RGB-D frame after every
    ``frame_steps`` (0: none; a divisor of ``steps``, and ``log_every`` of it), with its
    depth (``frame_depth``) and the depth camera of each step of its period (``sweep``);
    ``per_step``: the action holds one command per step, (steps, ...), as a replayed
    recording does; ``stamp``: keep, per ground-truth sample, the step of the first log row
    that counts it observed (the built-in knowledge's map at any logged time, for the field
    map metrics)."""

    steps: int
    log_every: int = 0
    track: bool = False
    frame_steps: int = 0
    frame_depth: bool = False
    sweep: bool = False
    per_step: bool = False
    stamp: bool = False

    @property
    def period(self) -> int:
        """Control steps between frames (the whole decision without frames)."""
        return self.frame_steps or self.steps

    @property
    def frames_per(self) -> int:
        """Frame periods per decision."""
        return self.steps // self.period

    @property
    def span(self) -> int:
        """Control steps between log rows (a frame period without a log)."""
        return self.log_every or self.period

    @property
    def spans(self) -> int:
        """Log spans per frame period."""
        return self.period // self.span

    def check(self) -> "Decision":
        if self.steps < 1 or self.steps % self.period or self.period % self.span:
            raise ValueError(f"a decision of {self.steps} steps needs frame_steps {self.frame_steps} dividing it "
                             f"and log_every {self.log_every} dividing the frame period")
        return self


class Frames(NamedTuple):
    """A decision's frames (F = steps / frame_steps): rgb (F, Hr, Wr, 3) uint8, labels (F,
    Hr, Wr) int16, depth (F, Hr, Wr) float32 or None, and sweep (F, frame_steps, h, w)
    float32 (the depth camera after every step of the frame's period) or None."""

    rgb: jax.Array
    labels: jax.Array
    depth: jax.Array | None
    sweep: jax.Array | None = None


class Outcome(NamedTuple):
    """What a decision kept: logs (L, N) fields or None, track (steps, ...) or None, frames
    or None, steps: the control steps it took (int32; fewer than ``steps`` only when an
    ``until`` ended it), and stamps (S,) int32 with ``Decision.stamp``: per sample, the
    step of the first log row counting it observed (-1: none yet)."""

    logs: ObjectLog | None
    track: Track | None
    frames: Frames | None
    steps: jax.Array
    stamps: jax.Array | None = None


def decide(env: RobotEnv, state: State, action, spec: Decision,
           until: Callable[[jax.Array, State], jax.Array] | None = None,
           stamps: jax.Array | None = None) -> tuple[State, Outcome]:
    """Step ``state`` through one decision toward ``action``. With ``until(i, state)``, a
    step is taken only while it holds (``i`` steps taken so far), up to ``spec.steps``: a
    decision that lasts as long as the drive (nothing is kept then). ``stamps`` (S,): the
    samples' first-observed steps so far, with ``spec.stamp``."""
    if spec.stamp and (stamps is None or not spec.log_every):
        raise ValueError("a decision that stamps samples needs log rows and the stamps so far")
    if until is not None:
        return _until(env, state, action, spec.steps, until)
    if not (spec.log_every or spec.track or spec.frame_steps):
        state = jax.lax.fori_loop(0, spec.steps, lambda _, s: env.step(s, action), state)
        return state, Outcome(None, None, None, jnp.int32(spec.steps))
    return _kept(env, state, action, spec.check(), stamps if spec.stamp else None)


def _until(env: RobotEnv, state: State, action, steps: int, until) -> tuple[State, Outcome]:
    def more(carry):
        i, s = carry
        return (i < steps) & until(i, s)

    taken, state = jax.lax.while_loop(more, lambda c: (c[0] + 1, env.step(c[1], action)), (jnp.int32(0), state))
    return state, Outcome(None, None, None, taken)


def _kept(env: RobotEnv, state: State, action, spec: Decision, stamps) -> tuple[State, Outcome]:
    """Frame periods of log spans of steps, as nested scans: logs (L, N), track (steps, ...),
    frames (F, ...), stamps (S,) or None (None adds nothing to the scans' carry)."""

    def step(s, a):
        s = env.step(s, a if spec.per_step else action)
        return s, (Track.of(s), env.sensed(s, s.depth, stream=noise.SWEEP)[0] if spec.sweep else None)

    def span(carry, a):  # log_every steps, then the log: logging every step took 7 % of a paper
        # session's step, and its metrics are written once a second
        s, st = carry
        s, track = jax.lax.scan(step, s, a, length=spec.span)
        if st is not None:
            st = jnp.where((st < 0) & (jnp.asarray(s.knowledge.seen, jnp.float32) > 0.5), s.t, st)
        return (s, st), (env.log(s) if spec.log_every else None, track)

    def period(carry, a):  # frame_steps steps, then the frame
        (s, st), (logs, (track, depths)) = jax.lax.scan(span, carry, a, length=spec.spans)
        frame = None
        if spec.frame_steps:
            img, dep, lab = env.camera_rgbd(s)
            dep, img = env.sensed(s, dep, img)  # as the robot's cameras report them (noise, when set)
            frame = Frames(img, lab.astype(jnp.int16), dep if spec.frame_depth else None,
                           depths.reshape(spec.period, *depths.shape[2:]) if spec.sweep else None)
        return (s, st), ((logs, track), frame)

    shape = (spec.frames_per, spec.spans, spec.span)
    actions = jax.tree.map(lambda a: a.reshape(*shape, *a.shape[1:]), action) if spec.per_step else None
    if spec.frames_per == 1:  # one frame per decision (a session's default): no scan of one
        # around the period, which XLA is free to compile differently
        (state, stamps), out = period((state, stamps), jax.tree.map(lambda a: a[0], actions))
        out = jax.tree.map(lambda a: a[None], out)
    else:
        (state, stamps), out = jax.lax.scan(period, (state, stamps), actions, length=spec.frames_per)
    (logs, track), frames = out  # (frames_per, spans, ...), frames (frames_per, ...)
    logs = jax.tree.map(lambda a: a.reshape(spec.frames_per * spec.spans, *a.shape[2:]), logs)
    track = jax.tree.map(lambda a: a.reshape(spec.steps, *a.shape[3:]), track) if spec.track else None
    return state, Outcome(logs, track, frames, jnp.int32(spec.steps), stamps)
