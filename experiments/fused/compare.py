"""Fused against perceived under three kinds of sensing: a short check of the mappers'
share of the built-in knowledge's final ORI, OMQ and AP50 per world.

    .venv/bin/python experiments/fused/compare.py --out /tmp/fused [--seeds 2 --duration 120
        --policies random --detector oracle]

Runs one session per sensing (exact; realistic noise with scan matching; with dead
reckoning) with ``--mapper oracle,perceived,fused --metrics ori,omq,ap50``, then prints a
table: per world and sensing, each mapper's final ORI as a share of the oracle's (mean over
runs), and its OMQ and AP50.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from rosmeery_jax.apps.cli import main

SENSING = {"exact": [], "scan_matching": ["--noise", "realistic", "--localisation", "scan_matching"],
           "dead_reckoning": ["--noise", "realistic", "--localisation", "dead_reckoning"]}


def run(out: Path, args) -> None:
    for name, extra in SENSING.items():
        if (out / name / "metrics.csv").exists():
            continue
        assert main(["run", "--worlds", args.worlds, "--policies", args.policies, "--seeds", str(args.seeds),
                     "--duration", str(args.duration), "--detector", args.detector, "--mapper",
                     "oracle,perceived,fused", "--metrics", "ori,omq,ap50", "--quiet", "--out", str(out / name),
                     *extra]) == 0


def table(out: Path) -> pd.DataFrame:
    rows = []
    for name in SENSING:
        df = pd.read_csv(out / name / "metrics.csv")
        final = df[df.time_s == df.time_s.max()]
        wide = final.pivot_table(index=["world", "policy", "seed", "mapper"], columns="metric", values="value")
        oracle = wide.xs("oracle", level="mapper")["ori"]
        for mapper in ("perceived", "fused"):
            m = wide.xs(mapper, level="mapper")
            share = (m["ori"] / oracle).groupby("world").mean()
            rest = m.groupby("world")[["omq", "ap50"]].mean()
            for world in share.index:
                rows.append({"world": world, "sensing": name, "mapper": mapper, "ori_share": share[world],
                             "omq": rest.omq[world], "ap50": rest.ap50[world]})
    return pd.DataFrame(rows).pivot_table(index=["world", "sensing"], columns="mapper",
                                          values=["ori_share", "omq", "ap50"]).round(3)


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--worlds", default="kitchen,laboratory,small_office,large_office")
    p.add_argument("--policies", default="random")
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--duration", type=float, default=120.0)
    p.add_argument("--detector", default="oracle")
    a = p.parse_args()
    run(a.out, a)
    with pd.option_context("display.width", 200):
        print(table(a.out))
