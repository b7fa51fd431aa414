"""The worker thread beside the simulation: each chunk's frames detected, folded into the
metrics' labels and fed to the mappers.

**The detector overlaps the simulation.** Chunk k's frames are detected in a worker thread
while chunk k + 1 simulates. The robot's knowledge receives the detections on a fixed
simulated-time schedule, part of the experiment: the frames of detector period p (one RGB
frame per decision by default, or one every ``detect_every`` steps) are folded in at the
start of period p + 2, so a label reaches the policy one to two periods after its frame,
whatever the chunking. The metrics' label fields are rebuilt here without that lag: a
frame counts from the step after it, so the run's last frame never counts, and the final
labels (objects table, exported maps) are those of the last logged step.

Shapes: B envs in a group, N objects (padded), F frames per chunk, D detections per frame.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.xla import cores
from rosmeery_jax.detector.detections import pad
from rosmeery_jax.env import RobotEnv, Track
from rosmeery_jax.env.decision import Frames
from rosmeery_jax.mapping.built_ins import built_in, mapper_for
from rosmeery_jax.mapping.protocol import Camera, DepthFrame, Frame, MapState, OnlineScorer, check_map, raised_by
from rosmeery_jax.metrics.map_score import TOLERANCE
from rosmeery_jax.session.batch import Group
from rosmeery_jax.session.schedule import Plan
from rosmeery_jax.sim.knowledge import ObjectLog

MAX_DET = 32  # detections kept per frame (the most confident)
LABEL_FIELDS = ("conf_true", "conf_any", "label", "declared", "correct")


class HostFrames(NamedTuple):
    """A chunk's frames on the host, as the mappers take them: its first frame's index; poses
    (B, steps, 3); rgb (B, F, H, W, 3), depth (B, F, H, W); sweep (B, F, frame_steps, h, w)
    (as rendered: max_range where no return) or None; dets (obj, label, conf (B, F, D), box (B, F, D, 4))."""

    first_frame: int
    poses: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray
    sweep: np.ndarray | None
    dets: tuple


class Spent(NamedTuple):
    """What feeding one env's mappers a chunk cost: seconds scoring their maps, and the
    feeding thread's CPU seconds (scoring included)."""

    score_s: float
    cpu_s: float


class Finished(NamedTuple):
    """Chunk c on the host: logs (B, n, N) with the label fields rebuilt, track (B, steps, ...),
    detections (obj, label, conf (B, F, D), box (B, F, D, 4)) or None."""

    logs: ObjectLog
    track: Track
    dets: tuple | None


@dataclass
class Mapped:
    """One env's mapper, fed in the worker thread: the entry, the mapper, its scorer, its
    maps scored so far (frame count of ``Plan.score_at`` -> ObjectLog with (N,) fields, and
    -> {name: value} of the field map metrics) and the map at the last planned count."""

    spec: str
    mapper: Any
    scorer: OnlineScorer
    logs: dict = field(default_factory=dict)
    final: MapState | None = None
    fields: dict = field(default_factory=dict)


