"""Write a world in the format of ``worlds/`` (docs in :mod:`.load`).

One writer serves the paper worlds (``scripts/author_paper_worlds.py``) and the procedural
generator (:mod:`.generate`), so every world file has the same header, materials, defaults
and number formatting (4 decimals, trailing zeros dropped: the text is the same on any
machine for the same numbers).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence
from xml.sax.saxutils import quoteattr

from rosmeery_jax.world.furniture import Part

WALL_RGBA = (0.88, 0.86, 0.80, 1.0)


@dataclass(frozen=True)
class Wall:
    """A wall box: centre (3,), full size (3,), yaw about z."""

    center: Sequence[float]
    size: Sequence[float]
    yaw: float = 0.0


@dataclass(frozen=True)
class Body:
    """One ground-truth object: its body pose (x, y, z, yaw) and parts in the body frame."""

    id: str
    category: str
    pose: Sequence[float]
    parts: Sequence[Part]


def fmt(values) -> str:
    """Numbers as MJCF text: 4 decimals, trailing zeros dropped, tiny values as 0."""
    return " ".join(f"{x:.4f}".rstrip("0").rstrip(".") if abs(x) > 1e-9 else "0" for x in values)


def world_xml(name: str, title: str, comment: Sequence[str], spawn: Sequence[float],
              walls: Sequence[Wall], bodies: Sequence[Body]) -> str:
    """The MJCF text of a world: ``comment`` lines go in the header comment."""
    note = [f"  <!-- {comment[0]}"] + [f"       {c}" for c in comment[1:]]
    note[-1] += " -->"
    lines = [
        f'<mujoco model="{name}">',
        *note,
        '  <compiler angle="radian"/>',
        '  <option timestep="0.02"/>',
        '  <visual><headlight ambient="0.45 0.45 0.45" diffuse="0.5 0.5 0.5"/></visual>',
        "  <asset>",
        '    <texture name="grid" type="2d" builtin="checker" rgb1="0.74 0.72 0.68" rgb2="0.68 0.66 0.62" width="256" height="256"/>',
        '    <material name="floor" texture="grid" texrepeat="10 10" texuniform="true"/>',
        f'    <material name="wall" rgba="{fmt(WALL_RGBA)}"/>',
        "  </asset>",
        "  <default>",
        '    <default class="static"><geom type="box" contype="0" conaffinity="1"/></default>',
        "  </default>",
        "  <custom>",
        f'    <text name="rosmeery:title" data={quoteattr(title)}/>',
        f'    <numeric name="rosmeery:spawn" data="{fmt(spawn)}"/>',
    ]
    lines += [f'    <text name="rosmeery:category:{b.id}" data={quoteattr(b.category)}/>' for b in bodies]
    lines += [
        "  </custom>",
        "  <worldbody>",
        '    <light name="sun" pos="0 0 8" dir="0 0 -1" directional="true" diffuse="0.5 0.5 0.5"/>',
        '    <geom name="floor" type="plane" size="0 0 0.05" material="floor" contype="0" conaffinity="1"/>',
    ]
    for i, w in enumerate(walls):
        half = [v / 2 for v in w.size]
        lines.append(f'    <geom name="wall_{i}" class="static" pos="{fmt(w.center)}" size="{fmt(half)}" '
                     f'euler="0 0 {w.yaw:.4f}" material="wall"/>')
    for b in bodies:
        lines.append(f'    <body name="{b.id}" pos="{fmt(b.pose[:3])}" euler="0 0 {b.pose[3]:.4f}">')
        for p in b.parts:
            euler = f' euler="0 0 {p.yaw:.4f}"' if abs(p.yaw) > 1e-9 else ""
            lines.append(f'      <geom name="{b.id}/{p.name}" class="static" pos="{fmt(p.pos)}" '
                         f'size="{fmt(p.half)}"{euler} rgba="{fmt(p.rgba)}"/>')
        lines.append("    </body>")
    lines += ["  </worldbody>", "</mujoco>", ""]
    return "\n".join(lines)
