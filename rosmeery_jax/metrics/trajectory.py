"""Replay a recorded trajectory: place the robot at each pose (no physics) and score it.

Input: a CSV with columns t, x, y, yaw (seconds, metres, radians; t strictly increasing),
or a session's ``trajectories.csv`` (world, policy, seed, time_s, x, y, yaw), of which one
run is replayed: the world's rows of the ``run`` (policy, seed) asked for.
At every pose the depth camera renders a frame, coverage and labels update (detector off:
ground-truth labels of observed objects), and the per-object log is recorded; the metric
curves follow from the logs. The whole trajectory runs as one jitted ``lax.scan``.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from rosmeery_jax import metrics
from rosmeery_jax.core import specs, xla
from rosmeery_jax.core.errors import InputError, shown
from rosmeery_jax.raycast.sensors import depth_seg
from rosmeery_jax.results import tables

POSE_COLUMNS = ("t", "x", "y", "yaw")
SESSION_COLUMNS = ("world", "policy", "seed", "time_s")  # a session's trajectories.csv holds these too
MAX_COORD = 1e6  # larger coordinates are corrupt (and would overflow float32)


def read_poses(path: str | Path, world=None, run: tuple[str, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(times (T,), poses (T, 3)) from a CSV; one-line InputError naming the file and field.
    With ``world``, every pose must lie on its floor plan's grid. From a session's
    trajectories, the rows of ``world`` and ``run`` = (policy, seed) (``run`` may be left
    out when the file holds one run of the world)."""
    path = Path(path)
    df = tables.read_table(path)
    session = set(SESSION_COLUMNS) <= set(df.columns)
    if session:
        df = session_run(df, path, world, run)
    elif run is not None:
        raise InputError(str(path), "columns", f"no {', '.join(SESSION_COLUMNS)}: not a session's trajectories, "
                         "so there is no run to pick")
    col = dict(zip(POSE_COLUMNS, ("time_s" if session else "t", "x", "y", "yaw")))  # as the file names them
    missing = [col[c] for c in POSE_COLUMNS if col[c] not in df.columns]
    if missing:
        raise InputError(str(path), "columns", f"missing {', '.join(missing)} (need {', '.join(col.values())})")
    if len(df) == 0:
        raise InputError(str(path), "rows", "no poses")
    t, x, y, yaw = (_finite(df, path, col[c], c == "t") for c in POSE_COLUMNS)
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        raise InputError(str(path), f"row {_line(df, back[0] + 1)}, column {col['t']}", "times must strictly increase")
    if t[0] < 0:
        raise InputError(str(path), f"row {_line(df, 0)}, column {col['t']}", f"{t[0]:g} s: times start at 0 or later")
    poses = np.stack([x, y, yaw], -1).astype(np.float32)
    if world is not None:
        outside = [k for k, xy in enumerate(poses[:, :2]) if not world.free_space.contains(xy)]
        if outside:
            k = outside[0]
            raise InputError(str(path), f"row {_line(df, k)}, columns x, y", f"({poses[k, 0]:g}, {poses[k, 1]:g}) "
                             f"lies outside the world {world.name!r}")
    return t, poses


def _line(df: pd.DataFrame, k: int) -> int:
    """The file's line of the k-th row left in ``df``."""
    return int(df.index[k]) + 2


def _finite(df: pd.DataFrame, path: Path, name: str, unbounded: bool) -> np.ndarray:
    """Column ``name`` as float64, every value finite (and within MAX_COORD unless ``unbounded``)."""
    v = pd.to_numeric(df[name], errors="coerce").to_numpy(float)
    bad = np.flatnonzero(~(np.isfinite(v) & ((np.abs(v) <= MAX_COORD) | unbounded)))
    if len(bad):
        raise InputError(str(path), f"row {_line(df, bad[0])}, column {name}", f"{shown(df[name].iloc[bad[0]])} is not a "
                         "finite number" + ("" if unbounded else f" within {MAX_COORD:g}"))
    return v


