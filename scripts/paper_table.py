"""Print the README's paper table and the figures its findings quote, from a results folder.

    .venv/bin/python scripts/paper_table.py results/paper
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

TITLES = {"kitchen": "Kitchen", "laboratory": "Laboratory", "small_office": "Small Office",
          "large_office": "Large Office"}
POLICIES = ("frontier", "random", "semantic_nbv")


def table(final: pd.DataFrame) -> None:
    """The README's table of final values (mean ± std over seeds; bold within one std of the best)."""
    print("| world | metric | frontier | random | semantic NBV |\n|---|---|---|---|---|")
    for w, title in TITLES.items():
        for m in ("ori", "cori", "opi"):
            part = final[(final.world == w) & (final.metric == m)].groupby("policy").value
            stats = pd.DataFrame({"mean": part.mean(), "std": part.std(ddof=0)})
            best = stats["mean"].idxmax()
            cells = []
            for p in POLICIES:
                mean, std = stats.loc[p, "mean"], stats.loc[p, "std"]
                text = f"{mean:.2f} ± {std:.2f}"
                cells.append(f"**{text}**" if mean >= stats.loc[best, "mean"] - stats.loc[best, "std"] else text)
            print(f"| {title if m == 'ori' else ''} | {m.upper().replace('CORI', 'cORI')} | " + " | ".join(cells) + " |")


def main(folder: str) -> None:
    out = Path(folder)
    full = pd.read_csv(out / "metrics.csv")
    if "mapper" not in full.columns:
        full["mapper"] = "oracle"
    end = full.time_s.max()
    for mapper in sorted(full.mapper.unique()):
        print(f"\nmapper: {mapper}")
        part = full[full.mapper == mapper]
        table(part[np.isclose(part.time_s, end)])
    if {"oracle", "perceived"} <= set(full.mapper):
        f = full[np.isclose(full.time_s, end) & (full.metric == "ori")]
        ratio = f.pivot_table(index=["world", "policy"], columns="mapper", values="value", aggfunc="mean")
        print("\nfinal ORI, perceived / oracle (mean over seeds):\n",
              (ratio.perceived / ratio.oracle).round(2).unstack().to_string())
    df = full[full.mapper == "oracle"]
    final = df[np.isclose(df.time_s, end)]
    ori = df[df.metric == "ori"]
    print("\nORI gained over the last 120 s (mean over seeds):")
    for (w, p), g in ori.groupby(["world", "policy"]):
        per_seed = g.pivot(index="time_s", columns="seed", values="value")
        gain = (per_seed.iloc[-1] - per_seed.loc[per_seed.index >= end - 120].iloc[0]).mean()
        t90 = []
        for s in per_seed.columns:
            v = per_seed[s].to_numpy()
            t90.append(per_seed.index[np.argmax(v >= 0.9 * v[-1])])
        print(f"  {w:<13}{p:<14} gain {gain:+.3f}   t90 {np.mean(t90):6.0f} s")
    strict = final[final.metric.isin(["opi", "opi_strict"])].groupby(["world", "policy", "metric"]).value.mean()
    print("\nOPI vs OPI-strict:\n", strict.unstack().round(2).to_string())
    traj = pd.read_csv(out / "trajectories.csv")
    dist = traj.sort_values("time_s").groupby(["world", "policy", "seed"])[["x", "y"]].apply(
        lambda g: float(np.hypot(np.diff(g.x), np.diff(g.y)).sum()))
    print("\nmetres driven (mean over seeds, 1 s samples):\n", dist.groupby(["world", "policy"]).mean().round(0)
          .unstack().to_string())


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "results/paper")