class Worker:
    """The worker thread: each chunk's frames are fetched, detected, folded into the
    metrics' labels (no lag) and fed to the perceived mappers, one chunk at a time in
    order. Its own counters are ``timing``. ``attach``: the compiled label update
    (``program.label_fn``), None without detectors; ``labels``: the metrics' label state it
    starts from."""

    def __init__(self, group: Group, plan: Plan, detectors: dict | None, attach, labels, data, blocks, bar,
                 ready: Future | None = None):
        self.group, self.plan, self.detectors, self.bar, self.ready = group, plan, detectors, bar, ready
        self.attach, self.labels, self.data, self.blocks = attach, labels, data, blocks
        self.last_fields = None  # the label fields after the last frame so far (B, N) each
        self.camera = Camera.of(group.config.camera)
        # score_s and mapper_cpu_s: summed over the mapper threads; mapper_s: the wall time of feeding
        self.timing = {"frames": 0, "detector_s": 0.0, "mapper_s": 0.0, "score_s": 0.0, "mapper_cpu_s": 0.0}
        self.mappers = [self._mappers(group.envs[w]) if real else None for w, real in zip(group.world, group.real)] \
            if plan.mappers else None
        self.chunks = plan.total // plan.per_call
        self.pool = ThreadPoolExecutor(max_workers=1)  # one worker: chunks are detected in order
        self.mapper_pool = ThreadPoolExecutor(max_workers=max(cores() - 1, 1))  # one core is the simulation's
        self.started = time.perf_counter()

    def _mappers(self, env: RobotEnv) -> dict:
        """One env's mappers by entry, the empty map scored (frame count 0)."""
        out = {}
        for spec in self.plan.mappers:
            cls = mapper_for(spec)
            out[spec] = Mapped(spec, cls(self.camera, env.world.taxonomy.names),
                                OnlineScorer(env.world, TOLERANCE, self.plan.field, self.plan.task))
            self.timing["score_s"] += self._score(out[spec], 0)
        return out

    def _score(self, online: "Mapped", count: int) -> float:
        """Ask the mapper for its map after ``count`` frames and score it, if planned; the
        seconds the scoring took."""
        if count not in self.plan.score_at:
            return 0.0
        with raised_by(online.spec, "semantic_map"):
            m = online.mapper.semantic_map()
        if not built_in(online.spec):
            m = check_map(online.spec, m, len(online.scorer.world.taxonomy.names))
        t0 = time.perf_counter()  # the scoring alone: a mapper may do work when asked for its map
        score = online.scorer.score(m)
        online.logs[count], online.fields[count] = score.log, score.field
        if count == max(self.plan.score_at):
            online.final = m
        return time.perf_counter() - t0

    def submit(self, c: int, logs, track, frames) -> Future:
        return self.pool.submit(self._finish, c, logs, track, frames)

    def close(self) -> None:
        self.pool.shutdown()
        self.mapper_pool.shutdown()

    def abandon(self) -> None:
        """Drop the chunks not yet detected (Ctrl-C or an error), without waiting for them."""
        self.pool.shutdown(wait=False, cancel_futures=True)
        self.mapper_pool.shutdown(wait=False, cancel_futures=True)

    def labelled(self, knowledge):
        """The final knowledge (B envs) with the detector's labels in place of the ground
        truth's; unchanged without detectors."""
        if self.detectors is None:
            return knowledge
        lab = self.labels
        return knowledge._replace(label=lab.label, confidence=lab.confidence)

    def maps(self) -> dict | None:
        """Per mapper entry, the real envs' :class:`Mapped` in row order; None without mappers."""
        if not self.mappers:
            return None
        real = [m for m in self.mappers if m is not None]
        return {spec: [m[spec] for m in real] for spec in self.plan.mappers}

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
                self._feed(c * plan.frames_per_call, track.believed, frames, dets)  # the robot's own poses
            self.timing["detector_s"] += t1 - t0  # this thread alone writes them; read after close()
            self.timing["mapper_s"] += time.perf_counter() - t1
            self.timing["frames"] += int(self.group.real.sum()) * plan.frames_per_call
        self.bar.update(plan.per_call * plan.decide_every * self.group.env.dt)
        done_steps = int(self.group.real.sum()) * (c + 1) * plan.per_call * plan.decide_every
        self.bar.set_postfix_str(f"{done_steps / (time.perf_counter() - self.started):,.0f} env-steps/s")
        return Finished(logs, track, dets)

    def _feed(self, first_frame: int, poses: np.ndarray, frames: Frames, dets) -> None:
        """Feed each env's frames of this chunk (poses (B, steps, 3), frames (B, F, ...)) and
        detections to its mappers, scoring their maps at the planned counts. The envs'
        built-in mappers are fed on a pool of threads, one per core but the simulation's
        (their passes release the GIL; each env's mapper is its own, so its maps are those
        of one thread); plugin mappers in this thread, env after env (they may share state)."""
        sweep = None if frames.sweep is None else np.asarray(frames.sweep)
        chunk = HostFrames(first_frame, poses, np.asarray(frames.rgb), np.asarray(frames.depth), sweep, dets)
        rows = [(r, m) for r, m in enumerate(self.mappers) if m is not None]
        jobs = [self.mapper_pool.submit(self._feed_env, chunk, r, ours) for r, m in rows
                if (ours := [o for o in m.values() if built_in(o.spec)])]
        spent = [self._feed_env(chunk, r, plugins) for r, m in rows
                 if (plugins := [o for o in m.values() if not built_in(o.spec)])]
        spent += [job.result() for job in jobs]  # an error of a built-in mapper raises here
        self.timing["score_s"] += sum(s.score_s for s in spent)
        self.timing["mapper_cpu_s"] += sum(s.cpu_s for s in spent)

    def _feed_env(self, chunk: "HostFrames", r: int, mappers: list) -> Spent:
        """Feed env row r's ``mappers`` (Mapped) its frames of ``chunk``. A frame is taken at
        its period's last step and counts from the step after it, as labels do
        (``frames_before``): the map with k frames is scored just before frame k is added,
        after the depth of the steps before it (for mappers that read it)."""
        cpu = time.thread_time()
        _, label, conf, box = chunk.dets
        every, dt, poses, score_s = self.plan.frame_steps, self.group.env.dt, chunk.poses[r], 0.0
        sweepers = [m for m in mappers if m.mapper.reads_depth()]
        if sweepers:  # no return: 0, as in the detector frame's depth
            sweep = np.where(chunk.sweep[r] < self.group.config.camera.max_range, chunk.sweep[r], 0)
        cameras = self.camera.pose(poses)  # (steps, 4, 4)
        for f in range(chunk.depth.shape[1]):
            index = chunk.first_frame + f
            steps = np.s_[f * every:(f + 1) * every]
            if sweepers:
                self._feed_depth(sweepers, index * every, poses[steps], cameras[steps], sweep[f])
            last = (f + 1) * every - 1
            frame = Frame(index, (index + 1) * every * dt, chunk.rgb[r, f], chunk.depth[r, f], poses[last],
                          cameras[last], box[r, f], label[r, f], conf[r, f])
            for online in mappers:
                if index:  # the empty map (0 frames) was scored when the mapper was built
                    score_s += self._score(online, index)
                with raised_by(online.spec, f"add (frame {index})"):
                    online.mapper.add(frame)
        return Spent(score_s, time.thread_time() - cpu)

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
        per_frame = [np.asarray(v) for v in per_frame]
        out = _relabel(logs, per_frame, self.plan.frame_steps, self.plan.log_every, self.last_fields)
        self.last_fields = [v[:, -1] for v in per_frame]
        return out


