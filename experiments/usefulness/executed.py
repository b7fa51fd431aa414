"""Executed tasks of a session run with ``--task objectnav``: per world and mapper, the
robots' success and SPL (means over seeds of the per-run means, as docs/tasks.md defines
them) beside the query's success on the same maps, and how the navigator ended the
episodes; then the task phase's time against the exploration's.

    .venv/bin/python experiments/usefulness/executed.py results/usefulness_exact
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pandas as pd

from rosmeery_jax.session import objectnav


def main(folder: str) -> None:
    out = Path(folder)
    tasks = pd.read_csv(out / "tasks.csv")
    means = objectnav.means(tasks)
    query = tasks.groupby(["world", "mapper", "seed"]).query_success.mean().groupby(["world", "mapper"]).mean()
    cells = means.groupby(["world", "mapper"])[["objectnav_success", "objectnav_spl"]].mean()
    ends = tasks.groupby(["world", "mapper"]).navigator.value_counts(normalize=True).unstack(fill_value=0.0)
    print("| world | mapper | success | SPL | query success | reached | stuck | unreachable | no goal |")
    print("|---|---|---|---|---|---|---|---|---|")
    for (world, mapper), row in cells.iterrows():
        e = ends.loc[(world, mapper)]
        print(f"| {world} | {mapper} | {row.objectnav_success:.2f} | {row.objectnav_spl:.2f} | "
              f"{query[(world, mapper)]:.2f} | {e.get('reached', 0):.2f} | {e.get('stuck', 0):.2f} | "
              f"{e.get('unreachable', 0):.2f} | {e.get('idle', 0):.2f} |")
    timing = json.loads((out / "timing.json").read_text())
    task_s = sum(g.get("task_s", 0.0) for g in timing["groups"])
    explore_s = sum(g["wall_s"] for g in timing["groups"]) - task_s
    print(f"\n{len(tasks)} episodes driven in {task_s:.1f} s; the groups explored in {explore_s:.1f} s "
          f"(ratio {task_s / explore_s:.2f}); the session's wall time {timing['wall_s']:.1f} s")


if __name__ == "__main__":
    main(sys.argv[1])
