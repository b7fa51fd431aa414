"""The compiled functions of a group (:mod:`rosmeery_jax.session.batch`): reset, the
chunk of decisions, the label update.

**One block program.** ``lax.map`` runs one ``vmap``ped block program over the group's
blocks of ``BLOCK`` envs (:func:`blocked`). The block's policy is chosen with
``lax.switch`` on a per-block index, so only that policy's decision runs (a per-env index
under ``vmap`` would run every policy for every env).

**Several devices.** With ``devices`` N > 1 (GPUs, or host devices made from the CPU's
cores) the blocks are split evenly over the devices (padding blocks make the count a
multiple of N) and every device runs the one-device block program on its share, all at
once (:class:`Replicas`). An SPMD program (``jax.shard_map``) was tried and dropped: XLA
fuses a partitioned program differently, so a robot's numbers changed with N.

Shapes: B envs in a group (a multiple of BLOCK), N objects (padded), F frames per chunk,
D detections per frame.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from rosmeery_jax.core import interrupt, xla
from rosmeery_jax.env import RobotEnv, Track, drive
from rosmeery_jax.env import world_data as wd
from rosmeery_jax.env.decision import Decision, Frames, decide
from rosmeery_jax.session.batch import BLOCK, Group
from rosmeery_jax.session.schedule import Plan
from rosmeery_jax.sim.knowledge import ObjectLog


def blocked(fn, devices: int = 1):
    """jit of ``fn(shared, block, *env_args)`` over B = k * BLOCK envs: ``shared`` goes to
    every env, ``block`` (k, ...) one row per block (the same for its envs, so not batched
    inside it), ``env_args`` (B, ...) one row per env. vmap over a block, ``lax.map`` over
    blocks (module docstring); with ``devices`` > 1, as :class:`Replicas`."""

    def run(shared, block_arg, *env_args):
        blocks = jax.tree.map(lambda a: a.reshape(a.shape[0] // BLOCK, BLOCK, *a.shape[1:]), env_args)
        out = jax.lax.map(lambda x: jax.vmap(fn, in_axes=(None, None) + (0,) * len(env_args))(shared, x[0], *x[1]),
                          (block_arg, blocks))
        return jax.tree.map(lambda a: a.reshape(a.shape[0] * a.shape[1], *a.shape[2:]), out)

    return xla.jit(run) if devices == 1 else Replicas(xla.jit(run), devices)


def shardings(devices: int) -> tuple[NamedSharding, NamedSharding]:
    """(whole, split): a copy on each of the first ``devices`` devices, and the leading
    (batch or block) axis split evenly over them."""
    mesh = Mesh(np.asarray(jax.devices()[:devices]), ("d",))
    return NamedSharding(mesh, PartitionSpec()), NamedSharding(mesh, PartitionSpec("d"))


class Replicas:
    """A blocked function on N devices: each runs the one-device program on its share of
    the blocks, all at once (JAX dispatches asynchronously). Called like the jitted function
    with ``(shared, block_arg, *env_args)``; arguments are placed as global arrays (``shared``
    whole on every device, the rest split over the leading axis) and results come back
    split the same way, so one call's results feed the next without a copy. Follows jax's
    ahead-of-time interface: ``lower(*args).compile()`` compiles every device's copy at once."""

    def __init__(self, jitted, devices: int, executables: list | None = None):
        self.jitted, self.devices, self.executables = jitted, devices, executables
        self.whole, self.split = shardings(devices)

    def _per_device(self, shared, block_arg, env_args) -> list[tuple]:
        """Each device's arguments: its copy of ``shared``, its share of the rest."""
        shared = jax.device_put(shared, self.whole)
        rest = jax.device_put((block_arg, env_args), self.split)

        def local(tree, device):
            return jax.tree.map(lambda a: next(s.data for s in a.addressable_shards if s.device == device), tree)

        return [(local(shared, d), local(rest[0], d), *local(rest[1], d)) for d in self.split.mesh.devices.flat]

    def lower(self, shared, block_arg, *env_args) -> "_Lowered":
        return _Lowered(self, self._per_device(shared, block_arg, env_args))

    def __call__(self, shared, block_arg, *env_args):
        calls = self.executables or [self.jitted] * self.devices
        outs = [f(*args) for f, args in zip(calls, self._per_device(shared, block_arg, env_args))]
        return jax.tree.map(lambda *parts: jax.make_array_from_single_device_arrays(
            (sum(p.shape[0] for p in parts), *parts[0].shape[1:]), self.split, list(parts)), *outs)


class _Lowered(NamedTuple):
    """:meth:`Replicas.lower`'s result: every device's arguments, compiled together."""

    replicas: Replicas
    args: list

    def compile(self) -> Replicas:
        r = self.replicas  # each device's copy in a thread of its own (XLA compiles without the GIL), Ctrl-C
        # honoured while waiting
        jobs = [interrupt.background(lambda a=a: r.jitted.lower(*a).compile(), "compile") for a in self.args]
        return Replicas(r.jitted, r.devices, [interrupt.wait(job) for job in jobs])


def in_world(group: Group, stacked: wd.WorldData, block: jax.Array) -> tuple[RobotEnv, list]:
    """The template env and policies, bound to the world of ``block`` (policy, world) (inside
    a trace; the block's envs share it, so it is not batched under their vmap)."""
    env = group.env.with_data(wd.pick(stacked, block[1]))
    return env, [p.bind(env) for p in group.policies]


