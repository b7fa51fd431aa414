"""The session engine: every (world, policy, seed) of a session in one batch, one compiled
chunk function, the detector overlapped with the simulation.

**Worlds are data.** The session's worlds are padded to shared sizes and stacked
(:mod:`rosmeery_jax.env.world_data`); each env gathers its own world inside the compiled
function, so adding a world adds rows, not a compile. A *group* is every entry that shares
one env configuration: all built-in policies share one, so the default and paper sessions
compile one chunk function; replayed recordings run in velocity mode and form a group of
their own.

**Blocks.** XLA compiles a different program for every batch shape, and programs of
different shapes round differently. The batch is therefore cut into blocks of ``BLOCK``
envs, each block one policy (a policy's entries are padded to whole blocks), and
``lax.map`` runs one ``vmap``ped block program over them: an env's numbers are the same
whatever runs beside it. The block's policy is chosen with ``lax.switch`` on a per-block
index, so only that policy's decision runs (a per-env index under ``vmap`` would run every
policy for every env).

**Several devices.** With ``devices`` N > 1 (GPUs, or host devices made from the CPU's
cores) the blocks are split evenly over the devices (padding blocks make the count a
multiple of N) and every device runs the one-device block program on its share, all at
once (:class:`Replicas`). An SPMD program (``jax.shard_map``) was tried and dropped: XLA
fuses a partitioned program differently, so a robot's numbers changed with N.

**The detector overlaps the simulation.** Chunk k's frames are detected in a worker thread
while chunk k + 1 simulates. The robot's knowledge receives the detections on a fixed
simulated-time schedule, part of the experiment: the frames of detector period p (one RGB
frame per decision by default, or one every ``detect_every`` steps) are folded in at the
start of period p + 2, so a label reaches the policy one to two periods after its frame,
whatever the chunking. The metrics' label fields are rebuilt afterwards without that lag:
a frame counts from the step after it, so the run's last frame never counts, and the final
labels (objects table, exported maps) are those of the last logged step.

Shapes: B envs in a group (a multiple of BLOCK), T steps, N objects (padded), F frames per
chunk, D detections per frame.
"""

from __future__ import annotations

import collections
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from rosmeery_jax.core import interrupt, xla
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.overrides import flatten
from rosmeery_jax.detector.detections import pad
from rosmeery_jax.env import Env, EnvConfig, Track, world_bank
from rosmeery_jax.env import world_data as wd
from rosmeery_jax.policies import make_policy, policy_class
from rosmeery_jax.scoring.evaluate import TOLERANCE
from rosmeery_jax.scoring.mapper import (Camera, DepthFrame, Frame, MapState, OnlineScorer, check_map, mapper_class,
                                         raised_by)
from rosmeery_jax.scoring.perceived import PerceivedMapper
from rosmeery_jax.sim.knowledge import ObjectLog
from rosmeery_jax.session import digest
from rosmeery_jax.world import load_world

BLOCK = 5  # envs per compiled block (module docstring): 5 seeds, the paper's and the default, fill one
QUEUED_CHUNKS = 2  # chunks dispatched and not yet run: one runs while the next waits its turn
MAX_DET = 32  # detections kept per frame (the most confident)
LABEL_FIELDS = ("conf_true", "conf_any", "label", "declared", "correct")


class Run(NamedTuple):
    """One (world, policy) pair: its rows in the group's batch (one per seed or recording)."""

    name: str
    world: int
    policy: int
    rows: np.ndarray
    host_policy: Any  # the policy built for this world (recordings, start checks)
    spec: str  # the policy entry, as the config names it
    seeds: range  # one per row: the session's, or a replay's recordings numbered from 0


@dataclass
class Group:
    """Entries that share one env configuration, as one batch of B envs.

    env: the template env (the group's first world at the padded sizes); envs: one per world
    (host side: world, truth); data: the stacked worlds (W, ...); policies: one template per
    policy entry; world / seed / real (B,) per env; blocks (B // BLOCK, 2) the policy and
    world of each block (every run is padded to whole blocks)."""

    config: EnvConfig
    env: Env
    envs: list[Env]
    data: wd.WorldData
    policies: list
    world: np.ndarray
    seed: np.ndarray
    real: np.ndarray
    blocks: np.ndarray
    runs: list[Run]
    devices: int = 1

    @property
    def size(self) -> int:
        return len(self.world)


