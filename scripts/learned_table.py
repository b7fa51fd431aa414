"""Print the README's learned-explorer table and its target checks from a results folder of
``experiments/learned/evaluate.toml``, and draw the ORI curves into docs/learned/.

    .venv/bin/python scripts/learned_table.py results/learned_eval [--figures docs/learned]

The measures of what limits the explorers (``experiments/learned/*.toml``) run the same
worlds and seeds, so their runs pair by seed with the evaluation's: ``--with`` adds their
folders, and ``--against`` compares every policy with one, per world (the tables of
docs/learned.md):

    .venv/bin/python scripts/learned_table.py results/learned_eval --with results/gradient_variants --against semantic_nbv

ORI AUC is the time average of a run's ORI curve (``rosmeery_jax.metrics.indices.summarize``).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import pandas as pd

from rosmeery_jax.core.errors import one_line
from rosmeery_jax.metrics.indices import summarize
from rosmeery_jax.results import statistics, tables

PAPER = ("kitchen", "laboratory", "small_office", "large_office")
POLICIES = ("learned", "gradient_nbv", "frontier", "random", "semantic_nbv")


def per_run(df: pd.DataFrame, metric: str = "ori") -> pd.DataFrame:
    """One row per (world, policy, seed): final value and AUC of ``metric``."""
    rows = []
    for (w, p, s), g in df[(df.metric == metric) & (df.mapper == "oracle")].groupby(["world", "policy", "seed"]):
        g = g.sort_values("time_s")
        rows.append({"world": w, "policy": p, "seed": s, **summarize(g.time_s.to_numpy(), g.value.to_numpy())})
    return pd.DataFrame(rows)


def label(world: str) -> str:
    """The docs' name of a world: "Small Office", "generated office 1000"."""
    if world.startswith("procedural_"):
        return "generated " + " ".join(world.split("_")[1:])
    return world.replace("_", " ").title()


def table(runs: pd.DataFrame, policies: list[str]) -> None:
    """ORI AUC mean [95 % interval] over seeds (final ORI in brackets); bold the world's best
    and every policy a paired test by seed cannot tell from it at 95 %. Paper worlds first,
    then the generated ones, each set followed by its mean row (best mean in bold)."""
    print("| world | " + " | ".join(policies) + " |\n|---|" + "---|" * len(policies))
    present = list(dict.fromkeys(runs.world))
    for name, worlds in (("paper worlds", [w for w in PAPER if w in present]),
                         ("generated", sorted((w for w in present if w not in PAPER),
                                              key=lambda w: (w.split("_")[1], w)))):
        for w in worlds:
            g = runs[runs.world == w]
            auc = g.pivot_table(index="seed", columns="policy", values="auc")
            final = g.groupby("policy").final.mean()
            ran = [p for p in policies if p in auc]  # a measure may run some worlds only
            cells = dict(zip(ran, statistics.bold_cells(
                auc, ran, lambda p, ci: f"{ci.mean:.3f} {ci.bounds('.3f')} ({final[p]:.2f})")))
            print(f"| {label(w)} | " + " | ".join(cells.get(p, "-") for p in policies) + " |")
        if worlds:
            sets = runs[runs.world.isin(worlds)].groupby("policy")
            means = sets.auc.mean()[sets.world.nunique() == len(worlds)]  # over every world of the set only
            cells = [f"**{means[p]:.3f}**" if p == means.idxmax() else f"{means[p]:.3f}" if p in means else "-"
                     for p in policies]
            print(f"| *mean, {name}* | " + " | ".join(cells) + " |")


def paired(runs: pd.DataFrame, a: str, b: str) -> None:
    """b against a on ORI AUC, paired by seed, per world."""
    print(f"\n{b} - {a}, ORI AUC paired by seed (95 % interval, sign-flip test):")
    for w, g in runs.groupby("world", sort=False):
        auc = g.pivot_table(index="seed", columns="policy", values="auc")
        r = statistics.paired(auc[a], auc[b])
        print(f"  {w:<26}{r.diff.mean:+.3f} {r.diff.bounds('+.3f')}  p = {r.p:.4f}"
              f"  {'significant' if r.significant else 'no difference shown'} at 95 % ({r.seeds} seeds)")


