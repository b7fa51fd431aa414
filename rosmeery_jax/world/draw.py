"""Top-down pictures of a world: walls, objects coloured by category and labelled, spawn."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.backend_bases import FigureCanvasBase  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
from matplotlib.patches import FancyArrow, Patch  # noqa: E402

from rosmeery_jax.core.errors import InputError  # noqa: E402
from rosmeery_jax.core.files import atomic_path  # noqa: E402
from rosmeery_jax.world.load import World  # noqa: E402
from rosmeery_jax.world.scene import WALL  # noqa: E402


def draw_world(world: World, ax=None, labels: bool = True, legend: bool = True):
    """Draw ``world`` on ``ax`` (a new figure if None); returns the axes."""
    if ax is None:
        _, ax = plt.subplots(figsize=(9, 9))
    fs, scene, truth = world.free_space, world.scene, world.truth
    ax.imshow(np.where(fs.reachable, 1.0, np.nan), extent=fs.extent, origin="lower",
              cmap="Greens", vmin=0, vmax=6, interpolation="nearest")
    corners = scene.footprint_corners()
    walls = scene.object_id == WALL
    ax.add_collection(PolyCollection(corners[walls], facecolors="0.25", edgecolors="0.25", linewidths=0.3))
    # Tall parts drawn last so table tops do not hide what stands on them.
    order = np.argsort(scene.center[:, 2] + scene.half[:, 2])
    objs = [g for g in order if scene.object_id[g] >= 0]
    colors = [world.taxonomy[truth.categories[scene.object_id[g]]].color for g in objs]
    ax.add_collection(PolyCollection(corners[objs], facecolors=colors, edgecolors="k",
                                     linewidths=0.3, alpha=0.85))
    if labels:
        for n, name in enumerate(truth.names):
            x, y = truth.bbox_center[n, :2]
            ax.annotate(name, (x, y), fontsize=5.5, ha="center", va="center",
                        bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.7))
    sx, sy, syaw = (float(v) for v in world.spawn)
    ax.add_patch(FancyArrow(sx, sy, 0.45 * np.cos(syaw), 0.45 * np.sin(syaw), width=0.08,
                            color="red", length_includes_head=True, zorder=5))
    ax.plot([sx], [sy], "o", color="red", ms=5, zorder=6)
    cats = sorted(set(truth.categories))
    handles = [Patch(color=world.taxonomy[c].color, label=f"{c} ({truth.categories.count(c)})") for c in cats]
    handles += [Patch(color="0.25", label="wall"), Patch(color=plt.get_cmap("Greens")(1 / 6), label="reachable"),
                Patch(color="red", label="robot spawn")]
    if legend:
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False)
    x0, x1, y0, y1 = fs.extent
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{world.title}: {truth.num_objects} objects, {int(truth.ps_G.sum())} surface samples, "
                 f"{fs.reachable_area_m2:.0f} m$^2$ reachable", fontsize=9)
    return ax


def picture_format(out: str | Path, flag: str = "--out") -> str:
    """The format ``out``'s suffix names (png without one), or one InputError if matplotlib
    writes no such format."""
    fmt = Path(out).suffix.lstrip(".").lower() or "png"
    formats = FigureCanvasBase.get_supported_filetypes()
    if fmt not in formats:
        raise InputError(str(out), flag, f"'.{fmt}' is not a picture format ({', '.join(sorted(formats))})")
    return fmt


def save_world_picture(world: World, out: str | Path, dpi: int = 130) -> Path:
    """Write the top-down picture of ``world`` to ``out`` (PNG without a suffix, atomically)."""
    out = Path(out)
    fmt = picture_format(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(9, 7.5))
    draw_world(world, ax)
    fig.tight_layout()
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=dpi, format=fmt)
    plt.close(fig)
    return out