@dataclass
class _Rows:
    """The batch being laid out: per env its world, seed and whether it is real; per block
    its (policy, world)."""

    world: list = field(default_factory=list)
    seed: list = field(default_factory=list)
    real: list = field(default_factory=list)
    blocks: list = field(default_factory=list)

    def add_block_run(self, policy: int, world: int, seeds: range) -> np.ndarray:
        """Rows for one run's ``seeds``, padded to whole blocks; returns the real rows."""
        size = len(seeds)
        rows = np.arange(len(self.world), len(self.world) + size)
        padded = -(-size // BLOCK) * BLOCK
        self.world += [world] * padded
        self.seed += [(seeds.start + i) % 2**31 for i in range(padded)]  # padding continues them (int32 keys)
        self.real += [True] * size + [False] * (padded - size)
        self.blocks += [(policy, world)] * (padded // BLOCK)
        return rows

    def add_padding_block(self) -> None:
        """A copy of the last block with no real env (whole blocks per device)."""
        policy, world = self.blocks[-1]
        self.blocks.append((policy, world))
        self.world += [world] * BLOCK
        self.seed += list(range(BLOCK))
        self.real += [False] * BLOCK


def build_groups(pairs: list[tuple[str, str]], session_env: dict, detecting: bool, seeds: range,
                 decide_every: int, total_steps: int, devices: int = 0) -> list[Group]:
    """The groups of (world spec, policy spec) pairs; runs with no entries are left out.
    ``devices`` 0 uses every device JAX has, or one per block when there are fewer blocks;
    with more than one, padding blocks (copies of the last, no real env) make the number of
    blocks a multiple of it."""
    by_config: dict[EnvConfig, list] = {}
    for world, spec in pairs:
        name = load_world(world).name
        overrides = {"labels": "detections" if detecting else "observed", **flatten(session_env),
                     **policy_class(spec).env_overrides(spec, name)}
        config = EnvConfig().with_overrides("config", **overrides)
        by_config.setdefault(config, []).append((world, spec))
    groups = [_group(config, members, seeds, decide_every, total_steps, devices) for config, members in by_config.items()]
    return [g for g in groups if g.runs]


def _group(config: EnvConfig, members: list, seeds: range, decide_every: int, total_steps: int,
           devices: int) -> Group:
    """One group: its worlds as one padded bank, its policies, its runs laid out in blocks."""
    specs = list(dict.fromkeys(w for w, _ in members))
    bank = world_bank(specs, config)
    envs = bank.envs()
    policy_specs = list(dict.fromkeys(p for _, p in members))
    policies = [make_policy(p, envs[0], decide_every, total_steps) for p in policy_specs]
    rows, runs = _Rows(), []
    for q, spec in enumerate(policy_specs):
        for world, p in members:
            if p != spec:
                continue
            w = specs.index(world)
            host = make_policy(spec, envs[w], decide_every, total_steps)
            mine = host.seeds(seeds)
            if mine:  # else a replay with no recording in this world
                runs.append(Run(f"{envs[w].world.name}__{policies[q].name}", w, q, rows.add_block_run(q, w, mine),
                                host, spec, mine))
    used = devices or max(1, min(len(jax.devices()), len(rows.blocks)))  # auto: no device without a real block
    for _ in range((-len(rows.blocks)) % used if runs else 0):  # whole blocks per device
        rows.add_padding_block()
    return Group(config, envs[0], envs, bank.data, policies, np.asarray(rows.world, np.int32),
                 np.asarray(rows.seed, np.int32), np.asarray(rows.real), np.asarray(rows.blocks, np.int32), runs, used)


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
        r = self.replicas
        with ThreadPoolExecutor(r.devices) as pool:  # XLA compiles without the GIL
            return Replicas(r.jitted, r.devices, list(pool.map(lambda a: r.jitted.lower(*a).compile(), self.args)))


def _in_world(group: Group, stacked: wd.WorldData, block: jax.Array) -> tuple[Env, list]:
    """The template env and policies, bound to the world of ``block`` (policy, world) (inside
    a trace; the block's envs share it, so it is not batched under their vmap)."""
    env = group.env.with_data(wd.pick(stacked, block[1]))
    return env, [p.bind(env) for p in group.policies]


def reset_fn(group: Group):
    """(stacked, blocks, key (B,)) -> State (B, ...)."""

    def one(stacked, block, key):
        env, _ = _in_world(group, stacked, block)
        return env.reset(key)

    return blocked(one, group.devices)


class Plan(NamedTuple):
    """How a group is stepped: ``total`` decisions, ``per_call`` of them per jitted call,
    ``decide_every`` control steps per decision, a detector frame every ``frame_steps``
    steps (a divisor of ``decide_every``), a log row every ``log_every`` steps (a divisor of
    ``frame_steps``); ``mappers``: the mapper entries fed every detector frame per env
    (needs detectors), their maps scored after each frame count in ``score_at``."""

    total: int
    per_call: int
    decide_every: int
    frame_steps: int
    log_every: int = 1
    mappers: tuple[str, ...] = ()
    score_at: frozenset = frozenset()
    digest: bool = False  # a digest of each env's state after every chunk (session.digest)

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
        return any(_mapper_cls(spec).reads_depth() for spec in self.mappers)

    @property
    def spans(self) -> int:
        """Logged spans per detector frame period."""
        return self.frame_steps // self.log_every


def _mapper_cls(spec: str) -> type:
    """A mapper entry's class: the built-in perceived mapper or a plugin."""
    return PerceivedMapper if spec == "perceived" else mapper_class(spec)


class Frames(NamedTuple):
    """The detector frames, one every ``frame_steps`` control steps, per env: rgb (F, Hr,
    Wr, 3) uint8, labels (F, Hr, Wr) int16, depth (F, Hr, Wr) float32 (None unless a mapper
    runs); and sweep (F, frame_steps, h, w) float32, the depth camera after every step of
    the frame's period (None unless a mapper reads it)."""

    rgb: jax.Array
    labels: jax.Array
    depth: jax.Array | None
    sweep: jax.Array | None = None


class Chunk(NamedTuple):
    """One call of the chunk function, per env: the state, policy states and key after it,
    logs (per_call * decide_every / log_every, N), track (per_call * decide_every, ...),
    frames (per_call * frames_per, ...) or None."""

    state: Any
    pstates: tuple
    key: jax.Array
    logs: ObjectLog
    track: Track
    frames: Frames | None


def chunk_fn(group: Group, plan: Plan, capture: bool):
    """One env per call of the returned function (blocked): fold the pending detections
    (F, D) into the knowledge, then ``plan.per_call`` decisions (:func:`_decision`).
    Returns a :class:`Chunk`; frames only with ``capture``, their depth only with
    ``plan.perceive``."""
    if plan.decide_every % plan.frame_steps or plan.frame_steps % plan.log_every:
        raise ValueError(f"log_every {plan.log_every} must divide the frame period {plan.frame_steps}, and the "
                         f"frame period decide_every {plan.decide_every}")

    def one(stacked, block, state, pstates, key, pending):
        env, policies = _in_world(group, stacked, block)
        if capture:
            state = state._replace(knowledge=attach_frames(env, state.knowledge, *pending))
        decide = _decision(env, policies, block[0], plan, capture)
        (state, pstates, key), ((logs, track), frames) = jax.lax.scan(decide, (state, pstates, key), None,
                                                                      length=plan.per_call)
        flat = lambda a: a.reshape(a.shape[0] * a.shape[1], *a.shape[2:])  # noqa: E731 (decision, within it)
        return Chunk(state, pstates, key, *jax.tree.map(flat, (logs, track, frames)))

    return blocked(one, group.devices)


def _decision(env: Env, policies: list, q: jax.Array, plan: Plan, capture: bool):
    """The scan body of one decision: block policy ``q`` decides (``lax.switch``, so only
    its own decision runs), then ``decide_every`` env steps, logged every ``log_every``;
    with ``capture``, a frame after every ``frame_steps`` of them. Returns logs
    (decide_every / log_every, N), track (decide_every, ...), frames (frames_per, ...)."""
    per_step = policies[0].per_step
    sweep = plan.sweep

    def branch(i):
        def decide(s, pss, k):
            action, new = policies[i].decide(s, pss[i], k)
            return action, pss[:i] + (new,) + pss[i + 1:]
        return decide

    def step(s, a, action):
        s = env.step(s, a if per_step else action)
        return s, (Track.of(s), s.depth if sweep else None)

    def span(s, a, action):  # log_every steps, then the log: the per-object log took 7 % of a
        # paper session's step when taken every step, and metrics are written every sample_s
        s, track = jax.lax.scan(lambda s, a: step(s, a, action), s, a, length=plan.log_every)
        return s, (env.log(s), track)

    def period(s, a, action):  # frame_steps steps, then the detector frame
        s, (logs, (track, depths)) = jax.lax.scan(lambda s, a: span(s, a, action), s, a, length=plan.spans)
        frame = None
        if capture:
            img, dep, lab = env.camera_rgbd(s)
            frame = Frames(img, lab.astype(jnp.int16), dep if plan.perceive else None,
                           depths.reshape(plan.frame_steps, *depths.shape[2:]) if sweep else None)
        return s, ((logs, track), frame)

    def steps(s, action):
        """The decision's steps, ``frames_per`` periods of them: logs (decide_every /
        log_every, N), track (decide_every, ...), frames (frames_per, ...)."""
        shape = (plan.frames_per, plan.spans, plan.log_every)
        actions = jax.tree.map(lambda a: a.reshape(*shape, *a.shape[1:]), action) if per_step else None
        if plan.frames_per == 1:  # the default, one frame per decision: no scan of one around the
            # period, which XLA is free to compile differently
            s, out = period(s, jax.tree.map(lambda a: a[0], actions), action)
            out = jax.tree.map(lambda a: a[None], out)
        else:
            s, out = jax.lax.scan(lambda s, a: period(s, a, action), s, actions, length=plan.frames_per)
        (logs, track), frames = out  # (frames_per, spans, ...), frames (frames_per, ...)
        logs = jax.tree.map(lambda a: a.reshape(plan.frames_per * plan.spans, *a.shape[2:]), logs)
        track = jax.tree.map(lambda a: a.reshape(plan.decide_every, *a.shape[3:]), track)
        return s, ((logs, track), frames)

    def decide(carry, _):
        s, pss, k = carry
        k, sub = jax.random.split(k)
        if len(policies) == 1:
            action, pss = branch(0)(s, pss, sub)
        else:
            action, pss = jax.lax.switch(q, [branch(i) for i in range(len(policies))], s, pss, sub)
        s, out = steps(s, action)
        return (s, pss, k), out

    return decide


def attach_frames(env: Env, knowledge, obj, label, conf):
    """Fold detections (F, D) into ``knowledge`` frame by frame, in frame order."""

    def body(k, d):
        return env.sk.attach(k, *d), None

    return jax.lax.scan(body, knowledge, (obj, label, conf))[0]


def label_fn(group: Group):
    """(stacked, blocks, labels, obj, label, conf (B, F, D)) -> labels after the frames and
    the log's label fields after each frame (B, F, N) each."""

    def one(stacked, block, k, obj, label, conf):
        env, _ = _in_world(group, stacked, block)

        def body(k, d):
            k = env.sk.attach(k, *d)
            return k, env.sk.label_fields(k)

        return jax.lax.scan(body, k, (obj, label, conf))

    return blocked(one, group.devices)


class Compiled(NamedTuple):
    reset: Any
    chunk: Any
    label: Any
    log: Any
    knowledge: Any


class Simulation(NamedTuple):
    """A group's results, real envs only, in row order. logs: ObjectLog (B, T / log_every +
    1, N), at steps 0, log_every, 2 log_every, ...; track (B, T + 1, ...) at every step;
    knowledge: the final labelled knowledge (batched); timing; mapped: per mapper entry, one
    :class:`Mapped` per env."""

    logs: ObjectLog
    track: Track
    knowledge: Any
    timing: dict
    mapped: dict | None = None
    log_every: int = 1
    digests: list | None = None  # per chunk: {part: (B,) digests} (session.digest)


class Keys(NamedTuple):
    """Per env (B,): the reset's, the policies' and the run's keys, all from its seed."""

    env: jax.Array
    policy: jax.Array
    run: jax.Array

    @staticmethod
    def of(group: Group) -> "Keys":
        keys = jax.vmap(jax.random.key)(jnp.asarray(group.seed))
        return Keys(*(jax.vmap(lambda k, i=i: jax.random.fold_in(k, i))(keys) for i in range(3)))


class Start(NamedTuple):
    """A group compiled and reset: its functions, the compiled chunk function, the first
    state and policy states, the log at step 0, and (with a detector) the metrics' label
    state with its compiled update."""

    fns: Compiled
    chunk: Any
    state: Any
    pstates: tuple
    first_log: ObjectLog
    labels: Any
    attach: Any


def simulate(group: Group, plan: Plan, detectors: dict | None, bar, clock: "CompileClock") -> Simulation:
    """Step the group to its end: ``plan.total`` decisions, ``plan.per_call`` per jitted
    call; chunk c's frames are detected in a worker thread (:class:`_Detection`) while
    chunk c + 1 simulates, and reach the robot at the start of chunk c + 2."""
    capture = detectors is not None
    keys = Keys.of(group)
    data, blocks = group.data, jnp.asarray(group.blocks)
    if group.devices > 1:  # placed once: every call's arguments are then where they belong
        whole, split = shardings(group.devices)
        data, blocks = jax.device_put(data, whole), jax.device_put(blocks, split)
    pending = plan.frames_per_call if capture else 1
    empty = tuple(jnp.asarray(a) for a in _no_detections(group.size, pending)[:3])
    xla_before = dict(CompileClock._counts)
    ready = _prepare(detectors, group.config.camera) if capture else None
    with clock:
        start = _start(group, plan, capture, data, blocks, keys, empty)
    track0 = jax.tree.map(np.asarray, Track.of(start.state))
    for run in group.runs:
        run.host_policy.check_start(track0.pose[run.rows])
    worker = _Detection(group, plan, detectors, start, data, blocks, bar, ready)
    state, pstates, key, jobs, wait_s, digests = start.state, start.pstates, keys.run, [], 0.0, []
    queued = collections.deque()  # the key each dispatched chunk returns: ready once that chunk has run
    try:
        with interrupt.deferred():  # Ctrl-C between chunks, never inside a JAX callback
            for c in range(plan.total // plan.per_call):
                interrupt.check()  # Ctrl-C stops a session here, between chunks (core.interrupt)
                _raise_failed(jobs)
                pending = empty
                if capture and c >= 2:  # the detections of period c - 2 reach the robot now
                    jax.block_until_ready(state)  # chunk c - 1 simulated: what follows is waiting for the detector
                    t1 = time.perf_counter()
                    pending = tuple(jnp.asarray(d) for d in jobs[c - 2].result().dets[:3])
                    wait_s += time.perf_counter() - t1
                if len(queued) == QUEUED_CHUNKS:  # else JAX queues the whole run at once: Ctrl-C would
                    jax.block_until_ready(queued.popleft())  # wait for all of it, its outputs all held
                out = start.chunk(data, blocks, state, pstates, key, pending)
                state, pstates, key = out.state, out.pstates, out.key
                queued.append(key)
                jobs.append(worker.submit(c, out.logs, out.track, out.frames))
                if plan.digest:  # waits for the chunk: a debugging aid, not for timed runs
                    digests.append(digest.of_state(state))
    except BaseException:  # Ctrl-C or an error: queued detections are dropped, not waited for
        worker.pool.shutdown(wait=False, cancel_futures=True)
        raise
    done = [j.result() for j in jobs]
    worker.close()
    real = int(group.real.sum())
    timing = {"envs": real, "padded_envs": group.size, "env_steps": real * plan.total * plan.decide_every,
              **worker.timing, "wait_s": wait_s, "sim_s": time.perf_counter() - worker.started,
              "compiles": 1,  # the chunk function: one per group
              "xla_compiles": CompileClock._counts["compiles"] - xla_before["compiles"],
              "cache_hits": CompileClock._counts["cache_hits"] - xla_before["cache_hits"]}
    if plan.digest:
        for part, d in zip(digests, done):
            part["detections"] = digest.rows(d.dets) if d.dets is not None else [""] * group.size
    return _collect(group, start, state, data, blocks, track0, done, worker, timing)._replace(
        digests=[{k: [v[r] for r in np.flatnonzero(group.real)] for k, v in part.items()} for part in digests]
        if plan.digest else None)


def _raise_failed(jobs: list[Future]) -> None:
    """The error of a chunk the worker has finished with one, now rather than at the end."""
    for job in jobs:
        if job.done() and job.exception() is not None:
            job.result()


def _check_poses(group: Group, first_step: int, poses: np.ndarray) -> None:
    """One line naming the run, seed and time of the first real robot whose pose is not
    finite in ``poses`` (B, steps, 3), steps from ``first_step`` + 1: every later figure of
    its run would be void. A target that is not finite is unreachable (``sim.navigation``),
    but a velocity command that is not finite moves the robot there."""
    bad = ~np.isfinite(poses).all(axis=-1) & group.real[:, None]
    if not bad.any():
        return
    hits = np.argwhere(bad)  # (row, step) pairs
    row, step = hits[np.argmin(hits[:, 1])]
    run = next(r for r in group.runs if row in r.rows)
    raise InputError("config", "policies", f"{run.spec!r} drove seed {group.seed[row]} in "
                     f"{group.envs[run.world].world.name} to a pose that is not finite at "
                     f"t = {(first_step + step + 1) * group.env.dt:.1f} s "
                     "(a velocity command that is not finite does this)")


def _start(group: Group, plan: Plan, capture: bool, data, blocks, keys: Keys, empty: tuple) -> Start:
    """Compile the group's functions (the chunk function in a thread, meanwhile the
    reset and the small helpers) and reset its envs."""
    fns = Compiled(reset_fn(group), chunk_fn(group, plan, capture), label_fn(group) if capture else None,
                   blocked(lambda s, blk, st: _in_world(group, s, blk)[0].log(st), group.devices),
                   blocked(lambda s, blk, st: _in_world(group, s, blk)[0].labelled_knowledge(st), group.devices))
    compiled_chunk = _compile_chunk(group, fns, data, blocks, keys, empty)
    state = fns.reset(data, blocks, keys.env)
    pstates = _init_policies(group, keys.policy)
    chunk = compiled_chunk(state, pstates)
    first_log = fns.log(data, blocks, state)
    labels = state.knowledge._replace(seen=jnp.zeros((group.size, 1), bool))  # the metrics' labels (no lag)
    attach = fns.label.lower(data, blocks, labels, *empty).compile() if capture else None
    return Start(fns, chunk, state, pstates, first_log, labels, attach)


class Finished(NamedTuple):
    """Chunk c on the host: logs (B, n, N) with the label fields rebuilt, track (B, steps, ...),
    detections (obj, label, conf (B, F, D), box (B, F, D, 4)) or None."""

    logs: ObjectLog
    track: Track
    dets: tuple | None


@dataclass
class Mapped:
    """One env's mapper, fed in the worker thread: the entry, the mapper, its scorer, its
    maps scored so far (frame count of ``Plan.score_at`` -> ObjectLog with (N,) fields) and
    the map at the last planned count."""

    spec: str
    mapper: Any
    scorer: OnlineScorer
    logs: dict = field(default_factory=dict)
    final: MapState | None = None


class _Detection:
    """The worker thread: each chunk's frames are fetched, detected, folded into the
    metrics' labels (no lag) and fed to the perceived mappers, one chunk at a time in
    order. Its own counters are ``timing``."""

    def __init__(self, group: Group, plan: Plan, detectors: dict | None, start: Start, data, blocks, bar,
                 ready: Future | None = None):
        self.group, self.plan, self.detectors, self.bar, self.ready = group, plan, detectors, bar, ready
        self.attach, self.labels, self.data, self.blocks = start.attach, start.labels, data, blocks
        self.camera = Camera.of(group.config.camera)
        self.timing = {"frames": 0, "detector_s": 0.0, "mapper_s": 0.0, "score_s": 0.0}  # score_s: within mapper_s
        self.mappers = [self._mappers(group.envs[w]) if real else None for w, real in zip(group.world, group.real)] \
            if plan.mappers else None
        self.chunks = plan.total // plan.per_call
        self.pool = ThreadPoolExecutor(max_workers=1)  # one worker: chunks are detected in order
        self.started = time.perf_counter()

    def _mappers(self, env: Env) -> dict:
        """One env's mappers by entry, the empty map scored (frame count 0)."""
        out = {}
        for spec in self.plan.mappers:
            cls = _mapper_cls(spec)
            out[spec] = Mapped(spec, cls(self.camera, env.world.taxonomy.names),
                                OnlineScorer(env.world, TOLERANCE))
            self._score(out[spec], 0)
        return out

    def _score(self, online: "Mapped", count: int) -> None:
        """Ask the mapper for its map after ``count`` frames and score it, if planned."""
        if count not in self.plan.score_at:
            return
        with raised_by(online.spec, "semantic_map"):
            m = online.mapper.semantic_map()
        m = check_map(online.spec, m, len(online.scorer.world.taxonomy.names))
        t0 = time.perf_counter()  # the scoring alone: a mapper may do work when asked for its map
        online.logs[count] = online.scorer.score(m).log
        self.timing["score_s"] += time.perf_counter() - t0
        if count == max(self.plan.score_at):
            online.final = m

    def submit(self, c: int, logs, track, frames) -> Future:
        return self.pool.submit(self._finish, c, logs, track, frames)

    def close(self) -> None:
        self.pool.shutdown()

    def _finish(self, c: int, logs, track, frames) -> Finished:
        """Chunk c: fetch it, detect its frames, rebuild the log's label fields."""
        logs, track = jax.tree.map(np.asarray, logs), jax.tree.map(np.asarray, track)
        dets, plan = None, self.plan
        _check_poses(self.group, c * plan.per_call * plan.decide_every, track.pose)
        if self.detectors is not None:
            t0 = time.perf_counter()
            if self.ready is not None:
                self.ready.result()  # the networks built while the session compiled (errors raise here)
            dets = _detect(self.group, self.detectors, frames, c * plan.frames_per_call)
            logs = self._relabel(c, logs, dets)
            t1 = time.perf_counter()
            if self.mappers:
                self._feed(c * plan.frames_per_call, track.pose, frames, dets)
            self.timing["detector_s"] += t1 - t0  # this thread alone writes them; read after close()
            self.timing["mapper_s"] += time.perf_counter() - t1
            self.timing["frames"] += int(self.group.real.sum()) * plan.frames_per_call
        self.bar.update(plan.per_call * plan.decide_every * self.group.env.dt)
        done_steps = int(self.group.real.sum()) * (c + 1) * plan.per_call * plan.decide_every
        self.bar.set_postfix_str(f"{done_steps / (time.perf_counter() - self.started):,.0f} env-steps/s")
        return Finished(logs, track, dets)

    def _feed(self, first_frame: int, poses: np.ndarray, frames: Frames, dets) -> None:
        """Feed each env's frames of this chunk (poses (B, steps, 3), frames (B, F, ...)) and
        detections to its mappers, scoring their maps at the planned counts. A frame is taken
        at its period's last step and counts from the step after it, as labels do
        (``frames_before``): the map with k frames is scored just before frame k is added,
        after the depth of the steps before it (for mappers that read it)."""
        rgb, depth = np.asarray(frames.rgb), np.asarray(frames.depth)
        sweep = None
        if frames.sweep is not None:  # no return: 0, as in the detector frame's depth
            sweep = np.asarray(frames.sweep)
            sweep = np.where(sweep < self.group.config.camera.max_range, sweep, 0)
        _, label, conf, box = dets
        every, dt = self.plan.frame_steps, self.group.env.dt
        for r, mappers in enumerate(self.mappers):
            if mappers is None:
                continue
            sweepers = [m for m in mappers.values() if m.mapper.reads_depth()]
            cameras = self.camera.pose(poses[r])  # (steps, 4, 4)
            for f in range(depth.shape[1]):
                index = first_frame + f
                steps = np.s_[f * every:(f + 1) * every]
                if sweepers:
                    self._feed_depth(sweepers, index * every, poses[r, steps], cameras[steps], sweep[r, f])
                last = (f + 1) * every - 1
                frame = Frame(index, (index + 1) * every * dt, rgb[r, f], depth[r, f], poses[r, last], cameras[last],
                              box[r, f], label[r, f], conf[r, f])
                for online in mappers.values():
                    if index:  # the empty map (0 frames) was scored when the mapper was built
                        self._score(online, index)
                    with raised_by(online.spec, f"add (frame {index})"):
                        online.mapper.add(frame)

    def _feed_depth(self, mappers: list, before: int, poses: np.ndarray, cameras: np.ndarray, sweep: np.ndarray) -> None:
        """Send ``mappers`` (Mapped) the depth of one frame period's steps after step ``before``: poses
        (frame_steps, 3), their camera poses (frame_steps, 4, 4), sweep (frame_steps, h, w)
        (0: no return); the last step is the detector frame's."""
        dt = self.group.env.dt
        for j in range(len(sweep) - 1):
            step = before + j + 1  # step s ends at s dt
            frame = DepthFrame(step, step * dt, sweep[j], poses[j], cameras[j])
            for online in mappers:
                with raised_by(online.spec, f"add_depth (step {step})"):
                    online.mapper.add_depth(frame)

    def _relabel(self, c: int, logs: ObjectLog, dets: tuple) -> ObjectLog:
        """Fold chunk c's detections into the metrics' labels; the log's label fields from them."""
        obj = dets[0]
        if c == self.chunks - 1:  # the run's last frame counts from a step that never comes
            obj = obj.copy()
            obj[:, -1] = -1
        self.labels, per_frame = self.attach(self.data, self.blocks, self.labels,
                                             *(jnp.asarray(d) for d in (obj, *dets[1:3])))
        return _relabel(logs, per_frame, self.plan.frame_steps, self.plan.log_every)


def _collect(group: Group, start: Start, state, data, blocks, track0, done: list[Finished], worker: _Detection,
             timing: dict) -> Simulation:
    """The group's logs, track and final knowledge, real envs only, in row order."""
    first = jax.tree.map(lambda a: np.asarray(a)[:, None], start.first_log)
    logs = jax.tree.map(lambda *a: np.concatenate(a, axis=1), first, *[d.logs for d in done])
    track = jax.tree.map(lambda *a: np.concatenate(a, axis=1), jax.tree.map(lambda a: a[:, None], track0),
                         *[d.track for d in done])
    knowledge = start.fns.knowledge(data, blocks, state)
    if worker.detectors is not None:
        lab = worker.labels
        knowledge = knowledge._replace(label=lab.label, confidence=lab.confidence, conf_true=lab.conf_true,
                                       conf_any=lab.conf_any)
    keep = group.real
    mapped = None
    if worker.mappers:
        real = [m for m in worker.mappers if m is not None]
        mapped = {spec: [m[spec] for m in real] for spec in worker.plan.mappers}
    return Simulation(jax.tree.map(lambda a: a[keep], logs), jax.tree.map(lambda a: a[keep], track),
                      jax.tree.map(lambda a: np.asarray(a)[keep], knowledge), timing, mapped, worker.plan.log_every)


def _compile_chunk(group: Group, fns: Compiled, data, blocks, keys: Keys, empty):
    """A function (state, pstates) -> the compiled chunk function. On one device the compile
    starts now, in a thread, from the arguments' shapes: XLA compiles without the GIL, so
    the reset and the small helpers compile and run meanwhile (1-2 s less of a cold start).
    On more, each device's copy compiles at the call (:class:`Replicas`, in parallel)."""
    if group.devices > 1:
        return lambda state, pstates: fns.chunk.lower(data, blocks, state, pstates, keys.run, empty).compile()
    state = jax.eval_shape(fns.reset, data, blocks, keys.env)
    strong = lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype)  # noqa: E731  (_init_policies gives numpy-made arrays)
    pstates = tuple(jax.tree.map(strong, jax.eval_shape(p.init_batch, keys.policy)) for p in group.policies)
    pool = ThreadPoolExecutor(max_workers=1)
    job = pool.submit(lambda: fns.chunk.lower(data, blocks, state, pstates, keys.run, empty).compile())
    pool.shutdown(wait=False)
    return lambda *_: _wait(job)


def _wait(job: Future):
    """The compile's result, Ctrl-C honoured while waiting for it."""
    while True:
        try:
            return job.result(timeout=0.2)
        except TimeoutError:
            interrupt.check()


def _init_policies(group: Group, keys: jax.Array) -> tuple:
    """The union of policy states (one slot per policy; B rows each): every row holds the
    template's initial state, overwritten by its own run's policy in that policy's slot."""
    out = []
    for q, template in enumerate(group.policies):
        full = jax.tree.map(np.array, template.init_batch(keys))
        for run in group.runs:
            if run.policy == q:
                part = run.host_policy.init_batch(keys[run.rows])
                jax.tree.map(lambda f, p: f.__setitem__(run.rows, np.asarray(p)), full, part)
        out.append(jax.tree.map(jnp.asarray, full))
    return tuple(out)


def _prepare(detectors: dict, camera) -> Future:
    """Build every detector's network for the camera's frames in a thread of its own, while
    the session compiles: a first use exports and quantises the graph (about 20 s)."""
    shared: dict = {}  # the first detector of each network: _detect runs one pass per shared network
    for d in detectors.values():
        if hasattr(d, "prepare"):
            shared.setdefault(getattr(d, "network", None), d)
    pool = ThreadPoolExecutor(max_workers=1)
    ready = pool.submit(lambda: [d.prepare(camera.rgb_height, camera.rgb_width) for d in shared.values()])
    pool.shutdown(wait=False)  # the job runs on; nothing more is queued
    return ready


def _no_detections(b: int, frames: int) -> tuple[np.ndarray, ...]:
    """obj, label (B, F, D) int32 -1, conf (B, F, D) and box (B, F, D, 4) zeros: nothing."""
    return (np.full((b, frames, MAX_DET), -1, np.int32), np.full((b, frames, MAX_DET), -1, np.int32),
            np.zeros((b, frames, MAX_DET), np.float32), np.zeros((b, frames, MAX_DET, 4), np.float32))


def _detect(group: Group, detectors: dict, frames: Frames, first_frame: int):
    """Run each world's detector on its real envs' frames. Returns obj, label, conf
    (B, F, D) and box (B, F, D, 4); padding envs get none. Worlds whose detectors share a
    ``network`` (the YOLO weights) share one pass over all their frames: the last batch of
    each world alone would be mostly padding."""
    rgb, seg = np.asarray(frames.rgb), np.asarray(frames.labels)  # (B, F, H, W, 3), (B, F, H, W)
    b, f = rgb.shape[:2]
    obj, label, conf, box = _no_detections(b, f)
    rows = {w: r for w in detectors if len(r := np.flatnonzero(group.real & (group.world == w)))}
    images = {w: rgb[r].reshape(-1, *rgb.shape[2:]) for w, r in rows.items()}
    labels = {w: seg[r].reshape(-1, *seg.shape[2:]).astype(np.int32) for w, r in rows.items()}
    passes: dict = {}  # a shared network, or the world alone -> its worlds
    for w in rows:
        passes.setdefault(getattr(detectors[w], "network", None) or w, []).append(w)
    found = {}
    for worlds in passes.values():
        if len(worlds) == 1:
            w, r = worlds[0], rows[worlds[0]]
            ids = np.stack(np.meshgrid(group.seed[r], first_frame + np.arange(f), indexing="ij"), -1).reshape(-1, 2)
            found[w] = detectors[w](images[w], labels[w], ids)
            continue
        raw = detectors[worlds[0]].raw(np.concatenate([images[w] for w in worlds]))
        for w, start in zip(worlds, np.cumsum([0] + [len(images[w]) for w in worlds])):
            found[w] = detectors[w].finish(raw[start:start + len(images[w])], labels[w])
    for w, r in rows.items():
        for i, row in enumerate(r):
            obj[row], label[row], conf[row], box[row] = pad(found[w][i * f:(i + 1) * f], f, MAX_DET)
    return obj, label, conf, box


def _relabel(logs: ObjectLog, per_frame, frame_steps: int, log_every: int = 1) -> ObjectLog:
    """Rewrite the chunk's label fields (B, n, N), one row after every ``log_every``-th
    step, from the step after each frame on: a frame taken at the end of frame period f
    (``frame_steps`` steps) counts from period f + 1 (before the chunk's first frame, the
    labels the previous chunk ended with)."""
    step = (np.arange(logs.ps.shape[1]) + 1) * log_every - 1  # each row's step in the chunk, from 0
    frame_of_step = step // frame_steps - 1
    take = frame_of_step >= 0
    updates = {}
    for name, values in zip(LABEL_FIELDS, per_frame):
        new = getattr(logs, name).copy()
        new[:, take] = np.asarray(values)[:, frame_of_step[take]].astype(new.dtype)
        updates[name] = new
    return logs._replace(**updates)


class CompileClock:
    """Seconds spent tracing and compiling inside ``with clock:`` (with the first calls of
    the small helpers), and every XLA compile counted by JAX's monitoring events (hits of
    the persistent compilation cache too)."""

    _counts = {"compiles": 0, "cache_hits": 0}
    _listening = False

    def __init__(self):
        self.seconds = 0.0
        if not CompileClock._listening:
            jax.monitoring.register_event_duration_secs_listener(CompileClock._on_duration)
            jax.monitoring.register_event_listener(CompileClock._on_event)
            CompileClock._listening = True

    @staticmethod
    def _on_duration(event: str, seconds: float, **kw) -> None:
        if event == "/jax/core/compile/backend_compile_duration":
            CompileClock._counts["compiles"] += 1

    @staticmethod
    def _on_event(event: str, **kw) -> None:
        if event == "/jax/compilation_cache/cache_hits":
            CompileClock._counts["cache_hits"] += 1

    def __enter__(self):
        self._t = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.seconds += time.perf_counter() - self._t
        return False
