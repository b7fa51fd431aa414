"""The building of a procedural world (:mod:`rosmeery_jax.world.generate`): its rooms cut
from one rectangle, walls with a doorway per cut, and the checks on a 5 cm grid that every
room is reachable and every object viewable. All lengths in whole centimetres."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy import ndimage

from rosmeery_jax.world.recipes import ROOMS, Piece, room_types

WALL_T, WALL_H = 10, 250  # cm
MIN_SIDE = 220  # cm: the shortest room side
DOOR = (90, 110)  # cm: doorway width range
DOOR_CLEAR = 100  # cm kept free on each side of a doorway
JUNCTION = 40  # cm between a doorway and a wall meeting its wall
CELL = 5  # cm: the check grid
CLEAR = 25  # cm: clearance a reachable cell needs (robot radius 20 cm + margin)
VIEW = 100  # cm: reachable floor must come this close to every object
ROBOT_TOP = 50  # cm: pieces starting below this block the robot
MIN_ROOM_REACH = 0.25  # m^2 of reachable floor every room needs


class Rect(NamedTuple):
    """An axis-aligned plan rectangle in cm."""

    x0: int
    y0: int
    x1: int
    y1: int

    @property
    def w(self) -> int:
        return self.x1 - self.x0

    @property
    def h(self) -> int:
        return self.y1 - self.y0

    def overlaps(self, o: "Rect") -> bool:
        return self.x0 < o.x1 and o.x0 < self.x1 and self.y0 < o.y1 and o.y0 < self.y1

    def within(self, o: "Rect") -> bool:
        return o.x0 <= self.x0 and self.x1 <= o.x1 and o.y0 <= self.y0 and self.y1 <= o.y1

    def grow(self, d: int) -> "Rect":
        return Rect(self.x0 - d, self.y0 - d, self.x1 + d, self.y1 + d)


@dataclass
class Item:
    """A placed object: its piece, canonical size (cm), plan footprint, quarter turns ``k``
    (its back faces +y, -x, -y, +x for k = 0..3), bottom height ``z`` and colours."""

    piece: Piece
    size: tuple[int, int, int]
    rect: Rect
    k: int
    z: int = 0
    room: int = 0
    colors: dict = field(default_factory=dict)
    turn: float = 0.0  # degrees turned from the quarter turn (chairs left askew)

    @property
    def top(self) -> int:
        return self.z + self.size[2]


class Cut(NamedTuple):
    """An interior wall on x = c (axis 0) or y = c (axis 1) from lo to hi, with a doorway."""

    axis: int
    c: int
    lo: int
    hi: int


class FloorPlan(NamedTuple):
    """A building: its size (W, H), rooms (type, interior), cuts and their doorways (start,
    end along the cut)."""

    size: tuple[int, int]
    rooms: list[tuple[str, Rect]]
    cuts: list[Cut]
    doors: list[tuple[int, int]]


def even(rng, lo: int, hi: int) -> int:
    """An even number of cm in [lo, hi]."""
    return 2 * int(rng.integers(-(-lo // 2), hi // 2 + 1))


def floor_plan(kind: str, rooms: int, rng) -> FloorPlan | None:
    """The building of a ``kind`` with ``rooms`` rooms, or None if the cut failed."""
    types = room_types(kind, rooms)
    areas = [float(rng.uniform(*ROOMS[t].area)) * 1e4 for t in types]
    aspect = float(rng.uniform(1.0, 1.6))
    W = max(MIN_SIDE, int(round(math.sqrt(sum(areas) * aspect) / 10)) * 10)
    H = max(MIN_SIDE, int(round(sum(areas) / W / 10)) * 10)
    leaves: dict[int, Rect] = {}
    cuts: list[Cut] = []
    if not _partition(Rect(0, 0, W, H), list(range(len(types))), areas, rng, leaves, cuts):
        return None
    doors = []
    for cut in cuts:
        d = _doorway(cut, cuts, rng)
        if d is None:
            return None
        doors.append(d)
    h = WALL_T // 2
    rooms = [(types[i], Rect(r.x0 + h, r.y0 + h, r.x1 - h, r.y1 - h)) for i, r in sorted(leaves.items())]
    return FloorPlan((W, H), rooms, cuts, doors)


def _partition(rect: Rect, ids: list[int], areas: list[float], rng, leaves: dict, cuts: list) -> bool:
    """Cut ``rect`` among rooms ``ids`` (recursive); False when a room would be too narrow."""
    if len(ids) == 1:
        leaves[ids[0]] = rect
        return min(rect.w, rect.h) >= MIN_SIDE + WALL_T
    order = [ids[i] for i in rng.permutation(len(ids))]
    a, b, sa, sb = [], [], 0.0, 0.0
    for i in sorted(order, key=lambda i: -areas[i]):  # stable: ties keep the random order
        if sa <= sb:
            a.append(i)
            sa += areas[i]
        else:
            b.append(i)
            sb += areas[i]
    frac = sa / (sa + sb)
    axis = 0 if rect.w > rect.h or (rect.w == rect.h and rng.random() < 0.5) else 1
    lo, hi = (rect.x0, rect.x1) if axis == 0 else (rect.y0, rect.y1)
    need = MIN_SIDE + WALL_T  # a narrow side takes floor from the wide one
    c = min(max(lo + int(round(frac * (hi - lo) / 10)) * 10, lo + need), hi - need)
    if axis == 0:
        ra, rb = Rect(rect.x0, rect.y0, c, rect.y1), Rect(c, rect.y0, rect.x1, rect.y1)
        cuts.append(Cut(0, c, rect.y0, rect.y1))
    else:
        ra, rb = Rect(rect.x0, rect.y0, rect.x1, c), Rect(rect.x0, c, rect.x1, rect.y1)
        cuts.append(Cut(1, c, rect.x0, rect.x1))
    return _partition(ra, a, areas, rng, leaves, cuts) and _partition(rb, b, areas, rng, leaves, cuts)


def _doorway(cut: Cut, cuts: list[Cut], rng) -> tuple[int, int] | None:
    """A doorway (start, end along the cut) clear of the walls that meet it, or None."""
    width = even(rng, *DOOR)
    keep = [cut.lo, cut.hi] + [o.c for o in cuts if o.axis != cut.axis and cut.lo < o.c < cut.hi
                               and cut.c in (o.lo, o.hi)]
    free = [s for s in range(cut.lo, cut.hi - width + 1, 2)
            if all(s >= j + JUNCTION or s + width <= j - JUNCTION for j in keep)]
    if not free:
        return None
    s = free[int(rng.integers(len(free)))]
    return s, s + width


def door_zones(cuts, doors) -> list[Rect]:
    out = []
    for cut, (d0, d1) in zip(cuts, doors):
        if cut.axis == 0:
            out.append(Rect(cut.c - DOOR_CLEAR, d0 - 10, cut.c + DOOR_CLEAR, d1 + 10))
        else:
            out.append(Rect(d0 - 10, cut.c - DOOR_CLEAR, d1 + 10, cut.c + DOOR_CLEAR))
    return out


def wall_rects(size, cuts, doors) -> list[Rect]:
    """Plan rects (cm) of the four outer walls and of each cut's wall on both sides of its doorway."""
    W, H = size
    h = WALL_T // 2
    out = [Rect(-h, -h, W + h, h), Rect(-h, H - h, W + h, H + h), Rect(-h, -h, h, H + h), Rect(W - h, -h, W + h, H + h)]
    for cut, (d0, d1) in zip(cuts, doors):
        for a, b in ((cut.lo, d0), (d1, cut.hi)):
            if b > a:
                out.append(Rect(cut.c - h, a, cut.c + h, b) if cut.axis == 0 else Rect(a, cut.c - h, b, cut.c + h))
    return out


