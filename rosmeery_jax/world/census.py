"""World statistics as a table: objects, floor and reachable area, categories, samples."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.specs import expand_ranges
from rosmeery_jax.world.load import World, load_world

COLUMNS = ["world", "objects", "categories", "boxes", "floor_m2", "reachable_m2", "objects_per_10m2", "samples"]


def world_names_in(args: list[str]) -> list[str]:
    """World names from folders (every ``*.xml`` in them, sorted), names, paths and
    comma-separated lists; ``procedural:KIND:A-B`` ranges expanded."""
    out: list[str] = []
    for arg in args:
        if Path(arg).is_dir():
            files = sorted(Path(arg).glob("*.xml"))
            if not files:
                raise InputError(arg, "", "folder holds no world files (*.xml)")
            out += [str(f) for f in files]
        else:
            out += expand_ranges([a.strip() for a in arg.split(",") if a.strip()])
    return out


def row(world: World) -> dict:
    """One world's statistics. floor_m2: the walled interior (cells inside the walls)."""
    fs, t = world.free_space, world.truth
    floor = float(fs.interior.sum()) * fs.resolution ** 2
    return {
        "world": world.name, "objects": t.num_objects, "categories": len(set(t.categories)),
        "boxes": world.scene.num_boxes, "floor_m2": round(floor, 1),
        "reachable_m2": round(fs.reachable_area_m2, 1),
        "objects_per_10m2": round(10 * t.num_objects / max(floor, 1e-9), 2),
        "samples": int(t.ps_G.sum()),
    }


def stats_table(names: list[str]) -> tuple[pd.DataFrame, pd.Series]:
    """Per-world rows and the category counts summed over all worlds."""
    worlds = [load_world(n) for n in names]
    table = pd.DataFrame([row(w) for w in worlds], columns=COLUMNS)
    cats = pd.Series(np.concatenate([w.truth.categories for w in worlds])).value_counts()
    return table, cats


def summary(table: pd.DataFrame) -> pd.DataFrame:
    """Mean, standard deviation, min and max of every numeric column."""
    return table.drop(columns="world").agg(["mean", "std", "min", "max"]).round(1)
