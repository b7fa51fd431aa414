"""A session's output files, each written atomically:

    OUT/runs/<world>__<policy>.metrics.csv    the run's curves (long format)
    OUT/runs/<world>__<policy>.objects.csv    final per-object state per seed
    OUT/maps/<world>__<policy>__seed<k>.ply / .json   semantic maps at the end (mapper "oracle";
        ``__seed<k>__<mapper>`` for another mapper's, e.g. ``perceived``: rosmeery_jax.mapping.protocol)
    OUT/runs/<world>__<policy>.trajectory.csv robot poses (sampled like metrics.csv)
    OUT/runs/<world>__<policy>.navigation.csv where each seed's time went (results.time_use;
        runs in target mode: the navigator drives)
    OUT/runs/<world>__<policy>.timing.json    the batch's compile, simulation and detector times
    OUT/runs/<world>__<policy>.tasks.csv      task "objectnav": each executed episode (session.objectnav)
    OUT/metrics.csv, OUT/objects.csv, OUT/trajectories.csv, OUT/navigation.csv (OUT/tasks.csv)
        all finished runs, merged once at the end
    OUT/plots/<world>_<metric>.png            mean over seeds with a std band per policy
    OUT/timing.json                           compile (``compiles``), simulation, detector and wall times

A run's files are recorded last in ``OUT/runs/<world>__<policy>.manifest.json`` (rows and
sha256 of each, :mod:`rosmeery_jax.results.manifest`): a run is done when its record
holds (``--resume`` re-simulates one whose files were damaged); the merged tables are
recorded in ``OUT/manifest.json``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np
import pandas as pd

from rosmeery_jax import metrics
from rosmeery_jax.core.files import write_atomic
from rosmeery_jax.env import Track
from rosmeery_jax.mapping.protocol import MapState, OnlineScorer, mapper_label
from rosmeery_jax.metrics import field
from rosmeery_jax.metrics.indices import MAP_METRICS
from rosmeery_jax.metrics.map_file import build_map, write_map, write_semantic_map
from rosmeery_jax.metrics.map_score import TOLERANCE
from rosmeery_jax.results import manifest, plots, tables, time_use
from rosmeery_jax.session.checks import run_label
from rosmeery_jax.session.config import SessionConfig
from rosmeery_jax.session.schedule import frames_before, sampled_rows, task_query
from rosmeery_jax.sim.knowledge import ObjectLog
from rosmeery_jax.world import load_world

INTEGRITY = 1  # config.json's "integrity": the folder records its files (results.manifest)


def run_name(world: str, policy: str) -> str:
    return f"{load_world(world).name}__{run_label(policy)}"


class RunResult(NamedTuple):
    """One run's simulation, per seed (S, in seed order): env (its world's); policy, the
    results' label; logs ObjectLog (S, T, N) one row every ``log_every`` steps; track
    (S, steps + 1, ...) pose and navigation status at every step; knowledge: the final labelled knowledge (S, ...); mapped: per mapper
    entry, one ``worker.Mapped`` per seed (None without mappers); seeds (S,) their numbers."""

    env: Any
    policy: str
    logs: ObjectLog
    track: Track
    knowledge: Any
    mapped: dict | None
    log_every: int
    seeds: range
    digests: pd.DataFrame | None = None  # seed, chunk, time_s and a digest per part (session.digest)
    stamps: np.ndarray | None = None  # (S, samples) first-observed step per sample (engine.Simulation)
    tasks: pd.DataFrame | None = None  # the executed task episodes (session.objectnav), task "objectnav"


def write_run(cfg: SessionConfig, run: RunResult, name: str, out: Path, timing: dict) -> None:
    """One run's files, each atomically; the metrics file last (its presence marks the run
    done). Padding objects and samples are cut off."""
    env, policy = run.env, run.policy
    world = env.world
    n, s = world.truth.num_objects, len(world.truth.samples.object)
    logs = jax.tree.map(lambda a: a[..., :n], run.logs)
    poses = run.track.pose
    step = np.arange(logs.ps.shape[1]) * run.log_every  # each log row's step
    times = step * env.dt
    keep = sampled_rows(cfg)
    counted = frames_before(cfg, step[keep])
    tags = dict(world=world.name, policy=policy, detector=cfg.detector)
    names = metrics.resolve(cfg.metrics)
    field_names, task = field.wanted(names), task_query(cfg)
    map_names = [n for n in names if n in MAP_METRICS]
    curves, objects, paths = [], [], []
    for i, seed in enumerate(run.seeds):  # per seed, so a seed's numbers never depend on the batch shape
        log = jax.tree.map(lambda a: a[i], logs)
        if "oracle" in cfg.mappers:
            k = jax.tree.map(lambda a: np.asarray(a)[i], run.knowledge)
            k = k._replace(seen=k.seen[:s], label=k.label[:n], confidence=k.confidence[:n])
            write_semantic_map(out / "maps", f"{name}__seed{seed}", world, k, float(times[-1]))
            c = {m: v[keep] for m, v in metrics.compute(log, env.truth, names).items()}  # {name: (K,)}
            if map_names:
                c.update(oracle_maps(world, run.stamps[i, :s], step[keep], jax.tree.map(lambda a: a[keep], log),
                                     field_names, task))
            curves.append(tables.metric_frame({m: c[m] for m in names}, times[keep], seed=seed, mapper="oracle",
                                               **tags))
            objects.append(tables.object_frame(world, jax.tree.map(lambda a: a[-1], log), seed=seed,
                                                mapper="oracle", policy=policy, detector=cfg.detector))
        for spec in cfg.mappers:
            if spec == "oracle":
                continue
            label = mapper_label(spec)
            done = run.mapped[spec][i]
            mlog = ObjectLog(*(np.stack(a) for a in zip(*(done.logs[c] for c in counted))))  # (K, N)
            c = metrics.compute(mlog, env.truth, names)
            c.update({m: np.array([done.fields[k][m] for k in counted]) for m in map_names})
            c = {m: c[m] for m in names}
            curves.append(tables.metric_frame(c, times[keep], seed=seed, mapper=label, **tags))
            objects.append(tables.object_frame(world, jax.tree.map(lambda a: a[-1], mlog), seed=seed, mapper=label,
                                                policy=policy, detector=cfg.detector))
            _write_mapper_map(env, done.final, out / "maps" / f"{name}__seed{seed}__{label}", times[-1])
        path = {"world": world.name, "policy": policy, "seed": seed, "time_s": tables.seconds(times[keep]),
                "x": poses[i, step[keep], 0], "y": poses[i, step[keep], 1], "yaw": poses[i, step[keep], 2]}
        if run.track.estimate is not None:  # the robot's own estimate beside the truth
            est = np.asarray(run.track.estimate)[i, step[keep]]
            path.update(est_x=est[:, 0], est_y=est[:, 1], est_yaw=est[:, 2])
        paths.append(pd.DataFrame(path))
    runs = out / "runs"
    tables.write_csv(pd.concat(objects, ignore_index=True), runs / f"{name}.objects.csv")
    write_atomic(runs / f"{name}.timing.json", json.dumps(
        {**timing, "note": "simulated in one batch with the other runs of its group: the times are the group's"},
        indent=2))
    tables.write_csv(pd.concat(paths, ignore_index=True), runs / f"{name}.trajectory.csv")
    if env.config.action_mode == "target":
        tables.write_csv(time_use.frame(run.track.status, poses, env.dt, run.seeds, world=world.name, policy=policy),
                          runs / f"{name}.navigation.csv")
    if run.digests is not None:
        tables.write_csv(run.digests, runs / f"{name}.digest.csv")
    if run.tasks is not None:
        tables.write_csv(run.tasks, runs / f"{name}.tasks.csv")
    tables.write_csv(pd.concat(curves, ignore_index=True), runs / f"{name}.metrics.csv")
    seal_run(out, name)


def oracle_maps(world, stamps: np.ndarray, steps: np.ndarray, log: ObjectLog, names, task=None) -> dict:
    """{name: (K,)} map metrics (field ``names``, and ``task``'s) of the built-in knowledge's
    map at ``steps`` (K,):
    the samples first observed by then (``stamps`` (S,), -1 never) labelled by their
    object's held label and confidence in ``log`` (fields (K, N)). The map grows sample
    by sample in the order of observation, so it is scored incrementally."""
    truth = world.truth
    order = np.lexsort((np.arange(len(stamps)), stamps))
    order = order[stamps[order] >= 0]
    ends = np.searchsorted(stamps[order], steps, side="right")
    points = np.asarray(truth.samples.points, np.float64)[order]
    instance = np.asarray(truth.samples.object, np.int64)[order]
    scorer = OnlineScorer(world, TOLERANCE, names, task)
    out = {n: np.zeros(len(steps)) for n in (*names, *scorer.task_names)}
    for k, end in enumerate(ends):
        conf = np.where(log.label[k] >= 0, log.conf_any[k], 0.0).astype(np.float32)
        sc = scorer.score(MapState(points[:end], instance[:end], np.asarray(log.label[k], np.int32), conf),
                          ties=order[:end])  # each point is its sample
        for n in out:
            out[n][k] = sc.field[n]
    return out


def run_files(out: Path, name: str) -> list[Path]:
    """The result files of run ``name`` in ``out``: its tables and maps (not its timing, which
    a resumed run measures anew)."""
    runs = [p for p in (out / "runs").glob(f"{name}.*") if p.suffix == ".csv"]
    return runs + list((out / "maps").glob(f"{name}__seed*"))


def run_manifest(out: Path, name: str) -> Path:
    return out / "runs" / f"{name}{manifest.RUN_SUFFIX}"


def run_damage(out: Path, name: str):
    """The first damage to run ``name``'s files (:func:`rosmeery_jax.results.manifest.damage`):
    its record must list its metrics table and every table and map of the run there is."""
    expected = {*run_files(out, name), out / "runs" / f"{name}.metrics.csv"}
    return manifest.damage(run_manifest(out, name), out, sorted(expected))


def seal_run(out: Path, name: str) -> None:
    """Record run ``name``'s files, last: the record marks the run done."""
    manifest.write(run_manifest(out, name), out, run_files(out, name))


def finished(out: Path) -> list[str]:
    """The runs of ``out`` with a record of their files (whole or not: see
    :func:`rosmeery_jax.results.manifest.damage`)."""
    found = (out / "runs").glob(f"*{manifest.RUN_SUFFIX}") if (out / "runs").is_dir() else []
    return sorted(p.name[:-len(manifest.RUN_SUFFIX)] for p in found)


def _write_mapper_map(env, m, stem: Path, time_s: float) -> None:
    """A mapper's last scored map as ``stem``.ply / .json."""
    names = [f"instance_{i}" for i in range(len(m.label))]
    write_map(stem.parent, stem.name, *build_map(env.world, m.points, m.instance, names, m.label, m.confidence,
                                                 float(time_s)))


def check_folder(out: Path) -> None:
    """Refuse a results folder whose files differ from its records (one InputError naming
    the damaged file and row). A folder of a version that kept no records is let through,
    its tables checked as they are read."""
    try:
        kept = json.loads((out / "config.json").read_text(encoding="utf-8")).get("integrity") == INTEGRITY
    except (OSError, UnicodeDecodeError, ValueError, AttributeError):
        kept = False
    if not kept and not (out / manifest.MANIFEST).exists():
        return
    merged = [out / f for f in MERGED if (out / f).exists()]
    for err in [manifest.damage(out / manifest.MANIFEST, out, merged)] + [run_damage(out, n) for n in finished(out)]:
        if err is not None:
            raise err


MERGED = ("metrics.csv", "objects.csv", "trajectories.csv", "navigation.csv", "tasks.csv")  # every run's tables


def merge(out: Path) -> None:
    """The merged tables and plots of every finished run in ``out``."""
    runs = [out / "runs" / f"{name}.metrics.csv" for name in finished(out)]
    if not runs:
        return
    df = pd.concat([pd.read_csv(p) for p in runs], ignore_index=True)
    written = [tables.write_csv(df, out / MERGED[0])]
    for suffix, merged in zip((".objects.csv", ".trajectory.csv", ".navigation.csv", ".tasks.csv"), MERGED[1:]):
        parts = [p.with_name(p.name.replace(".metrics.csv", suffix)) for p in runs]
        parts = [pd.read_csv(p) for p in parts if p.exists()]
        if parts:
            written.append(tables.write_csv(pd.concat(parts, ignore_index=True), out / merged))
    manifest.write(out / manifest.MANIFEST, out, written)
    plots.plot_results(df, out / "plots")


TIMING_KEYS = ("env_steps", "frames", "detector_s", "mapper_s", "mapper_cpu_s", "score_s", "wait_s", "compile_s",
               "compiles", "xla_compiles", "cache_hits", "sim_s", "task_s")


def sum_timing(parts: list[dict], t_start: float) -> dict:
    """This invocation's figures: the groups' (or cluster shards') times summed, and the wall
    time from ``t_start`` to now (set-up, compile, simulation, detection, writing)."""
    total = {k: sum(g.get(k, 0) for g in parts) for k in TIMING_KEYS if k != "task_s" or any(k in g for g in parts)}
    return {**total, **rates(total["env_steps"], time.perf_counter() - t_start, total["sim_s"])}


def rates(env_steps: float, wall_s: float, sim_s: float) -> dict:
    """A timing file's wall time and rates: env-steps per second end to end and simulating."""
    return {"wall_s": wall_s, "env_steps_per_s": env_steps / max(wall_s, 1e-9),
            "sim_env_steps_per_s": env_steps / max(sim_s, 1e-9)}