def reset_fn(group: Group):
    """(stacked, blocks, key (B,)) -> State (B, ...)."""

    def one(stacked, block, key):
        env, _ = in_world(group, stacked, block)
        return env.reset(key)

    return blocked(one, group.devices)


class Chunk(NamedTuple):
    """One call of the chunk function, per env: the state, policy states and key after it,
    logs (per_call * decide_every / log_every, N), track (per_call * decide_every, ...),
    frames (per_call * frames_per, ...) or None, stamps (S,) or None (``Plan.stamp``)."""

    state: Any
    pstates: tuple
    key: jax.Array
    logs: ObjectLog
    track: Track
    frames: Frames | None
    stamps: jax.Array | None = None


def chunk_fn(group: Group, plan: Plan, capture: bool):
    """One env per call of the returned function (blocked): fold the pending detections
    (F, D) into the knowledge, then ``plan.per_call`` decisions (:func:`_decision`).
    Returns a :class:`Chunk`; frames only with ``capture``, their depth only with
    ``plan.perceive``; with ``plan.stamp`` the function takes the samples' stamps (S,) last
    and returns them updated."""
    spec = plan.decision(capture, group.policies[0].per_step)  # decide checks it

    def one(stacked, block, state, pstates, key, pending, *stamps):
        env, policies = in_world(group, stacked, block)
        if capture:
            state = state._replace(knowledge=attach_frames(env, state.knowledge, *pending))
        decide = _decision(env, policies, block[0], spec)
        (state, pstates, key, stamps), ((logs, track), frames) = jax.lax.scan(
            decide, (state, pstates, key, stamps[0] if stamps else None), None, length=plan.per_call)
        flat = lambda a: a.reshape(a.shape[0] * a.shape[1], *a.shape[2:])  # noqa: E731 (decision, within it)
        return Chunk(state, pstates, key, *jax.tree.map(flat, (logs, track, frames)), stamps)

    return blocked(one, group.devices)


def _decision(env: RobotEnv, policies: list, q: jax.Array, spec: Decision):
    """The scan body of one decision: block policy ``q`` decides (``lax.switch``, so only
    its own decision runs), then :func:`rosmeery_jax.env.decision.decide` steps it. Returns
    logs (decide_every / log_every, N), track (decide_every, ...), frames (frames_per, ...)."""

    def branch(i):
        def choose(s, pss, k):
            action, new = policies[i].decide(s, pss[i], k)
            return action, pss[:i] + (new,) + pss[i + 1:]
        return choose

    def one(carry, _):
        s, pss, k, stamps = carry  # stamps: None unless the decision stamps samples
        k, sub = jax.random.split(k)
        # Always a branch, a lone policy's twice: compiled inline it was fused with the steps
        # around it, and a padded bank of worlds rounded its steps otherwise than beside others
        branches = [branch(i) for i in range(len(policies))] * (2 if len(policies) == 1 else 1)
        action, pss = jax.lax.switch(q, branches, s, pss, sub)
        s, out = decide(env, s, action, spec, stamps=stamps)
        return (s, pss, k, out.stamps), ((out.logs, out.track), out.frames)

    return one


def attach_frames(env: RobotEnv, knowledge, obj, label, conf):
    """Fold detections (F, D) into ``knowledge`` frame by frame, in frame order."""

    def body(k, d):
        return env.sk.attach(k, *d), None

    return jax.lax.scan(body, knowledge, (obj, label, conf))[0]


def label_fn(group: Group):
    """(stacked, blocks, labels, obj, label, conf (B, F, D)) -> labels after the frames and
    the log's label fields after each frame (B, F, N) each."""

    def one(stacked, block, k, obj, label, conf):
        env, _ = in_world(group, stacked, block)

        def body(k, d):
            k = env.sk.attach(k, *d)
            return k, env.sk.label_fields(k)

        return jax.lax.scan(body, k, (obj, label, conf))

    return blocked(one, group.devices)


def drive_fn(group: Group, steps: int, stream: int):
    """The executed tasks' program (:mod:`rosmeery_jax.session.objectnav`), blocked: per env
    its map logodds (H, W) and S drives (:mod:`rosmeery_jax.env.drive`) with their goals (S,
    3); drives flagged ``again`` (S,) start afresh at ``starts`` (S, 3) first, their key the
    env's ``seeds`` (S,) key folded with ``stream`` and ``copies`` (S,). Each drive then
    advances ``steps`` control steps. Returns the drives."""

    def one(stacked, block, logodds, drives, goals, again, starts, seeds, copies):
        env, _ = in_world(group, stacked, block)

        def slot(d, goal, fresh, pose, seed, copy):
            key = jax.random.fold_in(jax.random.fold_in(jax.random.key(seed), stream), copy)
            d = jax.tree.map(lambda a, b: jax.numpy.where(fresh, a, b), drive.start(env, pose, logodds, key), d)
            return drive.advance(env, d, goal, logodds, steps)

        return jax.vmap(slot)(drives, goals, again, starts, seeds, copies)

    return blocked(one, group.devices)


class Compiled(NamedTuple):
    reset: Any
    chunk: Any
    label: Any
    log: Any
    knowledge: Any

