"""Time `rosmeery evaluate` of a 1,000,000-point map of the Large Office, with the paper's
metrics and with every field map metric (docs/metrics.md), median of several whole
commands each.

    .venv/bin/python scripts/bench_field.py [--repeats 3] [--points 1000000]

The map: the world's surface samples repeated and jittered (2 cm), a tenth of the points
scattered off the objects, one instance per object with every fourth object split in two
and every fifth labelled with a wrong category.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rosmeery_jax.metrics.map_file import build_map, write_map
from rosmeery_jax.world import load_world


def make_map(folder: Path, points: int) -> Path:
    world = load_world("large_office")
    t = world.truth
    rng = np.random.default_rng(0)
    samples, obj = np.asarray(t.samples.points, np.float64), np.asarray(t.samples.object)
    on = int(points * 0.9)
    pick = rng.integers(0, len(samples), on)
    pts = samples[pick] + rng.normal(0, 0.02, (on, 3))
    inst = obj[pick] * 2 + ((obj[pick] % 4 == 0) & (pts[:, 2] > samples[pick][:, 2].mean()))
    lo, hi = samples.min(0), samples.max(0)
    off = rng.uniform(lo, hi, (points - on, 3))
    pts, inst = np.r_[pts, off], np.r_[inst, np.full(points - on, 2 * t.num_objects)]
    n = 2 * t.num_objects + 1
    cat = np.asarray(t.category_index)
    label = np.array([cat[i // 2] if i // 2 < t.num_objects else 0 for i in range(n)])
    label[::5] = (label[::5] + 1) % len(world.taxonomy.names)
    names = [f"instance_{i}" for i in range(n)]
    cloud, meta = build_map(world, pts, inst, names, label, np.full(n, 0.8, np.float32), 480.0)
    return write_map(folder, "large_office_1m", cloud, meta)[0]


def timed(ply: Path, out: Path, metrics: str) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "rosmeery_jax", "evaluate", "--world", "large_office", "--map", str(ply),
                    "--out", str(out), "--metrics", metrics], check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--points", type=int, default=1_000_000)
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as d:
        ply = make_map(Path(d), args.points)
        for metrics in ("ori,cori,cori_any,opi,opi_strict", "ori,cori,cori_any,opi,opi_strict,field"):
            times = [timed(ply, Path(d) / f"out{k}_{len(metrics)}", metrics) for k in range(args.repeats)]
            print(f"{args.points:,} points, --metrics {metrics}: median {statistics.median(times):.2f} s "
                  f"({', '.join(f'{t:.2f}' for t in times)})")


if __name__ == "__main__":
    main()
