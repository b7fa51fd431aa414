"""Furniture built from boxes: templates that fill a measured bounding box with parts.

Every part is a box that may only be rotated about z, so worlds built from these templates
stay on the fast raycast kernel (docs/performance.md). A template takes the object's measured
extent (``size``, full lengths in the object frame) and the offset of that box's centre from
the object origin (``center``), and returns the parts in the object frame. Parts never leave
the given box, so ground-truth bounding boxes equal the measured ones.

Used by ``scripts/author_paper_worlds.py`` (the four paper worlds) and available to anyone
authoring a world by script.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

RGBA = tuple[float, float, float, float]

WOOD = (0.62, 0.45, 0.28, 1.0)
DARK_WOOD = (0.40, 0.27, 0.17, 1.0)
LIGHT_WOOD = (0.80, 0.66, 0.46, 1.0)
METAL = (0.55, 0.57, 0.60, 1.0)
BLACK = (0.10, 0.10, 0.11, 1.0)
WHITE = (0.92, 0.92, 0.90, 1.0)
FABRIC_RED = (0.66, 0.16, 0.14, 1.0)
FABRIC_BLUE = (0.20, 0.30, 0.55, 1.0)
FABRIC_GREY = (0.45, 0.46, 0.50, 1.0)
CARDBOARD = (0.72, 0.56, 0.36, 1.0)
SCREEN = (0.05, 0.07, 0.12, 1.0)
GREEN = (0.20, 0.55, 0.22, 1.0)
TERRACOTTA = (0.70, 0.36, 0.22, 1.0)


@dataclass(frozen=True)
class Part:
    """One box of a piece of furniture, in the object frame.

    pos: centre (3,), half: half extents (3,), yaw: rotation about z (rad), rgba: colour.
    """

    name: str
    pos: tuple[float, float, float]
    half: tuple[float, float, float]
    rgba: RGBA
    yaw: float = 0.0


class _Frame:
    """The measured box: x0..x1, y0..y1, z0..z1 in the object frame."""

    def __init__(self, size: Sequence[float], center: Sequence[float]):
        sx, sy, sz = (float(v) for v in size)
        cx, cy, cz = (float(v) for v in center)
        self.sx, self.sy, self.sz = sx, sy, sz
        self.x0, self.x1 = cx - sx / 2, cx + sx / 2
        self.y0, self.y1 = cy - sy / 2, cy + sy / 2
        self.z0, self.z1 = cz - sz / 2, cz + sz / 2
        self.cx, self.cy = cx, cy

    def part(self, name, x0, x1, y0, y1, z0, z1, rgba, yaw=0.0) -> Part:
        """A part from its extents (clipped to the frame so nothing leaves the box)."""
        x0, x1 = max(x0, self.x0), min(x1, self.x1)
        y0, y1 = max(y0, self.y0), min(y1, self.y1)
        z0, z1 = max(z0, self.z0), min(z1, self.z1)
        return Part(
            name,
            ((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2),
            ((x1 - x0) / 2, (y1 - y0) / 2, (z1 - z0) / 2),
            rgba,
            yaw,
        )


def _legs(f: _Frame, top: float, t: float, rgba: RGBA, inset: float = 0.0) -> list[Part]:
    """Four square legs of side ``t`` from the floor of the frame up to ``top``."""
    out = []
    for i, (xa, ya) in enumerate(
        [(f.x0 + inset, f.y0 + inset), (f.x1 - inset - t, f.y0 + inset),
         (f.x0 + inset, f.y1 - inset - t), (f.x1 - inset - t, f.y1 - inset - t)]
    ):
        out.append(f.part(f"leg{i}", xa, xa + t, ya, ya + t, f.z0, top, rgba))
    return out


def chair(size, center, front: str = "-y", seat=WOOD, frame=DARK_WOOD) -> list[Part]:
    """Four legs, a seat at 46% of the height and a back on the side opposite ``front``."""
    f = _Frame(size, center)
    seat_z = f.z0 + 0.46 * f.sz
    t = 0.035
    parts = _legs(f, seat_z - 0.04, t, frame, inset=0.02)
    parts.append(f.part("seat", f.x0, f.x1, f.y0, f.y1, seat_z - 0.04, seat_z, seat))
    if front == "-y":
        parts.append(f.part("back", f.x0 + 0.02, f.x1 - 0.02, f.y1 - 0.05, f.y1, seat_z, f.z1, seat))
    else:
        parts.append(f.part("back", f.x0 + 0.02, f.x1 - 0.02, f.y0, f.y0 + 0.05, seat_z, f.z1, seat))
    return parts


def office_chair(size, center, front: str = "+y", fabric=FABRIC_BLUE) -> list[Part]:
    """A five-star base (two crossed feet), a gas column, seat, back and two armrests."""
    f = _Frame(size, center)
    seat_z = f.z0 + 0.49 * f.sz
    r = 0.5 * min(f.sx, f.sy) - 0.01
    parts = [
        f.part("foot_a", f.cx - r, f.cx + r, f.cy - 0.025, f.cy + 0.025, f.z0, f.z0 + 0.06, BLACK, ),
        Part("foot_b", (f.cx, f.cy, f.z0 + 0.03), (r, 0.025, 0.03), BLACK, math.pi / 2),
        f.part("column", f.cx - 0.03, f.cx + 0.03, f.cy - 0.03, f.cy + 0.03, f.z0 + 0.06, seat_z - 0.07, METAL),
        f.part("seat", f.x0 + 0.04, f.x1 - 0.04, f.y0 + 0.03, f.y1 - 0.03, seat_z - 0.07, seat_z, fabric),
    ]
    if front == "+y":
        parts.append(f.part("back", f.x0 + 0.06, f.x1 - 0.06, f.y0, f.y0 + 0.07, seat_z, f.z1, fabric))
    else:
        parts.append(f.part("back", f.x0 + 0.06, f.x1 - 0.06, f.y1 - 0.07, f.y1, seat_z, f.z1, fabric))
    arm_z = seat_z + 0.2
    parts += [
        f.part("arm_l", f.x0, f.x0 + 0.05, f.cy - 0.15, f.cy + 0.15, arm_z - 0.03, arm_z, BLACK),
        f.part("arm_r", f.x1 - 0.05, f.x1, f.cy - 0.15, f.cy + 0.15, arm_z - 0.03, arm_z, BLACK),
    ]
    return parts


def table(size, center, top=LIGHT_WOOD, legs=DARK_WOOD) -> list[Part]:
    """A top 4 cm thick on four legs."""
    f = _Frame(size, center)
    return _legs(f, f.z1 - 0.04, 0.05, legs, inset=0.03) + [
        f.part("top", f.x0, f.x1, f.y0, f.y1, f.z1 - 0.04, f.z1, top)
    ]


def round_table(size, center, top=LIGHT_WOOD, legs=DARK_WOOD) -> list[Part]:
    """An octagonal top (two squares 45 degrees apart) on a pedestal with a cross base."""
    f = _Frame(size, center)
    r = 0.5 * min(f.sx, f.sy)
    half_side = r / math.sqrt(2.0)  # each square's corners reach r, so the octagon fits the box
    zt = f.z1 - 0.02
    base_r = 0.35 * r
    return [
        Part("base_a", (f.cx, f.cy, f.z0 + 0.025), (base_r, 0.04, 0.025), legs, 0.0),
        Part("base_b", (f.cx, f.cy, f.z0 + 0.025), (base_r, 0.04, 0.025), legs, math.pi / 2),
        f.part("pedestal", f.cx - 0.06, f.cx + 0.06, f.cy - 0.06, f.cy + 0.06, f.z0 + 0.05, f.z1 - 0.04, legs),
        Part("top_a", (f.cx, f.cy, zt), (half_side, half_side, 0.02), top, 0.0),
        Part("top_b", (f.cx, f.cy, zt), (half_side, half_side, 0.02), top, math.pi / 4),
    ]


def desk(size, center, top=LIGHT_WOOD, sides=METAL) -> list[Part]:
    """A top on two side panels joined by a modesty panel (the laser sees the panels)."""
    f = _Frame(size, center)
    zt = f.z1 - 0.03
    long_x = f.sx >= f.sy
    parts = [f.part("top", f.x0, f.x1, f.y0, f.y1, zt, f.z1, top)]
    if long_x:
        parts += [
            f.part("side_l", f.x0 + 0.02, f.x0 + 0.05, f.y0 + 0.03, f.y1 - 0.03, f.z0, zt, sides),
            f.part("side_r", f.x1 - 0.05, f.x1 - 0.02, f.y0 + 0.03, f.y1 - 0.03, f.z0, zt, sides),
            f.part("modesty", f.x0 + 0.05, f.x1 - 0.05, f.y1 - 0.06, f.y1 - 0.04, zt - 0.35, zt, sides),
        ]
    else:
        parts += [
            f.part("side_l", f.x0 + 0.03, f.x1 - 0.03, f.y0 + 0.02, f.y0 + 0.05, f.z0, zt, sides),
            f.part("side_r", f.x0 + 0.03, f.x1 - 0.03, f.y1 - 0.05, f.y1 - 0.02, f.z0, zt, sides),
            f.part("modesty", f.x1 - 0.06, f.x1 - 0.04, f.y0 + 0.05, f.y1 - 0.05, zt - 0.35, zt, sides),
        ]
    return parts


def l_desk(size, center, arm: float = 0.8, top=LIGHT_WOOD, sides=METAL) -> list[Part]:
    """An L-shaped corner desk: one arm along the -x edge, one along the +y edge."""
    f = _Frame(size, center)
    zt = f.z1 - 0.03
    return [
        f.part("top_a", f.x0, f.x0 + arm, f.y0, f.y1, zt, f.z1, top),
        f.part("top_b", f.x0 + arm, f.x1, f.y1 - arm, f.y1, zt, f.z1, top),
        f.part("side_a", f.x0 + 0.03, f.x0 + arm - 0.03, f.y0 + 0.02, f.y0 + 0.05, f.z0, zt, sides),
        f.part("side_b", f.x1 - 0.05, f.x1 - 0.02, f.y1 - arm + 0.03, f.y1 - 0.03, f.z0, zt, sides),
        f.part("side_c", f.x0 + 0.03, f.x0 + 0.06, f.y1 - arm + 0.03, f.y1 - 0.03, f.z0, zt, sides),
    ]


def shelf(size, center, n_boards: int = 5, wood=WOOD, open_side: str = "-y") -> list[Part]:
    """An open bookcase: two sides, a back, a top and ``n_boards`` shelves."""
    f = _Frame(size, center)
    t = 0.025
    back = (f.y1 - t, f.y1) if open_side == "-y" else (f.y0, f.y0 + t)
    parts = [
        f.part("side_l", f.x0, f.x0 + t, f.y0, f.y1, f.z0, f.z1, wood),
        f.part("side_r", f.x1 - t, f.x1, f.y0, f.y1, f.z0, f.z1, wood),
        f.part("back", f.x0 + t, f.x1 - t, back[0], back[1], f.z0, f.z1, DARK_WOOD),
    ]
    for i in range(n_boards + 1):
        z = f.z0 + 0.05 + i * (f.sz - 0.05 - t) / n_boards
        parts.append(f.part(f"board{i}", f.x0 + t, f.x1 - t, f.y0, f.y1, z, z + t, wood))
    return parts


def cabinet(size, center, body=WOOD, front=LIGHT_WOOD, n_drawers: int = 3,
            front_side: str = "-y", top=None) -> list[Part]:
    """A carcass on a plinth with ``n_drawers`` fronts proud of the front face."""
    f = _Frame(size, center)
    d = 0.02
    if front_side == "-y":
        y_body, y_front = (f.y0 + d, f.y1), (f.y0, f.y0 + d)
    else:
        y_body, y_front = (f.y0, f.y1 - d), (f.y1 - d, f.y1)
    z_top = f.z1 - (0.03 if top else 0.0)
    parts = [
        f.part("plinth", f.x0 + 0.03, f.x1 - 0.03, y_body[0] + 0.03, y_body[1] - 0.03, f.z0, f.z0 + 0.08, BLACK),
        f.part("body", f.x0, f.x1, y_body[0], y_body[1], f.z0 + 0.08, z_top, body),
    ]
    if top:
        parts.append(f.part("countertop", f.x0, f.x1, f.y0, f.y1, z_top, f.z1, top))
    h = (z_top - f.z0 - 0.10) / n_drawers
    for i in range(n_drawers):
        z = f.z0 + 0.09 + i * h
        parts.append(f.part(f"drawer{i}", f.x0 + 0.02, f.x1 - 0.02, y_front[0], y_front[1], z + 0.01, z + h - 0.01, front))
    return parts


def refrigerator(size, center) -> list[Part]:
    """A white cabinet with a freezer door, a fridge door and a handle."""
    f = _Frame(size, center)
    split = f.z0 + 0.62 * f.sz
    return [
        f.part("body", f.x0, f.x1, f.y0 + 0.03, f.y1, f.z0, f.z1, WHITE),
        f.part("door_low", f.x0 + 0.01, f.x1 - 0.01, f.y0 + 0.01, f.y0 + 0.03, f.z0 + 0.02, split - 0.01, WHITE),
        f.part("door_high", f.x0 + 0.01, f.x1 - 0.01, f.y0 + 0.01, f.y0 + 0.03, split + 0.01, f.z1 - 0.02, WHITE),
        f.part("handle", f.x1 - 0.08, f.x1 - 0.05, f.y0, f.y0 + 0.01, split - 0.45, split + 0.3, METAL),
    ]


def stove(size, center) -> list[Part]:
    """A range: body, dark oven door on the front, four burners on top."""
    f = _Frame(size, center)
    parts = [
        f.part("body", f.x0, f.x1, f.y0 + 0.02, f.y1, f.z0, f.z1 - 0.02, WHITE),
        f.part("oven_door", f.x0 + 0.05, f.x1 - 0.05, f.y0, f.y0 + 0.02, f.z0 + 0.12, f.z1 - 0.22, BLACK),
    ]
    for i, (u, v) in enumerate([(0.25, 0.3), (0.75, 0.3), (0.25, 0.7), (0.75, 0.7)]):
        x = f.x0 + u * f.sx
        y = f.y0 + v * f.sy
        parts.append(f.part(f"burner{i}", x - 0.09, x + 0.09, y - 0.09, y + 0.09, f.z1 - 0.02, f.z1, BLACK))
    return parts


def microwave(size, center) -> list[Part]:
    """A box with a dark window and a control panel on its front."""
    f = _Frame(size, center)
    return [
        f.part("body", f.x0, f.x1, f.y0 + 0.01, f.y1, f.z0, f.z1, WHITE),
        f.part("window", f.x0 + 0.03, f.x0 + 0.68 * f.sx, f.y0, f.y0 + 0.01, f.z0 + 0.04, f.z1 - 0.04, SCREEN),
        f.part("panel", f.x0 + 0.72 * f.sx, f.x1 - 0.03, f.y0, f.y0 + 0.01, f.z0 + 0.04, f.z1 - 0.04, METAL),
    ]


def sink(size, center) -> list[Part]:
    """A vanity cabinet with a basin rim (four walls round a sunken bottom) and a tap."""
    f = _Frame(size, center)
    zc = f.z0 + 0.80 * f.sz
    rim = 0.05
    top_z = min(f.z1, zc + 0.08)
    parts = [
        f.part("cabinet", f.x0, f.x1, f.y0, f.y1, f.z0, zc - 0.15, WHITE),
        f.part("basin", f.x0 + rim, f.x1 - rim, f.y0 + rim, f.y1 - rim, zc - 0.15, zc - 0.13, METAL),
        f.part("rim_f", f.x0, f.x1, f.y0, f.y0 + rim, zc - 0.15, top_z, WHITE),
        f.part("rim_b", f.x0, f.x1, f.y1 - rim, f.y1, zc - 0.15, top_z, WHITE),
        f.part("rim_l", f.x0, f.x0 + rim, f.y0 + rim, f.y1 - rim, zc - 0.15, top_z, WHITE),
        f.part("rim_r", f.x1 - rim, f.x1, f.y0 + rim, f.y1 - rim, zc - 0.15, top_z, WHITE),
        f.part("tap", f.cx - 0.02, f.cx + 0.02, f.y1 - rim - 0.12, f.y1 - rim, top_z, f.z1, METAL),
    ]
    return parts


def toilet(size, center, front: str = "-y") -> list[Part]:
    """Pedestal, bowl, seat and cistern; the cistern sits on the side opposite ``front``."""
    f = _Frame(size, center)
    tank = (f.y1 - 0.2, f.y1) if front == "-y" else (f.y0, f.y0 + 0.2)
    bowl = (f.y0, f.y1 - 0.2) if front == "-y" else (f.y0 + 0.2, f.y1)
    seat_z = f.z0 + 0.45 * f.sz
    return [
        f.part("pedestal", f.cx - 0.1, f.cx + 0.1, bowl[0] + 0.1, bowl[1], f.z0, seat_z - 0.15, WHITE),
        f.part("bowl", f.x0 + 0.02, f.x1 - 0.02, bowl[0], bowl[1], seat_z - 0.15, seat_z - 0.02, WHITE),
        f.part("seat", f.x0, f.x1, bowl[0], bowl[1], seat_z - 0.02, seat_z, (0.85, 0.85, 0.82, 1.0)),
        f.part("tank", f.x0, f.x1, tank[0], tank[1], f.z0 + 0.1, f.z1, WHITE),
    ]


def bed(size, center, head: str = "+x", sheet=(0.85, 0.88, 0.95, 1.0), frame=WOOD) -> list[Part]:
    """Frame, mattress, pillow and a headboard at the ``head`` end."""
    f = _Frame(size, center)
    long_x = f.sx >= f.sy
    mat_z = f.z0 + 0.55 * f.sz
    parts = [
        f.part("frame", f.x0, f.x1, f.y0, f.y1, f.z0 + 0.1, f.z0 + 0.3, frame),
        f.part("mattress", f.x0 + 0.03, f.x1 - 0.03, f.y0 + 0.03, f.y1 - 0.03, f.z0 + 0.3, mat_z, sheet),
    ]
    parts += _legs(f, f.z0 + 0.1, 0.06, DARK_WOOD)
    if long_x:
        hx = (f.x1 - 0.06, f.x1) if head == "+x" else (f.x0, f.x0 + 0.06)
        px = (f.x1 - 0.45, f.x1 - 0.1) if head == "+x" else (f.x0 + 0.1, f.x0 + 0.45)
        parts.append(f.part("headboard", hx[0], hx[1], f.y0, f.y1, f.z0 + 0.1, f.z1, frame))
        parts.append(f.part("pillow", px[0], px[1], f.y0 + 0.15, f.y1 - 0.15, mat_z, mat_z + 0.1, WHITE))
    else:
        hy = (f.y1 - 0.06, f.y1) if head == "+x" else (f.y0, f.y0 + 0.06)
        py = (f.y1 - 0.45, f.y1 - 0.1) if head == "+x" else (f.y0 + 0.1, f.y0 + 0.45)
        parts.append(f.part("headboard", f.x0, f.x1, hy[0], hy[1], f.z0 + 0.1, f.z1, frame))
        parts.append(f.part("pillow", f.x0 + 0.15, f.x1 - 0.15, py[0], py[1], mat_z, mat_z + 0.1, WHITE))
    return parts


def sofa(size, center, back: str = "+y", fabric=(0.42, 0.30, 0.52, 1.0)) -> list[Part]:
    """Base, seat cushion, back rest and two arms; the back is on the ``back`` side."""
    f = _Frame(size, center)
    seat_z = f.z0 + 0.48 * f.sz
    by = (f.y1 - 0.22, f.y1) if back == "+y" else (f.y0, f.y0 + 0.22)
    sy = (f.y0, f.y1 - 0.22) if back == "+y" else (f.y0 + 0.22, f.y1)
    return [
        f.part("base", f.x0, f.x1, f.y0, f.y1, f.z0 + 0.05, seat_z - 0.12, DARK_WOOD),
        f.part("cushion", f.x0 + 0.2, f.x1 - 0.2, sy[0], sy[1], seat_z - 0.12, seat_z, fabric),
        f.part("back", f.x0, f.x1, by[0], by[1], seat_z - 0.12, f.z1, fabric),
        f.part("arm_l", f.x0, f.x0 + 0.2, f.y0, f.y1, seat_z - 0.12, seat_z + 0.18, fabric),
        f.part("arm_r", f.x1 - 0.2, f.x1, f.y0, f.y1, seat_z - 0.12, seat_z + 0.18, fabric),
        f.part("foot_l", f.x0 + 0.05, f.x0 + 0.12, f.cy - 0.1, f.cy + 0.1, f.z0, f.z0 + 0.05, BLACK),
        f.part("foot_r", f.x1 - 0.12, f.x1 - 0.05, f.cy - 0.1, f.cy + 0.1, f.z0, f.z0 + 0.05, BLACK),
    ]


def tv_stand(size, center) -> list[Part]:
    """A low cabinet: top, bottom, two sides and a middle shelf, open at the front."""
    f = _Frame(size, center)
    t = 0.03
    return [
        f.part("top", f.x0, f.x1, f.y0, f.y1, f.z1 - t, f.z1, DARK_WOOD),
        f.part("bottom", f.x0, f.x1, f.y0, f.y1, f.z0 + 0.04, f.z0 + 0.04 + t, DARK_WOOD),
        f.part("side_l", f.x0, f.x0 + t, f.y0, f.y1, f.z0, f.z1 - t, DARK_WOOD),
        f.part("side_r", f.x1 - t, f.x1, f.y0, f.y1, f.z0, f.z1 - t, DARK_WOOD),
        f.part("back", f.x0 + t, f.x1 - t, f.y1 - 0.02, f.y1, f.z0 + 0.04, f.z1 - t, WOOD),
        f.part("shelf", f.x0 + t, f.x1 - t, f.y0, f.y1, f.z0 + 0.5 * f.sz, f.z0 + 0.5 * f.sz + 0.02, DARK_WOOD),
    ]


def screen(size, center, wide_axis: str = "x", frame=BLACK) -> list[Part]:
    """A display: foot, neck and a thin bezel-and-panel screen (TV or monitor)."""
    f = _Frame(size, center)
    screen_z0 = f.z0 + 0.22 * f.sz
    if wide_axis == "x":
        return [
            f.part("foot", f.cx - 0.25 * f.sx, f.cx + 0.25 * f.sx, f.y0, f.y1, f.z0, f.z0 + 0.02, frame),
            f.part("neck", f.cx - 0.03, f.cx + 0.03, f.cy - 0.02, f.cy + 0.02, f.z0 + 0.02, screen_z0, frame),
            f.part("panel", f.x0, f.x1, f.cy - 0.03, f.cy + 0.03, screen_z0, f.z1, frame),
            f.part("glass", f.x0 + 0.02, f.x1 - 0.02, f.cy - 0.035, f.cy - 0.03, screen_z0 + 0.02, f.z1 - 0.02, SCREEN),
        ]
    return [
        f.part("foot", f.x0, f.x1, f.cy - 0.25 * f.sy, f.cy + 0.25 * f.sy, f.z0, f.z0 + 0.02, frame),
        f.part("neck", f.cx - 0.02, f.cx + 0.02, f.cy - 0.03, f.cy + 0.03, f.z0 + 0.02, screen_z0, frame),
        f.part("panel", f.cx - 0.025, f.cx + 0.025, f.y0, f.y1, screen_z0, f.z1, frame),
        f.part("glass", f.cx + 0.025, f.cx + 0.03, f.y0 + 0.02, f.y1 - 0.02, screen_z0 + 0.02, f.z1 - 0.02, SCREEN),
    ]


def books(size, center) -> list[Part]:
    """A row of upright books of different heights and colours."""
    f = _Frame(size, center)
    colours = [(0.70, 0.15, 0.12, 1.0), (0.15, 0.35, 0.60, 1.0), (0.85, 0.70, 0.20, 1.0),
               (0.20, 0.50, 0.25, 1.0), (0.45, 0.20, 0.45, 1.0)]
    n = len(colours)
    w = f.sx / n
    heights = [1.0, 0.85, 0.95, 0.75, 0.9]
    return [
        f.part(f"book{i}", f.x0 + i * w + 0.002, f.x0 + (i + 1) * w - 0.002, f.y0, f.y1,
               f.z0, f.z0 + heights[i] * f.sz, colours[i])
        for i in range(n)
    ]


def boxes(size, center) -> list[Part]:
    """Two cardboard boxes side by side and a smaller one on top."""
    f = _Frame(size, center)
    mid = f.x0 + 0.52 * f.sx
    low = f.z0 + 0.6 * f.sz
    return [
        f.part("box_a", f.x0, mid - 0.01, f.y0, f.y1, f.z0, low, CARDBOARD),
        f.part("box_b", mid + 0.01, f.x1, f.y0 + 0.05, f.y1, f.z0, low, (0.66, 0.50, 0.32, 1.0)),
        f.part("box_c", f.x0 + 0.1, mid + 0.1, f.y0 + 0.1, f.y1 - 0.1, low, f.z1, (0.78, 0.62, 0.42, 1.0)),
    ]


def trash_can(size, center) -> list[Part]:
    f = _Frame(size, center)
    return [
        f.part("bin", f.x0 + 0.01, f.x1 - 0.01, f.y0 + 0.01, f.y1 - 0.01, f.z0, f.z1 - 0.03, (0.35, 0.38, 0.40, 1.0)),
        f.part("lid", f.x0, f.x1, f.y0, f.y1, f.z1 - 0.03, f.z1, METAL),
    ]


def coat_rack(size, center) -> list[Part]:
    """A pole on a cross foot with two crossed hook bars at the top."""
    f = _Frame(size, center)
    r = 0.5 * min(f.sx, f.sy)
    return [
        Part("foot_a", (f.cx, f.cy, f.z0 + 0.02), (r, 0.025, 0.02), DARK_WOOD, 0.0),
        Part("foot_b", (f.cx, f.cy, f.z0 + 0.02), (r, 0.025, 0.02), DARK_WOOD, math.pi / 2),
        f.part("pole", f.cx - 0.02, f.cx + 0.02, f.cy - 0.02, f.cy + 0.02, f.z0 + 0.04, f.z1, DARK_WOOD),
        Part("hooks_a", (f.cx, f.cy, f.z1 - 0.12), (r * 0.8, 0.015, 0.015), DARK_WOOD, math.pi / 4),
        Part("hooks_b", (f.cx, f.cy, f.z1 - 0.12), (r * 0.8, 0.015, 0.015), DARK_WOOD, -math.pi / 4),
    ]


def pc_tower(size, center) -> list[Part]:
    f = _Frame(size, center)
    return [
        f.part("case", f.x0, f.x1, f.y0 + 0.01, f.y1, f.z0, f.z1, (0.18, 0.18, 0.20, 1.0)),
        f.part("front", f.x0 + 0.02, f.x1 - 0.02, f.y0, f.y0 + 0.01, f.z0 + 0.02, f.z1 - 0.02, METAL),
    ]


def potted_plant(size, center) -> list[Part]:
    """A terracotta pot with a leafy crown (two boxes 45 degrees apart) and a stem."""
    f = _Frame(size, center)
    pot_top = f.z0 + 0.3 * f.sz
    r = 0.5 * min(f.sx, f.sy)
    crown_z = f.z0 + 0.7 * f.sz
    h = 0.3 * f.sz / 2
    return [
        f.part("pot", f.cx - 0.6 * r, f.cx + 0.6 * r, f.cy - 0.6 * r, f.cy + 0.6 * r, f.z0, pot_top, TERRACOTTA),
        f.part("stem", f.cx - 0.02, f.cx + 0.02, f.cy - 0.02, f.cy + 0.02, pot_top, crown_z - h, (0.35, 0.25, 0.12, 1.0)),
        Part("leaves_a", (f.cx, f.cy, crown_z), (r / math.sqrt(2), r / math.sqrt(2), h), GREEN, 0.0),
        Part("leaves_b", (f.cx, f.cy, crown_z), (r / math.sqrt(2), r / math.sqrt(2), h), (0.25, 0.62, 0.25, 1.0), math.pi / 4),
    ]


def shower(size, center) -> list[Part]:
    """A tray with glass panels on three sides (open at -y) and a shower riser."""
    f = _Frame(size, center)
    glass = (0.70, 0.85, 0.92, 1.0)
    t = 0.02
    return [
        f.part("tray", f.x0, f.x1, f.y0, f.y1, f.z0, f.z0 + 0.08, WHITE),
        f.part("panel_back", f.x0, f.x1, f.y1 - t, f.y1, f.z0 + 0.08, f.z1, glass),
        f.part("panel_l", f.x0, f.x0 + t, f.y0, f.y1 - t, f.z0 + 0.08, f.z1, glass),
        f.part("panel_r", f.x1 - t, f.x1, f.y0, f.y1 - t, f.z0 + 0.08, f.z1, glass),
        f.part("riser", f.cx - 0.02, f.cx + 0.02, f.y1 - t - 0.04, f.y1 - t, f.z0 + 0.9, f.z1 - 0.1, METAL),
    ]


TEMPLATES: dict[str, Callable[..., list[Part]]] = {
    "chair": chair,
    "office_chair": office_chair,
    "table": table,
    "round_table": round_table,
    "desk": desk,
    "l_desk": l_desk,
    "shelf": shelf,
    "cabinet": cabinet,
    "refrigerator": refrigerator,
    "stove": stove,
    "microwave": microwave,
    "sink": sink,
    "toilet": toilet,
    "bed": bed,
    "sofa": sofa,
    "tv_stand": tv_stand,
    "screen": screen,
    "books": books,
    "boxes": boxes,
    "trash_can": trash_can,
    "coat_rack": coat_rack,
    "pc_tower": pc_tower,
    "potted_plant": potted_plant,
    "shower": shower,
}


def build(template: str, size, center, **kwargs) -> list[Part]:
    """Parts of ``template`` filling the box ``size`` centred at ``center`` (object frame)."""
    parts = TEMPLATES[template](size, center, **kwargs)
    for p in parts:
        if min(p.half) <= 0:
            raise ValueError(f"template {template!r}: part {p.name!r} is empty for size {size}")
    return parts


def footprint_corners(center_xy, half_xy, yaw) -> np.ndarray:
    """The four plan corners (4, 2) of a box of half extents ``half_xy`` rotated by ``yaw``."""
    c, s = math.cos(yaw), math.sin(yaw)
    hx, hy = half_xy
    local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
    rot = np.array([[c, -s], [s, c]])
    return local @ rot.T + np.asarray(center_xy)