def targets(runs: pd.DataFrame) -> None:
    auc = runs.groupby(["world", "policy"]).auc.mean().unstack()
    for name, worlds in (("paper worlds", [w for w in PAPER if w in auc.index]),
                         ("generated held-out worlds", [w for w in auc.index if w not in PAPER])):
        if worlds:  # the policies that ran every one of them
            print(f"\nmean ORI AUC over the {len(worlds)} {name}:\n"
                  + auc.loc[worlds].dropna(axis=1).mean().round(3).to_string())
    paper = auc.loc[[w for w in PAPER if w in auc.index]]
    if {"learned", "frontier", "random"} <= set(paper.columns):
        m = paper.mean()
        print(f"\nlearned vs frontier: {m.learned - m.frontier:+.3f}; vs random: {m.learned - m.random:+.3f} "
              "(mean ORI AUC over the paper worlds)")
    if {"learned", "random"} <= set(paper.columns):
        paired(runs, "random", "learned")
    if {"gradient_nbv", "semantic_nbv"} <= set(paper.columns):
        paired(runs, "semantic_nbv", "gradient_nbv")
        wins = (paper.gradient_nbv > paper.semantic_nbv)
        print(f"gradient_nbv's mean ORI AUC is above semantic_nbv's in {int(wins.sum())} of {len(paper)} paper "
              "worlds (means, not a test; the paired lines above test them): "
              + ", ".join(f"{w} {paper.gradient_nbv[w] - paper.semantic_nbv[w]:+.3f}" for w in paper.index))


def against(runs: pd.DataFrame, base: str) -> None:
    """Every other policy against ``base`` on ORI AUC, paired by seed, per world: the mean
    difference, in standard deviations of the per-seed differences, and the test's p."""
    print(f"\nagainst {base}, ORI AUC paired by seed: difference (in SDs of the per-seed differences), p")
    for p in sorted(set(runs.policy) - {base}):
        cells = []
        for w, g in runs.groupby("world", sort=False):
            auc = g.pivot_table(index="seed", columns="policy", values="auc")
            both = auc[[base, p]].dropna() if p in auc and base in auc else ()  # the seeds both ran
            if len(both):
                r = statistics.paired(both[base], both[p])
                sds = f"{r.in_sds:+.1f}" if math.isfinite(r.in_sds) else "no spread"
                cells.append(f"{label(w)} {r.diff.mean:+.3f} ({sds}) p {r.p:.3f}"
                             + (f" ({r.seeds} seeds)" if r.seeds < len(auc) else ""))
        print(f"  {p}: " + "; ".join(cells))


def figures(df: pd.DataFrame, directory: Path) -> None:
    import matplotlib.pyplot as plt

    from rosmeery_jax.results.plots import plot_curves, save_figure

    worlds = list(dict.fromkeys(df.world))
    fig, axes = plt.subplots((len(worlds) + 1) // 2, 2, figsize=(12, 3.4 * ((len(worlds) + 1) // 2)), squeeze=False)
    for ax, w in zip(axes.flat, worlds):
        plot_curves(df[df.mapper == "oracle"], w, "ori", ax)
    for ax in list(axes.flat)[len(worlds):]:
        ax.set_visible(False)
    fig.tight_layout()
    print(f"\nwrote {save_figure(fig, directory / 'ori.png')}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", nargs="?", default="results/learned_eval")
    ap.add_argument("--figures", default="", help="folder for ori.png (none when empty)")
    ap.add_argument("--with", dest="more", action="append", default=[],
                    help="another results folder of the same worlds and seeds (repeatable)")
    ap.add_argument("--against", default="", help="compare every policy with this one, per world")
    args = ap.parse_args()
    df = pd.concat([tables.load(f) for f in [args.folder, *args.more]], ignore_index=True)
    runs = per_run(df)
    policies = [p for p in POLICIES if p in set(runs.policy)] + sorted(set(runs.policy) - set(POLICIES))
    table(runs, policies)
    targets(runs)
    if args.against:
        against(runs, args.against)
    if args.figures:
        figures(df, Path(args.figures))


if __name__ == "__main__":
    one_line(main)