def session_run(df: pd.DataFrame, path: Path, world, run: tuple[str, int] | None) -> pd.DataFrame:
    """The rows of one run of a session's trajectories (world, policy, seed, time_s, ...).
    ``world`` picks the world (required when the file holds several); ``run`` = (policy,
    seed), required when the world has several runs."""
    seed = pd.to_numeric(df["seed"], errors="coerce").to_numpy(float)
    bad = np.flatnonzero(tables.not_seeds(seed))
    if len(bad):
        raise InputError(str(path), f"row {_line(df, bad[0])}, column seed", f"{shown(df['seed'].iloc[bad[0]])} is not a seed "
                         f"(a whole number from 0 to {specs.MAX_SEED})")
    df = df.assign(seed=seed.astype(np.int64), policy=df["policy"].fillna("").astype(str),
                   world=df["world"].fillna("").astype(str))
    if world is not None:
        df = df[df["world"] == world.name]
        if not len(df):
            raise InputError(str(path), "world", f"no run in the world {world.name!r}")
    elif df["world"].nunique() > 1:
        raise InputError(str(path), "world", "holds several worlds: name the world")
    runs = list(dict.fromkeys(f"{p}:{k}" for p, k in zip(df["policy"], df["seed"])))
    if run is not None:
        df = df[(df["policy"] == run[0]) & (df["seed"] == run[1])]
        if not len(df):
            raise InputError(str(path), "run", f"no run {run[0]}:{run[1]} (it holds {_listed(runs)})")
    elif len(runs) > 1:
        raise InputError(str(path), "run", f"holds {len(runs)} runs ({_listed(runs)}): pick one as POLICY:SEED")
    return df  # its index: the rows' places in the file (for the caller's messages)


def _listed(runs: list[str], most: int = 6) -> str:
    return ", ".join(runs[:most]) + (f", ... ({len(runs) - most} more)" if len(runs) > most else "")


class Replay(NamedTuple):
    """times (T,); logs: ObjectLog with (T, N) fields; knowledge: the final Knowledge;
    stamps (S,) int32: the pose index at which each surface sample was first observed, -1
    never (what the field map metrics of the built-in knowledge's map are scored from)."""

    times: np.ndarray
    logs: object
    knowledge: object
    stamps: np.ndarray


def replay(env, times: np.ndarray, poses: np.ndarray) -> Replay:
    """Run the observer over poses (T, 3) with ``env``'s camera and knowledge settings."""
    (k, stamps), logs = _observer(env)(env.sk.init(), jnp.asarray(poses, jnp.float32))
    return Replay(np.asarray(times, float), jax.tree.map(np.asarray, logs), jax.tree.map(np.asarray, k),
                  np.asarray(stamps))


@functools.lru_cache(maxsize=16)
def _observer(env):
    """The jitted scan for one env (compiled once per trajectory length)."""
    cam = env.config.camera

    def observe(carry, step):
        k, stamps = carry
        pose, t = step
        depth, _ = depth_seg(env.rays, cam, pose)
        k = env.sk.observe(k, pose, depth)
        labelled = env.sk.label_observed(k) if env.config.labels == "observed" else k
        stamps = jnp.where((jnp.asarray(k.seen, jnp.float32) > 0.5) & (stamps < 0), t, stamps)
        return (labelled, stamps), env.sk.log(labelled)

    def run(init, poses):
        stamps = jnp.full(jnp.shape(init.seen), -1, jnp.int32)
        return jax.lax.scan(observe, (init, stamps), (poses, jnp.arange(len(poses), dtype=jnp.int32)))

    return xla.jit(run)


def curves(env, result: Replay, names=metrics.DEFAULT_METRICS) -> dict[str, np.ndarray]:
    return metrics.compute(result.logs, env.sk.truth, names)
