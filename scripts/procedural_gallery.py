"""The README's gallery of procedural worlds and their statistics beside the paper worlds.

    .venv/bin/python scripts/procedural_gallery.py [--per-kind 25] [--out docs/procedural]

Draws seeds 0 and 1 of every kind into ``OUT/gallery.png`` and prints a Markdown table: the
mean (and standard deviation) of each statistic over seeds 0..N-1 of every kind at its
default options, and the four paper worlds.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from rosmeery_jax.world import PAPER_WORLDS, load_world  # noqa: E402
from rosmeery_jax.world.census import stats_table  # noqa: E402
from rosmeery_jax.world.draw import draw_world  # noqa: E402
from rosmeery_jax.world.generate import KINDS  # noqa: E402

COLUMNS = ["objects", "categories", "floor_m2", "reachable_m2", "objects_per_10m2", "samples"]


def gallery(out: Path) -> Path:
    fig, axes = plt.subplots(2, 4, figsize=(20, 10))
    for col, kind in enumerate(KINDS):
        for row in range(2):
            world = load_world(f"procedural:{kind}:{row}")
            ax = draw_world(world, axes[row, col], labels=False, legend=False)
            ax.set_title(f"procedural:{kind}:{row} ({world.truth.num_objects} objects, "
                         f"{world.free_space.reachable_area_m2:.0f} m$^2$ reachable)", fontsize=10)
    fig.tight_layout()
    path = out / "gallery.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def table(per_kind: int) -> str:
    lines = ["| worlds | " + " | ".join(COLUMNS) + " |", "|---" * (len(COLUMNS) + 1) + "|"]
    for kind in KINDS:
        t, _ = stats_table([f"procedural:{kind}:{s}" for s in range(per_kind)])
        cells = [f"{t[c].mean():.1f} ± {t[c].std():.1f}" if c != "samples" else f"{t[c].mean():,.0f}" for c in COLUMNS]
        lines.append(f"| {kind} (seeds 0-{per_kind - 1}) | " + " | ".join(cells) + " |")
    t, _ = stats_table(list(PAPER_WORLDS))
    for _, r in t.iterrows():
        cells = [f"{r[c]:,.0f}" if c == "samples" else f"{r[c]:g}" for c in COLUMNS]
        lines.append(f"| paper: {r['world']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-kind", type=int, default=25)
    ap.add_argument("--out", type=Path, default=Path("docs/procedural"))
    args = ap.parse_args()
    print(f"wrote {gallery(args.out)}")
    print(table(args.per_kind))


if __name__ == "__main__":
    main()
