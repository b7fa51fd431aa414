"""Did a change move a session's results beyond seed noise? Compare two results folders.

    .venv/bin/python scripts/compare_sessions.py results/before results/after [--metrics ori,cori,opi]

For every (world, policy, mapper, metric) in both folders, the final value and the area
under the curve (time-normalised mean, 0..1) over seeds: mean ± std in each folder, and
whether they differ beyond noise by two rules: the difference of means exceeds one pooled
seed std ("1 std"), and Welch's t-test at p < 0.05. With 5 seeds a side and no real change,
about 11 % of comparisons pass the first rule and 5 % the second by chance, so the summary
line prints the counts beside those expectations.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from rosmeery_jax.core.errors import one_line
from rosmeery_jax.results import tables

KEYS = ["world", "policy", "mapper", "metric"]


def per_seed(folder: Path, metrics: list[str]) -> pd.DataFrame:
    """One row per (world, policy, mapper, metric, seed): final value and AUC."""
    df = tables.load(folder)
    df = df[df.metric.isin(metrics)]
    end = df.time_s.max()

    def summary(g: pd.DataFrame) -> pd.Series:
        g = g.sort_values("time_s")
        return pd.Series({"final": g.value.iloc[-1], "auc": np.trapezoid(g.value, g.time_s) / end})

    return df.groupby(KEYS + ["seed"])[["time_s", "value"]].apply(summary).reset_index()


def compare(a: pd.DataFrame, b: pd.DataFrame) -> pd.DataFrame:
    """One row per key present in both ``per_seed`` tables and per figure (final, auc)."""
    rows, after = [], b.set_index(KEYS).sort_index()
    for key, ga in a.groupby(KEYS):
        if key not in after.index:
            continue
        gb = after.loc[[key]]
        for what in ("final", "auc"):
            x, y = ga[what].to_numpy(), gb[what].to_numpy()
            pooled = np.sqrt((x.var() + y.var()) / 2)
            diff = y.mean() - x.mean()
            p = stats.ttest_ind(x, y, equal_var=False).pvalue if pooled > 0 else (1.0 if diff == 0 else 0.0)
            rows.append({**dict(zip(KEYS, key)), "figure": what, "before": f"{x.mean():.3f} ± {x.std():.3f}",
                         "after": f"{y.mean():.3f} ± {y.std():.3f}", "diff": diff,
                         "beyond_1std": abs(diff) > pooled, "p": p})
    return pd.DataFrame(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--metrics", default="ori,cori,opi")
    args = ap.parse_args()
    metrics = args.metrics.split(",")
    table = compare(per_seed(args.before, metrics), per_seed(args.after, metrics))
    pd.set_option("display.width", 200)
    print(table.assign(diff=table["diff"].round(3), p=table.p.round(3)).to_string(index=False))
    n = len(table)
    print(f"\n{n} comparisons: {int(table.beyond_1std.sum())} beyond one pooled std (about {0.11 * n:.0f} "
          f"expected by chance), {int((table.p < 0.05).sum())} with Welch p < 0.05 (about {0.05 * n:.0f} by chance)")


if __name__ == "__main__":
    one_line(main)
