"""Where two runs part: a digest of each robot's state after every chunk, and a comparison
of two results folders (``rosmeery diff A B``, docs/paper.md#across-machines).

With ``digest = true`` a session writes ``runs/<world>__<policy>.digest.csv``: per seed and
chunk (``chunk_s`` of simulated time, or the detector period), a 64-bit BLAKE2b digest of
each part of the state: ``physics`` (MJX positions and velocities, the pose), ``map`` (the
occupancy log-odds), ``knowledge`` (observed samples, labels and confidences) and
``detections`` (the detector's objects, labels, confidences and boxes of the chunk's
frames). A digest covers every bit, so one ulp anywhere changes it.

:func:`compare` names, per run and seed, the last chunk at which two folders agree and the
parts that differ next; without digests it falls back to the first sampled time at which
the trajectories differ, and by how much.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import jax
import numpy as np
import pandas as pd

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.results import tables
from rosmeery_jax.session.outputs import check_folder

PARTS = ("physics", "map", "knowledge", "detections")


def of_state(state) -> dict[str, list[str]]:
    """Per part, one digest per env (B,) of the batched state."""
    groups = {"physics": (state.physics.qpos, state.physics.qvel, state.pose), "map": (state.logodds,),
              "knowledge": tuple(jax.tree.leaves(state.knowledge))}
    return {part: rows(arrays) for part, arrays in groups.items()}


def rows(arrays) -> list[str]:
    """One digest per leading-axis row (B,) of the arrays, together."""
    host = [np.ascontiguousarray(np.asarray(a)) for a in arrays]
    return [_digest(a[r] for a in host) for r in range(host[0].shape[0])]


def _digest(parts) -> str:
    h = hashlib.blake2b(digest_size=8)
    for p in parts:
        h.update(str(p.dtype).encode() + str(p.shape).encode())
        h.update(np.ascontiguousarray(p).tobytes())
    return h.hexdigest()


def compare(a: str | Path, b: str | Path) -> list[str]:
    """One line per run and seed of two results folders: identical, or where they part."""
    a, b = Path(a), Path(b)
    in_a, in_b = _finished(a), _finished(b)
    check_folder(a)  # damaged files are named, not compared
    check_folder(b)
    lines = _settings(a, b)
    for run in sorted(in_a | in_b):
        if run not in in_a or run not in in_b:
            lines.append(f"{run}: only in {a if run in in_a else b}")
            continue
        digest = [f / "runs" / f"{run}.digest.csv" for f in (a, b)]
        lines += _by_digest(run, a, b) if all(p.is_file() for p in digest) else _by_path(run, a, b)
    return lines


NOT_SETTINGS = ("out", "seeds", "first_seed", "worlds", "policies", "devices", "digest")  # where, which runs, how


def _settings(a: Path, b: Path) -> list[str]:
    """One line naming the session settings that differ between the folders (noise,
    localisation, env, detector, mappers, ...): runs of different settings part for that
    reason, not by chance."""
    cfg = []
    for folder in (a, b):
        try:
            cfg.append(json.loads((folder / "config.json").read_text(encoding="utf-8"))["session"])
        except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError):
            return []  # a folder without its record: nothing to say of its settings
    keys = sorted((set(cfg[0]) | set(cfg[1])) - set(NOT_SETTINGS))
    differ = [f"{k} {cfg[0].get(k)!r} / {cfg[1].get(k)!r}" for k in keys if cfg[0].get(k) != cfg[1].get(k)]
    return [f"settings differ ({a} / {b}): " + "; ".join(differ)] if differ else []


def _one_side(run: str, seeds_a, seeds_b, a: Path, b: Path) -> list[str]:
    """A line for each seed that only one folder holds (another seed count or first seed)."""
    in_a, in_b = set(seeds_a), set(seeds_b)
    return [f"{run} seed {s}: only in {a if s in in_a else b}" for s in sorted(in_a ^ in_b, key=float)]


def _finished(folder: Path) -> set[str]:
    """The runs a results folder holds (those with a metrics file)."""
    runs = {p.name[:-len(".metrics.csv")] for p in (folder / "runs").glob("*.metrics.csv")} \
        if (folder / "runs").is_dir() else set()
    if not runs:
        raise InputError(str(folder), "runs", "no finished runs to compare (not a results folder?)")
    return runs


def _digests(path: Path) -> pd.DataFrame:
    """A digest file as text (an empty part, as ``detections`` without a detector, stays "":
    read as NaN it differed from itself), its seeds and chunks whole numbers."""
    df = tables.read_table(path, ("seed", "chunk", "time_s", *PARTS), dtype=str, keep_default_na=False)
    for c in ("seed", "chunk"):
        tables.numbers(df, path, c, seeds=True)  # checked; kept as text, as the digests are compared
    return df


def _by_digest(run: str, a: Path, b: Path) -> list[str]:
    da, db = (_digests(f / "runs" / f"{run}.digest.csv") for f in (a, b))
    out = _one_side(run, da.seed, db.seed, a, b)
    for seed, ga in sorted(da[da.seed.isin(db.seed)].groupby("seed"), key=lambda g: float(g[0])):
        gb = db[db.seed == seed]
        m = ga.merge(gb, on=["seed", "chunk", "time_s"], suffixes=("_a", "_b"))
        differ = [[p for p in PARTS if r[f"{p}_a"] != r[f"{p}_b"]] for _, r in m.iterrows()]
        first = next((k for k, d in enumerate(differ) if d), None)
        if first is None:
            out.append(f"{run} seed {seed}: identical over {len(m)} chunks")
            continue
        row = m.iloc[first]
        before = f"identical up to chunk {int(m.iloc[first - 1].chunk)} ({m.iloc[first - 1].time_s} s)" if first \
            else "different from the first chunk"
        out.append(f"{run} seed {seed}: {before}; at chunk {int(row.chunk)} ({row.time_s} s) "
                   f"{', '.join(differ[first])} differ")
    return out


def _path(path: Path) -> pd.DataFrame:
    """A run's trajectory file, its seed, time and pose columns numbers."""
    df = tables.read_table(path, ("seed", "time_s", "x", "y", "yaw"))
    for c in ("seed", "time_s", "x", "y", "yaw"):
        values = tables.numbers(df, path, c, seeds=c == "seed")
        df[c] = values.astype(np.int64) if c == "seed" else values
    return df


def _by_path(run: str, a: Path, b: Path) -> list[str]:
    ta, tb = (_path(f / "runs" / f"{run}.trajectory.csv") for f in (a, b))
    key = ["seed", "time_s"]
    m = ta.merge(tb, on=key, suffixes=("_a", "_b")).sort_values(key)
    out = _one_side(run, ta.seed, tb.seed, a, b)
    for seed, g in m.groupby("seed"):
        d = np.abs(g[["x_a", "y_a", "yaw_a"]].to_numpy() - g[["x_b", "y_b", "yaw_b"]].to_numpy()).max(1)
        k = np.flatnonzero(d > 0)
        if not len(k):
            out.append(f"{run} seed {seed}: the same path at every sampled time (no digests to compare)")
            continue
        t = g.time_s.to_numpy()
        out.append(f"{run} seed {seed}: the paths part at {t[k[0]]:g} s by {d[k[0]]:.2g} (m or rad); "
                   f"{d.max():.2g} at most (no digests: rerun both with --digest for the part and chunk)")
    return out
