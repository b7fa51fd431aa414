"""The session engine: a group (:mod:`rosmeery_jax.session.batch`) stepped to its end by
its one compiled chunk function (:mod:`rosmeery_jax.session.program`), each chunk handed to
the worker thread (:mod:`rosmeery_jax.session.worker`) while the next one simulates.

Shapes: B envs in a group, T steps, N objects (padded).
"""

from __future__ import annotations

import collections
import time
from concurrent.futures import Future
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.core import interrupt
from rosmeery_jax.env import Track
from rosmeery_jax.session import digest
from rosmeery_jax.session.batch import Group
from rosmeery_jax.session.program import Compiled, blocked, chunk_fn, in_world, label_fn, reset_fn, shardings
from rosmeery_jax.session.schedule import Plan
from rosmeery_jax.session.worker import Finished, Worker, no_detections, prepare_detectors
from rosmeery_jax.sim.knowledge import ObjectLog

QUEUED_CHUNKS = 2  # chunks dispatched and not yet run: one runs while the next waits its turn


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
    stamps: np.ndarray | None = None  # (B, S) int32 each sample's first-observed step, -1 never (Plan.stamp)
    logodds: Any = None  # (B padded, H, W) the robots' occupancy maps at the end (Plan.drives)


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
    call; chunk c's frames are detected in a worker thread (:class:`Worker`) while
    chunk c + 1 simulates, and reach the robot at the start of chunk c + 2."""
    capture = detectors is not None
    keys = Keys.of(group)
    data, blocks = group.data, jnp.asarray(group.blocks)
    if group.devices > 1:  # placed once: every call's arguments are then where they belong
        whole, split = shardings(group.devices)
        data, blocks = jax.device_put(data, whole), jax.device_put(blocks, split)
    pending = plan.frames_per_call if capture else 1
    empty = tuple(jnp.asarray(a) for a in no_detections(group.size, pending)[:3])
    xla_before = dict(CompileClock._counts)
    ready = prepare_detectors(detectors, group.config.camera) if capture else None
    with clock:
        start = _start(group, plan, capture, data, blocks, keys, empty)
    track0 = jax.tree.map(np.asarray, Track.of(start.state))
    for run in group.runs:
        run.host_policy.check_start(track0.pose[run.rows])
    worker = Worker(group, plan, detectors, start.attach, start.labels, data, blocks, bar, ready)
    state, pstates, key, jobs, wait_s, digests = start.state, start.pstates, keys.run, [], 0.0, []
    stamps = (first_stamps(start.state),) if plan.stamp else ()
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
                out = start.chunk(data, blocks, state, pstates, key, pending, *stamps)
                state, pstates, key = out.state, out.pstates, out.key
                stamps = (out.stamps,) if plan.stamp else ()
                queued.append(key)
                jobs.append(worker.submit(c, out.logs, out.track, out.frames))
                if plan.digest:  # waits for the chunk: a debugging aid, not for timed runs
                    digests.append(digest.of_state(state))
    except BaseException:  # Ctrl-C or an error: queued detections are dropped, not waited for
        worker.abandon()
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
    keep = group.real
    return _collect(group, start, state, data, blocks, track0, done, worker, timing)._replace(
        stamps=np.asarray(stamps[0])[keep] if stamps else None,
        logodds=state.logodds if plan.drives is not None else None,
        digests=[{k: [v[r] for r in np.flatnonzero(group.real)] for k, v in part.items()} for part in digests]
        if plan.digest else None)


def first_stamps(state) -> jax.Array:
    """(B, S) int32: 0 for the samples observed at reset, -1 for the rest."""
    return jnp.where(jnp.asarray(state.knowledge.seen, jnp.float32) > 0.5, 0, -1).astype(jnp.int32)


def _raise_failed(jobs: list[Future]) -> None:
    """The error of a chunk the worker has finished with one, now rather than at the end."""
    for job in jobs:
        if job.done() and job.exception() is not None:
            job.result()


def _start(group: Group, plan: Plan, capture: bool, data, blocks, keys: Keys, empty: tuple) -> Start:
    """Compile the group's functions (the chunk function in a thread, meanwhile the
    reset and the small helpers) and reset its envs."""
    fns = Compiled(reset_fn(group), chunk_fn(group, plan, capture), label_fn(group) if capture else None,
                   blocked(lambda s, blk, st: in_world(group, s, blk)[0].log(st), group.devices),
                   blocked(lambda s, blk, st: in_world(group, s, blk)[0].labelled_knowledge(st), group.devices))
    compiled_chunk = _compile_chunk(group, plan, fns, data, blocks, keys, empty)
    state = fns.reset(data, blocks, keys.env)
    pstates = _init_policies(group, keys.policy)
    chunk = compiled_chunk(state, pstates)
    first_log = fns.log(data, blocks, state)
    labels = state.knowledge._replace(seen=jnp.zeros((group.size, 1), bool))  # the metrics' labels (no lag)
    attach = fns.label.lower(data, blocks, labels, *empty).compile() if capture else None
    return Start(fns, chunk, state, pstates, first_log, labels, attach)


def _collect(group: Group, start: Start, state, data, blocks, track0, done: list[Finished], worker: Worker,
             timing: dict) -> Simulation:
    """The group's logs, track and final knowledge, real envs only, in row order."""
    first = jax.tree.map(lambda a: np.asarray(a)[:, None], start.first_log)
    logs = jax.tree.map(lambda *a: np.concatenate(a, axis=1), first, *[d.logs for d in done])
    track = jax.tree.map(lambda *a: np.concatenate(a, axis=1), jax.tree.map(lambda a: a[:, None], track0),
                         *[d.track for d in done])
    knowledge = worker.labelled(start.fns.knowledge(data, blocks, state))
    keep = group.real
    return Simulation(jax.tree.map(lambda a: a[keep], logs), jax.tree.map(lambda a: a[keep], track),
                      jax.tree.map(lambda a: np.asarray(a)[keep], knowledge), timing, worker.maps(),
                      worker.plan.log_every)


def _compile_chunk(group: Group, plan: Plan, fns: Compiled, data, blocks, keys: Keys, empty):
    """A function (state, pstates) -> the compiled chunk function. On one device the compile
    starts now, in a thread, from the arguments' shapes: XLA compiles without the GIL, so
    the reset and the small helpers compile and run meanwhile (1-2 s less of a cold start).
    On more, each device's copy compiles at the call (:class:`Replicas`, in parallel)."""
    stamp = (lambda state: (first_stamps(state),)) if plan.stamp else (lambda state: ())
    if group.devices > 1:
        return lambda state, pstates: fns.chunk.lower(data, blocks, state, pstates, keys.run, empty,
                                                      *stamp(state)).compile()
    state = jax.eval_shape(fns.reset, data, blocks, keys.env)
    strong = lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype)  # noqa: E731  (_init_policies gives numpy-made arrays)
    pstates = tuple(jax.tree.map(strong, jax.eval_shape(p.init_batch, keys.policy)) for p in group.policies)
    extra = (jax.eval_shape(first_stamps, state),) if plan.stamp else ()
    job = interrupt.background(lambda: fns.chunk.lower(data, blocks, state, pstates, keys.run, empty,
                                                       *extra).compile(), "compile")
    return lambda *_: interrupt.wait(job)


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

