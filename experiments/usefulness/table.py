"""The usefulness tables of docs/paper.md ("How useful the map is") from session folders.

    .venv/bin/python experiments/usefulness/table.py exact=results/usefulness_exact \
        scan_matching=results/usefulness_noisy

Each folder is a session with the task metrics (``--metrics ori,task``) and the mappers
``oracle,perceived``. Prints, per folder, the mean task success / SPL over its seeds at 60,
120, 240 and 480 s per world, policy and mapper, then Kendall's tau (tau-b) over runs between
final ORI and final task SPL, per mapper, pooled and within each world, with a 95 %
bootstrap interval (runs resampled, 2,000 times, seed 0).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

TIMES = (60.0, 120.0, 240.0, 480.0)
WORLDS = {"kitchen": "Kitchen", "laboratory": "Laboratory", "small_office": "Small Office",
          "large_office": "Large Office"}


def curves(folder: Path) -> pd.DataFrame:
    df = pd.read_csv(folder / "metrics.csv")
    return df[df.metric.isin(["ori", "task_success", "task_spl"])]


def cell(part: pd.DataFrame) -> str:
    """Mean success and SPL over seeds at each of TIMES: 'S 0.69 0.86 0.98 0.98 · SPL 0.64 ...'."""
    out = []
    for key, name in (("task_success", "S"), ("task_spl", "SPL")):
        v = [part[(part.metric == key) & (part.time_s == t)].value.mean() for t in TIMES]
        out.append(name + " " + " ".join(f"{x:.2f}" for x in v))
    return " · ".join(out)


def at_times(frames: dict) -> str:
    """One row per world and policy; a column per (folder, mapper)."""
    names = [(label, mapper) for label in frames for mapper in ("oracle", "perceived")]
    first = next(iter(frames.values()))
    rows = []
    for world, policy in first[["world", "policy"]].drop_duplicates().itertuples(index=False):
        cells = [cell(frames[label][(frames[label].world == world) & (frames[label].policy == policy)
                                    & (frames[label].mapper == mapper)]) for label, mapper in names]
        rows.append(f"| {WORLDS.get(world, world)} | {policy} | " + " | ".join(cells) + " |")
    head = " | ".join(f"{mapper}, {label}" for label, mapper in names)
    return "\n".join([f"| world | policy | {head} |", "|---|---|" + "---|" * len(names), *rows])


def tau(ori: np.ndarray, spl: np.ndarray) -> str:
    if len(ori) < 3 or np.ptp(ori) == 0 or np.ptp(spl) == 0:
        return "n/a"
    t = stats.kendalltau(ori, spl).statistic
    ci = stats.bootstrap((ori, spl), lambda a, b: stats.kendalltau(a, b).statistic, paired=True,
                         n_resamples=2000, vectorized=False, rng=np.random.default_rng(0), method="percentile")
    lo, hi = ci.confidence_interval
    if not (np.isfinite(lo) and np.isfinite(hi)):  # resamples too alike (SPL nearly constant)
        return f"{t:+.2f} [no interval]"
    return f"{t:+.2f} [{lo:+.2f}, {hi:+.2f}]"


def taus(frames: dict) -> str:
    rows = []
    for label, df in frames.items():
        final = df[df.time_s == df.time_s.max()].pivot_table(index=["world", "policy", "seed", "mapper"],
                                                              columns="metric", values="value").reset_index()
        for mapper in ("oracle", "perceived"):
            f = final[final.mapper == mapper]
            cells = [tau(f.ori.to_numpy(), f.task_spl.to_numpy()) + f" (n={len(f)})"]
            cells += [tau(w.ori.to_numpy(), w.task_spl.to_numpy()) for w in (f[f.world == k] for k in WORLDS)]
            rows.append(f"| {mapper}, {label} | " + " | ".join(cells) + " |")
    head = " | ".join(WORLDS.values())
    return "\n".join([f"| map | all runs | {head} |", "|---|---|" + "---|" * len(WORLDS), *rows])


def main(folders: list[str]) -> None:
    """Folders as LABEL=DIR (or DIR: its name is the label)."""
    frames = {}
    for f in folders:
        label, _, path = f.rpartition("=")
        frames[label or Path(path).name] = curves(Path(path))
    print(f"task success (S) and SPL at {', '.join(f'{t:g}' for t in TIMES)} s, mean over seeds\n\n{at_times(frames)}\n\n"
          f"Kendall's tau, final ORI vs final task SPL, 95 % bootstrap interval\n\n{taus(frames)}")


if __name__ == "__main__":
    main(sys.argv[1:])
