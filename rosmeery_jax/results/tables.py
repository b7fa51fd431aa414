"""Results tables: long-format metric curves and per-object states, written atomically.

``metrics.csv``: world, policy, detector, mapper, seed, time_s, metric, value (one row per
sample; ``mapper`` is who built the scored map: "oracle", "perceived", or "own" for a map
scored by ``rosmeery evaluate``).
``objects.csv``: world, policy, detector, mapper, seed, object, category, ps_G, ps, coverage,
label, confidence, P_G, p (the final state of each object).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from rosmeery_jax.core.errors import InputError, shown
from rosmeery_jax.core.files import write_atomic
from rosmeery_jax.core.specs import MAX_SEED, plain_name

METRIC_COLUMNS = ["world", "policy", "detector", "mapper", "seed", "time_s", "metric", "value"]
NAME_COLUMNS = ("world", "policy", "detector", "mapper", "metric")  # their values name plot files
OBJECT_COLUMNS = ["world", "policy", "detector", "mapper", "seed", "object", "category", "ps_G", "ps", "coverage",
                  "label", "confidence", "P_G", "p"]


def seconds(t):
    """Times or durations in seconds (scalar or array) to the microsecond, as every results
    file writes them: 0.3, not 3 * 0.1 = 0.30000000000000004."""
    t = np.asarray(t, float)
    whole = np.abs(t) >= 2.0 ** 52  # no fraction to round, and rounding them would overflow
    return np.where(whole, t, np.round(np.where(whole, 0.0, t), 6))[()]


def not_seeds(values: np.ndarray) -> np.ndarray:
    """(R,) True where a table's seed column (as floats, NaN for text) holds no seed: a
    whole number from 0 to MAX_SEED."""
    return ~(np.isfinite(values) & (values >= 0) & (values <= MAX_SEED) & (values == np.round(values)))


def numbers(df: pd.DataFrame, path: Path, column: str, seeds: bool = False) -> np.ndarray:
    """``column`` of a table read by :func:`read_table` as float64, every value finite (a
    seed, with ``seeds``), or one InputError naming the file, row and column."""
    values = pd.to_numeric(df[column], errors="coerce").to_numpy(float)
    bad = np.flatnonzero(not_seeds(values) if seeds else ~np.isfinite(values))
    if len(bad):
        kind = f"a seed (a whole number from 0 to {MAX_SEED})" if seeds else "a finite number"
        raise InputError(str(path), f"row {bad[0] + 2}, column {column}", f"{shown(df[column].iloc[bad[0]])} is not {kind}")
    return values


def metric_frame(curves: dict[str, np.ndarray], times: np.ndarray, *, world: str, policy: str,
                 detector: str, seed: int, mapper: str = "oracle") -> pd.DataFrame:
    """Long table of curves {metric: (T,)} sampled at times (T,) seconds (:func:`seconds`)."""
    times = seconds(times)
    parts = [pd.DataFrame({"time_s": times, "metric": name, "value": np.asarray(c, float)}) for name, c in curves.items()]
    df = pd.concat(parts, ignore_index=True)
    df.insert(0, "seed", int(seed))
    df.insert(0, "mapper", mapper)
    df.insert(0, "detector", detector)
    df.insert(0, "policy", policy)
    df.insert(0, "world", world)
    return df[METRIC_COLUMNS]


def object_frame(world, log, *, policy: str, detector: str, seed: int, mapper: str = "oracle") -> pd.DataFrame:
    """Per-object final state from one env's :class:`ObjectLog` at one time (fields (N,))."""
    truth = world.truth
    names = world.taxonomy.names
    label = np.asarray(log.label)
    conf_held = np.where(label >= 0, np.asarray(log.conf_any), 0.0)
    ps = np.asarray(log.ps)
    ps = ps.astype(int) if np.all(ps == np.round(ps)) else ps.astype(float)
    return pd.DataFrame({
        "world": world.name, "policy": policy, "detector": detector, "mapper": mapper, "seed": int(seed),
        "object": list(truth.names), "category": list(truth.categories),
        "ps_G": np.asarray(truth.ps_G), "ps": ps, "coverage": ps / np.asarray(truth.ps_G),
        "label": [names[k] if k >= 0 else "" for k in label], "confidence": conf_held,
        "P_G": np.asarray(truth.num_predicates), "p": np.asarray(log.declared),
    })[OBJECT_COLUMNS]


def write_csv(df: pd.DataFrame, path: str | Path) -> Path:
    return write_atomic(path, df.to_csv(index=False))


def read_table(path: str | Path, columns=(), missing: str = "not found", **read) -> pd.DataFrame:
    """A CSV file's table with at least ``columns``, row k being the file's line k + 2 (the
    header is line 1); a missing (``missing`` says what it means), unreadable or short file
    is one InputError naming it. ``read``: pandas.read_csv's options."""
    path = Path(path)
    if not path.is_file():
        raise InputError(str(path), "file", missing)
    try:
        df = pd.read_csv(path, **read)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, OSError) as err:
        raise InputError(str(path), "file", f"not a readable CSV ({str(err).splitlines()[0][:120]})") from None
    df.index = pd.RangeIndex(len(df))  # a ragged file may have made its first fields an index
    absent = [c for c in columns if c not in df.columns]
    if absent:
        raise InputError(str(path), "columns", f"missing {', '.join(absent)}")
    return df


def load(directory: str | Path) -> pd.DataFrame:
    """The metric curves of a results folder as one long DataFrame (``metrics.csv``);
    a missing or malformed file is one InputError naming the file and the column or row."""
    path = Path(directory) / "metrics.csv"
    df = read_table(path, missing="not found: not a results folder")
    if "mapper" not in df.columns:  # results written before mappers were a column
        df["mapper"] = "oracle"
    missing = [c for c in METRIC_COLUMNS if c not in df.columns]
    if missing:
        raise InputError(str(path), "columns", f"missing {', '.join(missing)}")
    for c in NAME_COLUMNS:
        bad = [i for i, v in enumerate(df[c].astype(str)) if not plain_name(v)]
        if bad:
            cell = df[c].iloc[bad[0]]
            raise InputError(str(path), f"row {bad[0] + 2}, column {c}", "is empty" if pd.isna(cell) else
                             f"{shown(cell)} is not a plain name (names in a results table become file names: no "
                             "folders, no leading dot)")
    for c in ("seed", "time_s", "value"):
        values = numbers(df, path, c, seeds=c == "seed")
        df[c] = values.astype(int) if c == "seed" else values
    return df