def occupancy(size, cuts, doors, items) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) bool grid of cells (``CELL`` cm, origin at (-WALL_T, -WALL_T)) blocked for the
    robot by walls or low pieces, and the cell centres' plan coordinates (2, H, W) in cm.

    Whole footprints block, not the parts the loader rasterises (a table's legs): this check
    is conservative, so the loader's free space (``freespace.py``) reaches at least as far,
    and it needs no boxes built, which keeps generation at milliseconds per world."""
    W, H = size
    o = -WALL_T
    shape = ((H + 2 * WALL_T) // CELL + 1, (W + 2 * WALL_T) // CELL + 1)
    occ = np.zeros(shape, bool)

    def mark(r: Rect):
        i0, i1 = (r.y0 - o) // CELL, -(-(r.y1 - o) // CELL)
        j0, j1 = (r.x0 - o) // CELL, -(-(r.x1 - o) // CELL)
        occ[max(i0, 0):i1, max(j0, 0):j1] = True

    for r in wall_rects(size, cuts, doors):
        mark(r)
    for it in items:
        if it.z < ROBOT_TOP:
            mark(it.rect)
    ys = o + (np.arange(shape[0]) + 0.5) * CELL
    xs = o + (np.arange(shape[1]) + 0.5) * CELL
    return occ, np.stack(np.meshgrid(xs, ys))


def _cells(r: Rect, xy: np.ndarray) -> np.ndarray:
    x, y = xy
    return (x > r.x0) & (x < r.x1) & (y > r.y0) & (y < r.y1)


def check(plan: FloorPlan, items: list[Item]) -> tuple[int, int, float] | None:
    """The spawn if every room is reachable and every object is viewable, else None."""
    occ, xy = occupancy(plan.size, plan.cuts, plan.doors, items)
    rooms = plan.rooms
    clear = ndimage.distance_transform_edt(~occ) * CELL
    free = clear > CLEAR
    first = _cells(rooms[0][1], xy) & free
    if not first.any():
        return None
    i, j = np.unravel_index(np.argmax(np.where(first, clear, -1.0)), clear.shape)
    labels, _ = ndimage.label(free)
    reach = labels == labels[i, j]
    for _, r in rooms:
        if (reach & _cells(r, xy)).sum() * CELL ** 2 < MIN_ROOM_REACH * 1e4:
            return None
    near = ndimage.distance_transform_edt(~reach) * CELL
    for it in items:
        cells = _cells(it.rect.grow(CELL), xy)
        if not cells.any() or near[cells].min() > VIEW:
            return None
    return int(round(xy[0, i, j])), int(round(xy[1, i, j])), 0.0
