"""What procedural rooms hold: furniture pieces (sizes in cm, template, colours) and, per kind
of room, the groups it must have, the groups it may repeat and its small clutter.

Sizes are ranges of common real furniture (a desk 120-160 x 70-80 x 75 cm, a double bed
140-160 x 200-210 cm). Every size is an even number of centimetres, so every footprint centre
falls on a whole centimetre and the written file is exact. Canonical frame of a piece: width
along x, depth along y, its back at +y and its front facing -y (the templates of
:mod:`.furniture` are built so).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from rosmeery_jax.world import furniture as F


@dataclass(frozen=True)
class Piece:
    """One kind of object: taxonomy ``category``, furniture ``template`` and its ``kwargs``,
    size ranges in cm (width x, depth y, height z; inclusive), and ``colors``: per template
    argument, the colours drawn from."""

    category: str
    template: str
    width: tuple[int, int]
    depth: tuple[int, int]
    height: tuple[int, int]
    kwargs: dict = field(default_factory=dict)
    colors: dict = field(default_factory=dict)


WOODS = (F.WOOD, F.DARK_WOOD, F.LIGHT_WOOD, F.WHITE)
FABRICS = (F.FABRIC_RED, F.FABRIC_BLUE, F.FABRIC_GREY, (0.42, 0.30, 0.52, 1.0), (0.25, 0.45, 0.35, 1.0))
SHEETS = ((0.85, 0.88, 0.95, 1.0), (0.80, 0.86, 0.78, 1.0), (0.93, 0.85, 0.80, 1.0), (0.70, 0.72, 0.80, 1.0))
COUNTERS = ((0.30, 0.30, 0.32, 1.0), (0.85, 0.83, 0.78, 1.0), F.DARK_WOOD)

PIECES: dict[str, Piece] = dict([
    ("desk", Piece("desk", "desk", (120, 160), (70, 80), (74, 76), colors={"top": WOODS})),
    ("bench_desk", Piece("desk", "desk", (200, 300), (76, 80), (74, 76), colors={"top": WOODS})),
    ("office_chair", Piece("chair", "office_chair", (56, 62), (56, 62), (96, 110), {"front": "-y"},
                           {"fabric": FABRICS + (F.BLACK,)})),
    ("chair", Piece("chair", "chair", (44, 50), (46, 52), (84, 96), {"front": "-y"},
                    {"seat": WOODS + FABRICS[:3], "frame": (F.DARK_WOOD, F.METAL, F.BLACK)})),
    ("monitor", Piece("monitor", "screen", (50, 66), (18, 22), (40, 50))),
    ("tv", Piece("tv", "screen", (100, 140), (22, 28), (60, 80))),
    ("tv_stand", Piece("tv_stand", "tv_stand", (120, 180), (40, 50), (46, 56))),
    ("pc_tower", Piece("pc_tower", "pc_tower", (20, 22), (44, 48), (42, 48))),
    ("dining_table", Piece("dining table", "table", (120, 180), (80, 100), (74, 76),
                           colors={"top": WOODS, "legs": (F.DARK_WOOD, F.METAL, F.BLACK)})),
    ("meeting_table", Piece("dining table", "table", (200, 280), (100, 120), (74, 76),
                            colors={"top": WOODS, "legs": (F.DARK_WOOD, F.METAL, F.BLACK)})),
    ("round_table", Piece("dining table", "round_table", (90, 120), (90, 120), (74, 76),
                          colors={"top": WOODS})),
    ("sofa", Piece("couch", "sofa", (180, 240), (86, 96), (80, 90), colors={"fabric": FABRICS})),
    ("bed", Piece("bed", "bed", (140, 160), (200, 210), (90, 110), {"head": "+x"},
                  {"sheet": SHEETS, "frame": WOODS[:3]})),
    ("single_bed", Piece("bed", "bed", (90, 100), (200, 206), (86, 100), {"head": "+x"},
                         {"sheet": SHEETS, "frame": WOODS[:3]})),
    ("wardrobe", Piece("cabinet", "cabinet", (100, 150), (56, 62), (190, 210), {"n_drawers": 2},
                       {"body": WOODS, "front": WOODS})),
    ("dresser", Piece("dresser", "cabinet", (80, 120), (44, 54), (80, 100), {"n_drawers": 3},
                      {"body": WOODS, "front": WOODS})),
    ("storage_cabinet", Piece("cabinet", "cabinet", (80, 120), (44, 50), (100, 140), {"n_drawers": 4},
                              {"body": (F.METAL, F.WHITE, F.WOOD), "front": (F.METAL, F.WHITE)})),
    ("shelf", Piece("shelf", "shelf", (80, 120), (30, 40), (160, 200), {"n_boards": 4},
                    {"wood": WOODS})),
    ("kitchen_cabinet", Piece("kitchen_cabinet", "cabinet", (60, 90), (60, 60), (90, 92),
                              {"n_drawers": 2}, {"body": (F.WHITE, F.WOOD, F.LIGHT_WOOD),
                                                 "front": ((0.80, 0.82, 0.85, 1.0), F.WOOD, F.WHITE),
                                                 "top": COUNTERS})),
    ("stove", Piece("oven", "stove", (60, 60), (60, 60), (90, 92))),
    ("sink", Piece("sink", "sink", (60, 90), (56, 60), (90, 100))),
    ("refrigerator", Piece("refrigerator", "refrigerator", (70, 80), (68, 72), (170, 190))),
    ("microwave", Piece("microwave", "microwave", (46, 54), (34, 40), (28, 32))),
    ("toilet", Piece("toilet", "toilet", (38, 42), (64, 70), (74, 80))),
    ("shower", Piece("shower", "shower", (80, 90), (80, 90), (200, 206))),
    ("book", Piece("book", "books", (20, 34), (16, 22), (20, 28))),
    ("boxes", Piece("boxes", "boxes", (60, 90), (40, 60), (50, 80))),
    ("trash_can", Piece("trash_can", "trash_can", (30, 36), (30, 36), (40, 60))),
    ("potted_plant", Piece("potted plant", "potted_plant", (40, 50), (40, 50), (80, 120))),
    ("coat_rack", Piece("coat_rack", "coat_rack", (44, 50), (44, 50), (170, 180))),
])

# Small pieces against a wall: they keep 30 cm free in front (furniture 60 cm).
SMALL = ("potted_plant", "trash_can", "boxes", "coat_rack", "pc_tower")

# Pieces that others may stand on (books, a monitor, a microwave).
SUPPORTS = ("desk", "dining table", "tv_stand", "dresser", "kitchen_cabinet")


@dataclass(frozen=True)
class RoomType:
    """area: target floor area range (m^2); must: groups every such room gets first; more:
    groups added while the object budget lasts; clutter: small single objects."""

    area: tuple[float, float]
    must: tuple[str, ...]
    more: tuple[str, ...]
    clutter: tuple[str, ...]


_SMALL = ("potted_plant", "trash_can", "boxes", "book")
_DESKTOP = _SMALL + ("pc_tower",)
ROOMS: dict[str, RoomType] = {
    "living": RoomType((20, 30), ("sofa", "tv"), ("shelf", "round_dining", "coat_rack", "dresser"), _SMALL + ("coat_rack",)),
    "kitchen": RoomType((11, 16), ("counter",), ("dining", "shelf"), ("trash_can", "potted_plant", "book")),
    "kitchen_dining": RoomType((22, 32), ("counter", "dining"), ("shelf", "dining", "sofa"), _SMALL),
    "bedroom": RoomType((11, 16), ("bed", "wardrobe"), ("dresser", "desk", "shelf"), ("potted_plant", "trash_can", "book")),
    "bathroom": RoomType((5, 7), ("toilet", "sink"), ("shower",), ("trash_can",)),
    "study": RoomType((9, 12), ("desk",), ("shelf", "desk", "storage_cabinet"), _DESKTOP),
    "open_office": RoomType((28, 42), ("desk",), ("desk", "desk", "shelf", "storage_cabinet"), _DESKTOP + ("coat_rack",)),
    "meeting": RoomType((14, 20), ("meeting",), ("shelf", "tv", "storage_cabinet"), ("potted_plant", "trash_can", "book")),
    "office": RoomType((10, 14), ("desk",), ("desk", "shelf", "storage_cabinet"), _DESKTOP),
    "storage": RoomType((6, 9), ("shelf",), ("shelf", "storage_cabinet", "boxes"), ("boxes", "trash_can")),
    "lab": RoomType((30, 44), ("bench",), ("bench", "desk", "shelf", "storage_cabinet"), _DESKTOP),
}

# How often a group may repeat in one room (others: twice).
REPEAT = {"desk": 8, "bench": 4, "shelf": 3, "boxes": 3, "book": 3}

# The rooms of each kind of world, largest first; more rooms than listed repeat the tail.
KIND_ROOMS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "apartment": (("living", "kitchen", "bedroom", "bathroom"), ("bedroom", "study")),
    "office": (("open_office", "meeting", "office", "storage"), ("office",)),
    "kitchen": (("kitchen_dining", "living", "bathroom"), ("bedroom", "storage")),
    "lab": (("lab", "office", "storage"), ("lab", "office")),
}
KIND_DEFAULTS = {"apartment": (5, 30), "office": (4, 28), "kitchen": (3, 26), "lab": (3, 22)}  # rooms, objects


def room_types(kind: str, rooms: int) -> list[str]:
    """The ``rooms`` room types of a world of ``kind``."""
    first, tail = KIND_ROOMS[kind]
    out = list(first[:rooms])
    while len(out) < rooms:
        out.append(tail[(len(out) - len(first)) % len(tail)])
    return out
