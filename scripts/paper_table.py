"""Print the paper table (intervals over seeds, paired tests by seed) and the figures its
findings quote, from a results folder.

    .venv/bin/python scripts/paper_table.py results/paper
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from rosmeery_jax.core.errors import InputError, one_line
from rosmeery_jax.results import statistics, tables

TITLES = {"kitchen": "Kitchen", "laboratory": "Laboratory", "small_office": "Small Office",
          "large_office": "Large Office"}
POLICIES = ("frontier", "random", "semantic_nbv")


def _per_seed(final: pd.DataFrame, world: str, metric: str) -> pd.DataFrame:
    """Final values, one row per seed and one column per policy."""
    part = final[(final.world == world) & (final.metric == metric)]
    return part.pivot_table(index="seed", columns="policy", values="value")


def table(final: pd.DataFrame) -> None:
    """The paper table: mean [95 % bootstrap interval] over seeds; bold the best and every
    policy a paired test by seed cannot tell from it at 95 %."""
    print("| world | metric | frontier | random | semantic NBV |\n|---|---|---|---|---|")
    for w, title in TITLES.items():
        for m in ("ori", "cori", "opi"):
            seeds = _per_seed(final, w, m)
            cells = statistics.bold_cells(seeds, POLICIES, lambda p, ci: f"{ci.mean:.2f} {ci.bounds()}")
            print(f"| {title if m == 'ori' else ''} | {m.upper().replace('CORI', 'cORI')} | " + " | ".join(cells) + " |")


FIELD = {"omq": "OMQ", "ap": "AP", "ap50": "AP50", "ap25": "AP25", "f1_25": "F1 @ IoU 0.25", "f1_weak": "F1 weak",
         "accuracy_5cm": "accuracy 5 cm", "completeness_5cm": "completeness 5 cm", "chamfer_5cm": "Chamfer 5 cm (cm)",
         "miou": "mIoU"}


def field_table(final: pd.DataFrame) -> None:
    """The field's map metrics (docs/metrics.md): mean [95 % bootstrap interval] over seeds,
    per world, metric and policy; no bold (the Chamfer is better lower)."""
    print("| world | metric | frontier | random | semantic NBV |\n|---|---|---|---|---|")
    for w, title in TITLES.items():
        for k, (m, name) in enumerate(FIELD.items()):
            seeds = _per_seed(final, w, m) * (100 if m.startswith("chamfer") else 1)
            cells = [f"{ci.mean:.2f} {ci.bounds()}" for ci in (statistics.interval(seeds[p]) for p in POLICIES)]
            print(f"| {title if k == 0 else ''} | {name} | " + " | ".join(cells) + " |")


def comparisons(final: pd.DataFrame, metric: str = "ori") -> None:
    """Every pair of policies per world, paired by seed: the difference of final values, its
    interval, the permutation test's p and the verdict at 95 %."""
    print(f"\npaired comparisons of final {metric.upper()} by seed (b - a, 95 % interval, sign-flip test):")
    for w, title in TITLES.items():
        seeds = _per_seed(final, w, metric)
        for a, b in ((a, b) for i, a in enumerate(POLICIES) for b in POLICIES[i + 1:]):
            r = statistics.paired(seeds[a], seeds[b])
            verdict = (f"{b if r.diff.mean > 0 else a} ahead" if r.significant else "no difference shown")
            print(f"  {title:<13}{b:>13} - {a:<13}{r.diff.mean:+.3f} {r.diff.bounds('+.3f')}  "
                  f"p = {r.p:.4f}  ({r.seeds} seed{'s' * (r.seeds != 1)}): {verdict}")


def _check_runs(full: pd.DataFrame, out: Path) -> None:
    """The paper's worlds and policies are all in the folder."""
    for key, wanted in (("world", TITLES), ("policy", POLICIES)):
        missing = [w for w in wanted if w not in set(full[key])]
        if missing:
            raise InputError(str(out / "metrics.csv"), key, f"no {missing[0]} rows: the paper table needs the "
                             f"worlds {', '.join(TITLES)} and the policies {', '.join(POLICIES)}")


def main(folder: str) -> None:
    out = Path(folder)
    full = tables.load(out)
    _check_runs(full, out)
    fewest, needed = int(full.groupby(["world", "policy"]).seed.nunique().min()), statistics.seeds_needed()
    if fewest < needed:
        print(f"note: {fewest} seed{'s' * (fewest > 1)} in the smallest run group: an interval needs 3, and a "
              f"paired test {needed} to show a difference at 95 %")
    end = full.time_s.max()
    for mapper in sorted(full.mapper.unique()):
        print(f"\nmapper: {mapper}")
        part = full[full.mapper == mapper]
        table(part[np.isclose(part.time_s, end)])
        comparisons(part[np.isclose(part.time_s, end)])
        if set(FIELD) <= set(part.metric):
            print(f"\nthe field's map metrics, mapper {mapper}:")
            field_table(part[np.isclose(part.time_s, end)])
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
    traj = tables.read_table(out / "trajectories.csv", ["world", "policy", "seed", "time_s", "x", "y"])
    dist = traj.sort_values("time_s").groupby(["world", "policy", "seed"])[["x", "y"]].apply(
        lambda g: float(np.hypot(np.diff(g.x), np.diff(g.y)).sum()))
    print("\nmetres driven (mean over seeds, 1 s samples):\n", dist.groupby(["world", "policy"]).mean().round(0)
          .unstack().to_string())


if __name__ == "__main__":
    one_line(main, sys.argv[1] if len(sys.argv) > 1 else "results/paper")
