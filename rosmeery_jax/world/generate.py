"""Procedural indoor worlds: a seeded generator of apartments, offices, kitchens and labs.

``generate(GenOptions(kind, seed, ...))`` returns a :class:`Layout`; ``layout.xml()`` is a
world file in the format of ``worlds/`` (it loads with ``load_world``). The
names ``procedural:KIND:SEED[:option=value]...`` and their cached files:
:mod:`rosmeery_jax.world.procedural`.

How a world is made (all lengths whole centimetres, so the text is exact):

1. **Rooms.** The kind fixes the room types (:mod:`.recipes`); each draws a target area.
   A rectangle of the summed area is cut recursively (a binary space partition): each cut
   splits the rooms into two groups of near-equal area and the rectangle in proportion,
   across its longer side; rooms are at least 2.2 m on a side.
2. **Walls and doors.** 10 cm walls, 2.5 m high: four outer walls and one wall per cut,
   with one doorway (90-110 cm) per cut, kept 40 cm clear of every wall meeting it. Each
   side of a cut is connected, so one door per cut connects every room.
3. **Furniture by rules.** Groups from the templates: desks with a chair and a monitor,
   benches, tables with chairs around, a kitchen counter (cabinets, stove, sink, fridge,
   microwave), sofa and TV, beds and wardrobes, toilet, sink and shower, shelves. Pieces
   that belong against a wall turn their back to it and keep 60 cm free in front; tables
   keep 50 cm free around their chairs; 1 m on each side of a door stays free. Groups go
   first where a room must have them, then wherever the room is emptiest, until the
   object budget minus the clutter share is spent; clutter (plants, bins, boxes, books on
   desks and tables) fills the rest. No two objects overlap (their boxes may touch), except
   that with ``tuck`` > 0 that share of the chairs at desks and tables is pushed in under
   them, by up to half the chair's depth, as people leave chairs; ``turn`` > 0 turns each
   of those chairs by up to that many degrees either way; with ``islands`` > 0 that share
   of the desk groups are free-standing rows of 2-4 desks, one or two rows back to back,
   a chair and a monitor at each (all three 0 by default).
4. **Checks.** On a 5 cm grid: the spawn is the free cell of the first room farthest from
   any obstacle; every room has reachable floor (clearance above 25 cm, connected to the
   spawn) and every object has reachable floor within 1 m of its footprint.

A layout that fails a check is drawn again from the next sub-seed (deterministic); a world
that cannot hold what was asked raises :class:`GenerationError` naming what was not placed.
Steps 1, 2 and 4 are :mod:`rosmeery_jax.world.floor_plan`; this module holds the options,
the furniture rules and the layout they make.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.world import furniture as F
from rosmeery_jax.world.floor_plan import WALL_H, Cut, Item, Rect, check, door_zones, even, floor_plan, wall_rects
from rosmeery_jax.world.mjcf import Body, Wall, world_xml
from rosmeery_jax.world.recipes import (
    KIND_DEFAULTS,
    KIND_ROOMS,
    PIECES,
    REPEAT,
    ROOMS,
    SMALL,
    SUPPORTS,
    Piece,
    room_types,
)

KINDS = tuple(KIND_ROOMS)
VERSION = 1  # bump when the same options would give a different file

ACCESS = 60  # cm kept free in front of a piece against a wall
AROUND = 50  # cm kept free around a table group
GAP = 2  # cm between a piece and the wall behind it
PER_OBJECT_M2 = 1.5  # capacity: floor area per object at most
ATTEMPTS = 32  # whole layouts tried per world before giving up (a 6-room lab fails a third of its draws)


class GenerationError(InputError):
    """The options ask for more than a world of this kind and size can hold."""


@dataclass(frozen=True)
class GenOptions:
    """What to generate. rooms / objects: None = the kind's default; clutter: the share of
    objects that are small clutter (plants, bins, boxes, books), in [0, 1]; tuck: the share
    of chairs at desks and tables pushed in under them, in [0, 1]; turn: the most those
    chairs are turned from facing their desk or table, in degrees [0, 180]; islands: the
    share of desk groups set as free-standing rows of desks, in [0, 1]; spare: the share of
    clutter objects that are a spare chair standing alone with its back to a wall, in [0, 1]."""

    kind: str
    seed: int
    rooms: int | None = None
    objects: int | None = None
    clutter: float = 0.2
    tuck: float = 0.0
    turn: float = 0.0
    islands: float = 0.0
    spare: float = 0.0

    def resolved(self) -> "GenOptions":
        rooms, objects = KIND_DEFAULTS[self.kind]
        return GenOptions(self.kind, self.seed, rooms if self.rooms is None else self.rooms,
                          objects if self.objects is None else self.objects, self.clutter, self.tuck, self.turn,
                          self.islands, self.spare)

    @property
    def name(self) -> str:
        """The world's name: ``procedural_KIND_SEED`` plus any option not at its default."""
        o, d = self.resolved(), KIND_DEFAULTS[self.kind]
        extra = "".join(s for s, on in [(f"_r{o.rooms}", o.rooms != d[0]), (f"_k{o.objects}", o.objects != d[1]),
                                        (f"_c{o.clutter:g}", o.clutter != 0.2), (f"_t{o.tuck:g}", o.tuck != 0),
                                        (f"_y{o.turn:g}", o.turn != 0), (f"_i{o.islands:g}", o.islands != 0),
                                        (f"_s{o.spare:g}", o.spare != 0)]
                        if on)
        return f"procedural_{self.kind}_{self.seed}{extra}"


