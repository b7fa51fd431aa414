"""The usefulness tables of docs/paper.md ("How useful the map is") from session folders.

    .venv/bin/python experiments/usefulness/table.py results/usefulness_exact results/usefulness_noisy

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


def at_times(df: pd.DataFrame) -> str:
    rows = []
    for (world, policy), part in df.groupby(["world", "policy"], sort=False):
        cells = []
        for mapper in ("oracle", "perceived"):
            for t in TIMES:
                m = part[(part.mapper == mapper) & (part.time_s == t)]
                s, spl = (m[m.metric == k].value.mean() for k in ("task_success", "task_spl"))
                cells.append(f"{s:.2f} / {spl:.2f}")
        rows.append(f"| {WORLDS.get(world, world)} | {policy} | " + " | ".join(cells) + " |")
    head = " | ".join(f"{m} {t:g} s" for m in ("oracle", "perceived") for t in TIMES)
    return "\n".join([f"| world | policy | {head} |", "|---|---|" + "---|" * 2 * len(TIMES), *rows])


def tau(ori: np.ndarray, spl: np.ndarray) -> str:
    if len(ori) < 3 or np.ptp(ori) == 0 or np.ptp(spl) == 0:
        return "n/a"
    t = stats.kendalltau(ori, spl).statistic
    ci = stats.bootstrap((ori, spl), lambda a, b: stats.kendalltau(a, b).statistic, paired=True,
                         n_resamples=2000, vectorized=False, rng=np.random.default_rng(0), method="percentile")
    lo, hi = ci.confidence_interval
    return f"{t:+.2f} [{lo:+.2f}, {hi:+.2f}]"


def taus(df: pd.DataFrame) -> str:
    final = df[df.time_s == df.time_s.max()].pivot_table(index=["world", "policy", "seed", "mapper"],
                                                          columns="metric", values="value").reset_index()
    rows = []
    for mapper in ("oracle", "perceived"):
        f = final[final.mapper == mapper]
        cells = [tau(f.ori.to_numpy(), f.task_spl.to_numpy()) + f" (n={len(f)})"]
        for world in WORLDS:
            w = f[f.world == world]
            cells.append(tau(w.ori.to_numpy(), w.task_spl.to_numpy()))
        rows.append(f"| {mapper} | " + " | ".join(cells) + " |")
    head = " | ".join(WORLDS.values())
    return "\n".join([f"| mapper | all runs | {head} |", "|---|---|" + "---|" * len(WORLDS), *rows])


def main(folders: list[str]) -> None:
    for folder in map(Path, folders):
        df = curves(folder)
        print(f"## {folder}\n\ntask success / SPL, mean over seeds\n\n{at_times(df)}\n\n"
              f"Kendall's tau, final ORI vs final task SPL, 95 % bootstrap interval\n\n{taus(df)}\n")


if __name__ == "__main__":
    main(sys.argv[1:])