def prepare_detectors(detectors: dict, camera) -> Future:
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


def no_detections(b: int, frames: int) -> tuple[np.ndarray, ...]:
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
    obj, label, conf, box = no_detections(b, f)
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


def _relabel(logs: ObjectLog, per_frame, frame_steps: int, log_every: int = 1, before=None) -> ObjectLog:
    """Rewrite the chunk's label fields (B, n, N), one row after every ``log_every``-th
    step, from the step after each frame on: a frame taken at the end of frame period f
    (``frame_steps`` steps) counts from period f + 1. Before the chunk's first frame counts,
    the labels after the previous chunk's last frame (``before``, (B, N) per field; None in
    the first chunk, where no frame has counted and the log's own fields hold none). The
    robot's knowledge in the log gets its labels a detector period later, so its fields
    would show labels the metrics had already counted dropping away for a row."""
    step = (np.arange(logs.ps.shape[1]) + 1) * log_every - 1  # each row's step in the chunk, from 0
    frame_of_step = step // frame_steps - 1
    take = frame_of_step >= 0
    updates = {}
    for k, (name, values) in enumerate(zip(LABEL_FIELDS, per_frame)):
        new = getattr(logs, name).copy()
        new[:, take] = np.asarray(values)[:, frame_of_step[take]].astype(new.dtype)
        if before is not None:
            new[:, ~take] = np.asarray(before[k])[:, None].astype(new.dtype)
        updates[name] = new
    return logs._replace(**updates)


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