@dataclass
class Layout:
    """A generated world: options, building size, rooms (type, interior), cuts with their
    doorways, placed items and the spawn (x, y in cm; yaw)."""

    options: GenOptions
    size: tuple[int, int]
    rooms: list[tuple[str, Rect]]
    cuts: list[Cut]
    doors: list[tuple[int, int]]
    items: list[Item]
    spawn: tuple[int, int, float]
    attempt: int

    def walls(self) -> list[Wall]:
        return [Wall(((r.x0 + r.x1) / 200, (r.y0 + r.y1) / 200, WALL_H / 200), (r.w / 100, r.h / 100, WALL_H / 100))
                for r in wall_rects(self.size, self.cuts, self.doors)]

    def bodies(self) -> list[Body]:
        counts: dict[str, int] = {}
        out = []
        for it in self.items:
            slug = it.piece.category.replace(" ", "_")
            n = counts[slug] = counts.get(slug, -1) + 1
            sx, sy, sz = (v / 100 for v in it.size)
            parts = F.build(it.piece.template, (sx, sy, sz), (0.0, 0.0, sz / 2), **it.piece.kwargs, **it.colors)
            cx, cy = (it.rect.x0 + it.rect.x1) / 200, (it.rect.y0 + it.rect.y1) / 200
            yaw = it.k * math.pi / 2 + math.radians(it.turn)
            out.append(Body(f"{slug}_{n}", it.piece.category, (cx, cy, it.z / 100, yaw), parts))
        return out

    def xml(self) -> str:
        o = self.options.resolved()
        title = f"Procedural {o.kind.title()} {o.seed}"
        comment = [f"{title}: generated by rosmeery-jax's procedural world generator (version {VERSION}):",
                   f"rosmeery worlds generate --kind {o.kind} --seed {o.seed} --rooms {o.rooms} "
                   f"--objects {o.objects} --clutter {o.clutter:g}"
                   + "".join(f" --{k} {getattr(o, k):g}" for k in ("tuck", "turn", "islands", "spare") if getattr(o, k)),
                   "rooms: " + ", ".join(t for t, _ in self.rooms) + "."]
        sx, sy, syaw = self.spawn
        return world_xml(self.options.name, title, comment, (sx / 100, sy / 100, syaw), self.walls(), self.bodies())


# ----------------------------------------------------------------------------- options


def check_options(o: GenOptions, source: str = "options") -> GenOptions:
    """``o`` with defaults filled in; a bad option raises one InputError naming it."""
    if o.kind not in KINDS:
        raise InputError(source, "kind", f"unknown kind {o.kind!r} (one of {', '.join(KINDS)})")
    if isinstance(o.seed, bool) or not isinstance(o.seed, (int, np.integer)) or o.seed < 0:
        raise InputError(source, "seed", f"{o.seed!r} is not a non-negative integer")
    r = o.resolved()
    if not isinstance(r.rooms, (int, np.integer)) or not 1 <= r.rooms <= 12:
        raise InputError(source, "rooms", f"{o.rooms!r}: between 1 and 12 rooms")
    if not isinstance(r.objects, (int, np.integer)) or r.objects < r.rooms:
        raise InputError(source, "objects", f"{o.objects!r}: at least one object per room ({r.rooms} rooms)")
    if not isinstance(r.clutter, (int, float)) or not 0.0 <= r.clutter <= 1.0:
        raise InputError(source, "clutter", f"{o.clutter!r}: a share between 0 and 1")
    if not isinstance(r.tuck, (int, float)) or not 0.0 <= r.tuck <= 1.0:
        raise InputError(source, "tuck", f"{o.tuck!r}: a share between 0 and 1")
    if not isinstance(r.turn, (int, float)) or not 0.0 <= r.turn <= 180.0:
        raise InputError(source, "turn", f"{o.turn!r}: degrees between 0 and 180")
    if not isinstance(r.islands, (int, float)) or not 0.0 <= r.islands <= 1.0:
        raise InputError(source, "islands", f"{o.islands!r}: a share between 0 and 1")
    if not isinstance(r.spare, (int, float)) or not 0.0 <= r.spare <= 1.0:
        raise InputError(source, "spare", f"{o.spare!r}: a share between 0 and 1")
    area = sum(ROOMS[t].area[1] for t in room_types(r.kind, r.rooms))
    most = int(area / PER_OBJECT_M2)
    if r.objects > most:
        raise InputError(source, "objects", f"{r.objects} objects do not fit {r.rooms} rooms of a {r.kind} "
                         f"(at most {most}: one per {PER_OBJECT_M2:g} m^2 of up to {area:g} m^2); "
                         "ask for more rooms or fewer objects")
    return r


# ----------------------------------------------------------------------------- generation


def generate(options: GenOptions) -> Layout:
    """A layout for ``options`` (the same options always give the same layout)."""
    o = check_options(options)
    unplaced: list[str] = []
    for attempt in range(ATTEMPTS):
        rng = np.random.default_rng([VERSION, KINDS.index(o.kind), o.seed, attempt])
        plan = floor_plan(o.kind, o.rooms, rng)
        if plan is None:
            continue
        items, unplaced = _furnish(o, rng, plan.rooms, plan.cuts, plan.doors)
        if unplaced:
            continue
        spawn = check(plan, items)
        if spawn is not None:
            return Layout(options, *plan, items, spawn, attempt)
    what = f"could not place {', '.join(unplaced)}" if unplaced else "no layout passed the reachability checks"
    ask = "fewer objects, more rooms or a lower spare (spare chairs need free wall)" if o.spare else (
        "fewer objects or more rooms")
    raise GenerationError(options.name, "objects", f"{what} in {ATTEMPTS} attempts for {o.objects} objects in "
                          f"{o.rooms} rooms; ask for {ask}")


# ----------------------------------------------------------------------------- furnishing


class _Room(NamedTuple):
    index: int
    type: str
    rect: Rect


class _Placer:
    """Placed items and the zones that must stay free (each zone tagged with its group)."""

    def __init__(self, zones: list[Rect]):
        self.items: list[Item] = []
        self.group: list[int] = []
        self.zones: list[tuple[Rect, int]] = [(z, -1) for z in zones]
        self.next_group = 0
        self.used: dict[tuple[int, str], int] = {}  # (room, group name) -> times placed

    def fits(self, items: list[Item], zones: list[Rect], room: Rect) -> bool:
        g = self.next_group
        for it in items:
            if not it.rect.within(room):
                return False
            for other in self.items:
                if it.rect.overlaps(other.rect) and it.z < other.top and other.z < it.top:
                    return False
            if it.z == 0 and any(it.rect.overlaps(z) for z, owner in self.zones if owner != g):
                return False
        for z in zones:
            if not z.within(room):
                return False
            if any(z.overlaps(o.rect) for o in self.items if o.z == 0):
                return False
        return True

    def add(self, items: list[Item], zones: list[Rect]) -> None:
        g = self.next_group
        self.items += items
        self.group += [g] * len(items)
        self.zones += [(z, g) for z in zones]
        self.next_group += 1


def _draw(rng, key: str) -> tuple[Piece, tuple[int, int, int], dict]:
    p = PIECES[key]
    size = (even(rng, *p.width), even(rng, *p.depth), even(rng, *p.height))
    colors = {arg: choices[int(rng.integers(len(choices)))] for arg, choices in p.colors.items()}
    return p, size, colors


def _wall_rect(room: Rect, side: int, u0: int, u1: int, v0: int, v1: int) -> Rect:
    """The plan rect at offsets u (along the wall of ``side``) and v (out from it).
    Sides: 0 north (y1), 1 west (x0), 2 south (y0), 3 east (x1); k of a back to it = side."""
    x0, y0, x1, y1 = room
    if side == 0:
        return Rect(x0 + u0, y1 - v1, x0 + u1, y1 - v0)
    if side == 1:
        return Rect(x0 + v0, y0 + u0, x0 + v1, y0 + u1)
    if side == 2:
        return Rect(x0 + u0, y0 + v0, x0 + u1, y0 + v1)
    return Rect(x1 - v1, y0 + u0, x1 - v0, y0 + u1)


def _set_back(depth: int, piece_depth: int) -> int:
    """How far (cm) a piece on a top ``depth`` deep stands from its back edge: a third of the
    way in, 2 cm clear."""
    return 2 + (depth - 4 - piece_depth) // 3


def _wall_group(rng, room: Rect, key: str, front: list[str] = (), on: list[str] = (),
                access: int = ACCESS):
    """``key`` against a random wall, pieces ``front`` facing it side by side in front of it,
    pieces ``on`` on top of it. Returns (items, zones) or None if it cannot fit."""
    side = int(rng.integers(4))
    length = room.w if side in (0, 2) else room.h
    piece, size, colors = _draw(rng, key)
    if size[0] > length:
        return None
    t = int(rng.integers(0, length - size[0] + 1))
    anchor = Item(piece, size, _wall_rect(room, side, t, t + size[0], GAP, GAP + size[1]), side, colors=colors)
    items, v = [anchor], GAP + size[1]
    fronts = [_draw(rng, f) for f in front]
    if fronts:
        slot = size[0] // len(fronts)
        depth = max(s[1] for _, s, _ in fronts)
        for i, (p, s, c) in enumerate(fronts):
            u = t + i * slot + (slot - s[0]) // 2
            items.append(Item(p, s, _wall_rect(room, side, u, u + s[0], v + 6, v + 6 + s[1]), (side + 2) % 4,
                              colors=c))
        v += 6 + depth
    for i, key_on in enumerate(on):
        p, s, c = _draw(rng, key_on)
        slot = size[0] // len(on)
        if s[0] > slot or s[1] > size[1] - 4:
            continue
        u = t + i * slot + (slot - s[0]) // 2
        back = GAP + _set_back(size[1], s[1])
        items.append(Item(p, s, _wall_rect(room, side, u, u + s[0], back, back + s[1]), side, anchor.top, colors=c))
    zone = _wall_rect(room, side, t, t + size[0], v, v + access)
    return items, [zone]


def _table_group(rng, room: Rect, table: str, chair: str, ends: bool):
    """A table standing free with chairs on its long sides (and ends), backs turned away."""
    p, size, colors = _draw(rng, table)
    turn = int(rng.integers(2))  # 0: the long side along x
    tw, th = (size[0], size[1]) if turn == 0 else (size[1], size[0])
    top = Rect(0, 0, tw, th)
    items = [Item(p, size, top, turn, colors=colors)]
    cp, cs, cc = _draw(rng, chair)
    cw, cd = cs[0], cs[1]
    n_long = max(1, min(3, size[0] // 70))  # chairs 70 cm apart at least (they are <= 62 wide)
    long_sides, end_sides = ((0, 2), (1, 3)) if turn == 0 else ((1, 3), (0, 2))
    plan = [(s, n_long) for s in long_sides] + ([(s, 1) for s in end_sides] if ends else [])
    for side, n in plan:
        length = tw if side in (0, 2) else th
        for i in range(n):
            u = length * (2 * i + 1) // (2 * n) - cw // 2
            if side == 0:  # north of the table, back to +y
                r = Rect(u, th + 6, u + cw, th + 6 + cd)
            elif side == 2:
                r = Rect(u, -6 - cd, u + cw, -6)
            elif side == 1:  # west, back to -x
                r = Rect(-6 - cd, u, -6, u + cw)
            else:
                r = Rect(tw + 6, u, tw + 6 + cd, u + cw)
            items.append(Item(cp, cs, r, side, colors=cc))
    return _place_free(rng, room, items)


def _place_free(rng, room: Rect, items: list[Item]):
    """Items laid out in their own plan frame, moved to a random spot of ``room`` with AROUND
    cm free around them all: (items, [that zone]), or None if they do not fit."""
    bound = Rect(min(i.rect.x0 for i in items), min(i.rect.y0 for i in items),
                 max(i.rect.x1 for i in items), max(i.rect.y1 for i in items)).grow(AROUND)
    if bound.w > room.w or bound.h > room.h:
        return None
    dx = room.x0 - bound.x0 + int(rng.integers(0, room.w - bound.w + 1))
    dy = room.y0 - bound.y0 + int(rng.integers(0, room.h - bound.h + 1))
    for it in items:
        it.rect = Rect(it.rect.x0 + dx, it.rect.y0 + dy, it.rect.x1 + dx, it.rect.y1 + dy)
    return items, [Rect(bound.x0 + dx, bound.y0 + dy, bound.x1 + dx, bound.y1 + dy)]


def _island_group(rng, room: Rect):
    """A free-standing row of 2-4 equal desks end to end (half the time two rows back to
    back), an office chair facing each and a monitor on each, as open-plan offices and labs
    set desks; placed like a table group."""
    p, (dw, dd, dh), colors = _draw(rng, "desk")
    n, rows = int(rng.integers(2, 5)), 1 + int(rng.random() < 0.5)
    items = []
    for row in range(rows):  # row 0's users sit south of it (its back faces +y), row 1's north
        k, y0 = (0, 0) if row == 0 else (2, dd)
        for i in range(n):
            desk = Item(p, (dw, dd, dh), Rect(i * dw, y0, (i + 1) * dw, y0 + dd), k, colors=colors)
            cp, cs, cc = _draw(rng, "office_chair")
            u = i * dw + (dw - cs[0]) // 2
            v = -6 - cs[1] if row == 0 else 2 * dd + 6  # 6 cm off the desk's front
            seat = Rect(u, v, u + cs[0], v + cs[1])
            mp, ms, mc = _draw(rng, "monitor")
            m = i * dw + (dw - ms[0]) // 2
            off = _set_back(dd, ms[1])
            v = dd - off - ms[1] if row == 0 else dd + off
            screen = Rect(m, v, m + ms[0], v + ms[1])
            items += [desk, Item(cp, cs, seat, (k + 2) % 4, colors=cc), Item(mp, ms, screen, k, desk.top, colors=mc)]
    if rng.random() < 0.5:  # the rows along y: a quarter turn counter-clockwise
        for it in items:
            r = it.rect
            it.rect, it.k = Rect(-r.y1, r.x0, -r.y0, r.x1), (it.k + 1) % 4
    return _place_free(rng, room, items)


def _counter(rng, room: Rect):
    """A kitchen counter along a wall: fridge, cabinets, stove, sink; a microwave on a cabinet."""
    side = int(rng.integers(4))
    length = room.w if side in (0, 2) else room.h
    keys = ["refrigerator", "kitchen_cabinet", "stove", "kitchen_cabinet", "sink", "kitchen_cabinet"]
    units = [_draw(rng, k) for k in keys]
    while units and sum(s[0] for _, s, _ in units) > length:
        units.pop()
    if len(units) < 3:
        return None
    total = sum(s[0] for _, s, _ in units)
    t = int(rng.integers(0, length - total + 1))
    items = []
    for p, s, c in units:
        items.append(Item(p, s, _wall_rect(room, side, t, t + s[0], GAP, GAP + s[1]), side, colors=c))
        t += s[0]
    cabinets = [it for it in items if it.piece.template == "cabinet"]
    mp, ms, mc = _draw(rng, "microwave")
    host = cabinets[int(rng.integers(len(cabinets)))]
    if ms[0] <= host.size[0] - 4:
        u0 = (host.rect.x0 if side in (0, 2) else host.rect.y0) - (room.x0 if side in (0, 2) else room.y0)
        u = u0 + (host.size[0] - ms[0]) // 2
        items.insert(items.index(host) + 1, Item(mp, ms, _wall_rect(room, side, u, u + ms[0], GAP + 4, GAP + 4 + ms[1]),
                                                 side, host.top, colors=mc))
    depth = max(s[1] for _, s, _ in units)
    return items, [_wall_rect(room, side, t - total, t, GAP + depth, GAP + depth + ACCESS + 30)]


def _on_support(rng, placer: _Placer, room: _Room, key: str):
    """A small piece on a desk, table or cabinet top in ``room``."""
    tops = [it for it in placer.items if it.room == room.index and it.z == 0 and it.piece.category in SUPPORTS]
    if not tops:
        return None
    host = tops[int(rng.integers(len(tops)))]
    p, s, c = _draw(rng, key)
    w, d = (s[0], s[1]) if host.k % 2 == 0 else (s[1], s[0])
    inner = host.rect.grow(-4) if host.piece.template != "round_table" else host.rect.grow(-host.rect.w // 5)
    if w > inner.w or d > inner.h:
        return None
    x0 = inner.x0 + int(rng.integers(0, inner.w - w + 1))
    y0 = inner.y0 + int(rng.integers(0, inner.h - d + 1))
    return [Item(p, s, Rect(x0, y0, x0 + w, y0 + d), host.k, host.top, colors=c)], []


def _group(rng, name: str, room: _Room, placer: _Placer, o: GenOptions):
    """Candidate (items, zones) of group ``name`` in ``room`` (or None)."""
    r = room.rect
    if name in ("desk", "bench") and o.islands and rng.random() < o.islands:
        return _island_group(rng, r)
    if name == "desk":
        return _wall_group(rng, r, "desk", ["office_chair"], ["monitor"])
    if name == "bench":
        return _wall_group(rng, r, "bench_desk", ["office_chair", "office_chair"], ["monitor", "monitor"])
    if name == "tv":
        return _wall_group(rng, r, "tv_stand", on=["tv"])
    if name == "spare_chair":
        return _wall_group(rng, r, "chair")
    if name == "dining":
        return _table_group(rng, r, "dining_table", "chair", ends=bool(rng.random() < 0.4))
    if name == "round_dining":
        return _table_group(rng, r, "round_table", "chair", ends=True)
    if name == "meeting":  # a long table where the room takes one, else a dining table
        table = "meeting_table" if rng.random() < 0.6 else "dining_table"
        return _table_group(rng, r, table, "chair" if rng.random() < 0.5 else "office_chair", ends=True)
    if name == "counter":
        return _counter(rng, r)
    if name == "bed":
        return _wall_group(rng, r, "bed" if rng.random() < 0.6 else "single_bed")
    if name == "book":
        return _on_support(rng, placer, room, "book")
    return _wall_group(rng, r, name, access=30 if name in SMALL else ACCESS)


def _leave_chairs(rng, items: list[Item], o: GenOptions) -> None:
    """Leave the floor chairs of a desk or table group (anchor first) as people do: each is
    pushed in under the nearest desk or table with probability ``o.tuck``, by 0 to half its
    depth (cm, drawn uniformly), and turned by up to ``o.turn`` degrees either way. Draws
    nothing when both are 0, so worlds without them are those of before."""
    if not (o.tuck or o.turn) or items[0].piece.category not in ("desk", "dining table"):
        return
    tables = [it.rect for it in items if it.piece.category in ("desk", "dining table") and it.z == 0]
    for it in items[1:]:
        if it.piece.category != "chair" or it.z != 0:
            continue
        if o.tuck and rng.random() < o.tuck:
            r = it.rect
            anchor = min(tables, key=lambda t: abs(t.x0 + t.x1 - r.x0 - r.x1) + abs(t.y0 + t.y1 - r.y0 - r.y1))
            # the side of the anchor the chair stands on, and the gap to close
            for gap, dx, dy, depth in ((r.y0 - anchor.y1, 0, -1, r.h), (anchor.y0 - r.y1, 0, 1, r.h),
                                       (r.x0 - anchor.x1, -1, 0, r.w), (anchor.x0 - r.x1, 1, 0, r.w)):
                if gap >= 0:
                    d = gap + int(rng.integers(0, depth // 2 + 1))
                    it.rect = Rect(r.x0 + dx * d, r.y0 + dy * d, r.x1 + dx * d, r.y1 + dy * d)
                    break
        if o.turn:
            it.turn = float(rng.uniform(-o.turn, o.turn))


def _try(rng, placer: _Placer, room: _Room, names, budget: int, tries: int, o: GenOptions) -> int:
    """Place one group of a name drawn from ``names`` (cut to ``budget`` objects, its chairs
    left as ``o`` says); returns the number of objects placed (0: nothing fitted in ``tries``
    draws)."""
    names = [n for n in names if placer.used.get((room.index, n), 0) < REPEAT.get(n, 2)]
    for _ in range(tries if names else 0):
        name = names[int(rng.integers(len(names)))]
        cand = _group(rng, name, room, placer, o)
        if cand is None:
            continue
        items, zones = cand
        items = items[:budget]
        _leave_chairs(rng, items, o)
        if placer.fits(items, zones, room.rect):
            for it in items:
                it.room = room.index
            placer.add(items, zones)
            placer.used[room.index, name] = placer.used.get((room.index, name), 0) + 1
            return len(items)
    return 0


def _furnish(o: GenOptions, rng, rooms, cuts, doors) -> tuple[list[Item], list[str]]:
    placer = _Placer(door_zones(cuts, doors))
    rs = [_Room(i, t, r) for i, (t, r) in enumerate(rooms)]
    clutter = int(round(o.objects * o.clutter))
    budget = o.objects - clutter
    count = [0] * len(rs)
    for depth in range(max(len(ROOMS[r.type].must) for r in rs)):
        for r in rs:
            must = ROOMS[r.type].must
            if depth < len(must) and budget > 0:
                n = _try(rng, placer, r, (must[depth],), budget, 12, o)
                count[r.index] += n
                budget -= n
    open_rooms = list(rs)
    while budget > 0 and open_rooms:
        r = min(open_rooms, key=lambda r: (count[r.index] / r.rect.w / r.rect.h, r.index))
        n = _try(rng, placer, r, ROOMS[r.type].more, budget, 8, o)
        if n == 0:
            open_rooms.remove(r)
        count[r.index] += n
        budget -= n
    left = clutter + budget
    weights = np.array([r.rect.w * r.rect.h for r in rs], float)
    misses: list[str] = []
    while left > 0:
        placed = 0
        for _ in range(6):
            r = rs[int(rng.choice(len(rs), p=weights / weights.sum()))]
            spare = o.spare and rng.random() < o.spare  # no draw without the option: worlds stay as they were
            placed = _try(rng, placer, r, ("spare_chair",) if spare else ROOMS[r.type].clutter, 1, 4, o)
            if placed:
                break
        if not placed:
            misses.append("a clutter object")
        left -= 1
    if misses:
        misses = [f"{len(misses)} clutter object{'s' * (len(misses) > 1)}"]
    return placer.items, misses


