"""Object-goal episodes of a world (docs/tasks.md), in the manner of Habitat's ObjectNav
episode datasets: a start pose in free space and a goal category present in the world,
with the geodesic distance from the start to the nearest success region of the category.

A **success region** of a category is the union of the approach nodes
(:mod:`rosmeery_jax.world.approach`) of the cells holding a surface sample of an object of
that category: the reachable cells (the robot's centre) within ``SUCCESS_DISTANCE`` (1.0 m,
Habitat's ObjectNav radius) of such a cell, centre to centre on the floor plane, with no
wall cell between them (furniture does not block the sight: the camera sees over most of it).

A set is generated from a seed (:func:`generate`): goals cycle through the world's
reachable categories in a shuffled order, so every category is a goal at least once when
there are as many episodes as categories; starts are spread over the free space by
farthest-point sampling from a random first cell (so they cover the rooms), each at least
``MIN_DISTANCE`` (1 m) from its goal's region where the world has such a start (else the
farthest one outside the region). The file (:func:`write`, :func:`read`)::

    {"format": "rosmeery-objectnav", "version": 1, "world": "kitchen", "world_sha256": "...",
     "seed": 0, "robot_radius": 0.2, "success_distance": 1.0,
     "episodes": [{"id": 0, "start": [x, y, yaw], "goal": "chair", "geodesic_distance": 3.41}, ...]}

Shapes: E episodes, H x W cells.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import write_atomic
from rosmeery_jax.world import geodesic
from rosmeery_jax.world.approach import SUCCESS_DISTANCE, Approach
from rosmeery_jax.world.freespace import rasterize
from rosmeery_jax.world.scene import WALL

FORMAT, VERSION = "rosmeery-objectnav", 1
MIN_DISTANCE = 1.0  # m: a start's least geodesic distance to its goal's region
MAX_EPISODES = 10_000  # a set larger than this is a mistake (and would not fit a batch)
DEFAULT_EPISODES, DEFAULT_SEED = 50, 0


class Episode(NamedTuple):
    id: int
    start: tuple[float, float, float]
    goal: str
    geodesic_distance: float


class Regions(NamedTuple):
    """A world's task geometry: its free-space graph, its approach nodes (what blocks a line
    of sight: its wall cells), each category's success region (H, W) bool and the geodesic
    distance field (H, W) metres to it."""

    graph: geodesic.Graph
    approach: Approach
    region: dict
    distance: dict


def world_hash(world) -> str:
    return hashlib.sha256(Path(world.path).read_bytes()).hexdigest()


_REGIONS: dict = {}  # (world file, its config): Regions


def regions(world) -> Regions:
    """Success regions and distance fields of every category of ``world`` (cached per world
    file and configuration)."""
    key = (str(world.path), world_hash(world), world.config)
    if key not in _REGIONS:
        _REGIONS[key] = _regions(world)
    return _REGIONS[key]


def _regions(world) -> Regions:
    fs = world.free_space
    g = geodesic.graph(fs)
    walls = rasterize(world.scene, world.scene.object_id == WALL, fs.origin, fs.occupied.shape, fs.resolution)
    near = Approach(walls, g, fs.origin)
    t = world.truth
    obj = np.asarray(t.samples.object)
    cells = near.cells(np.asarray(t.samples.points, np.float64)[:, :2])
    region, distance = {}, {}
    for category in sorted(set(t.categories)):
        ids = [n for n, c in enumerate(t.categories) if c == category]
        region[category] = near.region(cells[np.isin(obj, ids)])
        distance[category] = geodesic.field(g, np.argwhere(region[category]))
    return Regions(g, near, region, distance)


def approach_region(world, xy: np.ndarray) -> np.ndarray:
    """(H, W) the approach region of the points ``xy`` (P, 2): a success region's rule
    applied to any points (a map's instance)."""
    near = regions(world).approach
    return near.region(near.cells(xy))


def generate(world, episodes: int = DEFAULT_EPISODES, seed: int = DEFAULT_SEED) -> list[Episode]:
    """``episodes`` object-goal episodes of ``world`` from ``seed`` (module docstring): the
    same episodes for the same world and seed, whatever else runs."""
    check_count(episodes, "command line", "--episodes")
    reg = regions(world)
    fs = world.free_space
    goals = [c for c in sorted(reg.region) if reg.region[c].any()]
    if not goals:
        raise InputError(world.path, "objects", "no object can be reached within 1 m: no episode can be made")
    rng = np.random.default_rng(seed)
    order = [goals[i] for i in rng.permutation(len(goals))]
    cells = _spread(np.argwhere(fs.reachable), rng, min(len(np.argwhere(fs.reachable)), 4 * episodes))
    out, used = [], np.zeros(len(cells), bool)
    for k in range(episodes):
        goal = order[k % len(order)]
        d = reg.distance[goal][cells[:, 0], cells[:, 1]]
        d = np.where(np.isfinite(d), d, -1.0)
        ok = np.flatnonzero(~used & (d >= MIN_DISTANCE))
        if not len(ok):  # a small world: the farthest start outside the region, used or not
            ok = [int(np.argmax(d))] if d.max() > 0 else []
        if not len(ok):
            raise InputError(world.path, "free space", f"every reachable cell is within a {goal}'s success region")
        pick = ok[0]
        used[pick] = True
        i, j = cells[pick]
        x, y = fs.origin + (np.array([j, i]) + 0.5) * fs.resolution
        yaw = float(rng.uniform(-math.pi, math.pi))
        out.append(Episode(k, (round(float(x), 4), round(float(y), 4), round(yaw, 4)), goal,
                           round(float(d[pick]), 4)))
    return out


_GENERATED: dict = {}  # (world file, its config, count): the seed-0 set


def generated(world, episodes: int = DEFAULT_EPISODES) -> list[Episode]:
    """The world's default set of ``episodes`` (seed 0), made once per process."""
    key = (str(world.path), world_hash(world), world.config, episodes)
    if key not in _GENERATED:
        _GENERATED[key] = generate(world, episodes, DEFAULT_SEED)
    return _GENERATED[key]


def _spread(cells: np.ndarray, rng, n: int) -> np.ndarray:
    """``n`` of ``cells`` (V, 2) by farthest-point sampling from a random first one."""
    chosen = [int(rng.integers(len(cells)))]
    gap = np.hypot(*(cells - cells[chosen[0]]).T)
    for _ in range(n - 1):
        chosen.append(int(np.argmax(gap)))
        gap = np.minimum(gap, np.hypot(*(cells - cells[chosen[-1]]).T))
    return cells[chosen]


def check_count(episodes, source, where: str) -> None:
    if isinstance(episodes, bool) or not isinstance(episodes, int) or not 1 <= episodes <= MAX_EPISODES:
        raise InputError(source, where, f"{episodes!r} must be a whole number of episodes in [1, {MAX_EPISODES}]")


def write(path: str | Path, world, episodes: list[Episode], seed: int) -> Path:
    """The episode file (module docstring), written atomically."""
    doc = {"format": FORMAT, "version": VERSION, "world": world.name, "world_sha256": world_hash(world),
           "seed": seed, "robot_radius": float(world.config.robot_radius), "success_distance": SUCCESS_DISTANCE,
           "episodes": [{"id": e.id, "start": list(e.start), "goal": e.goal, "geodesic_distance": e.geodesic_distance}
                        for e in episodes]}
    return write_atomic(Path(path), json.dumps(doc, indent=1))


def read(path: str | Path, world) -> list[Episode]:
    """An episode file for ``world``, every episode checked (its goal a category of the
    world that can be reached, its start a finite pose on the free space); its geodesic
    distance is computed again, not trusted. One InputError naming the file and field."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(path, "file", "not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
        raise InputError(path, "file", f"not a JSON episode file ({type(err).__name__})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError(path, "format", f"must be {FORMAT!r}")
    if doc.get("world") != world.name:
        raise InputError(path, "world", f"{doc.get('world')!r} is not the world scored ({world.name!r})")
    items = doc.get("episodes")
    if not isinstance(items, list) or not items:
        raise InputError(path, "episodes", "must be a non-empty list")
    check_count(len(items), path, "episodes")
    return [_episode(path, world, k, e) for k, e in enumerate(items)]


def _episode(path: Path, world, k: int, e) -> Episode:
    where = f"episodes[{k}]"
    if not isinstance(e, dict):
        raise InputError(path, where, "must be an object (id, start, goal)")
    start = e.get("start")
    if (not isinstance(start, list) or len(start) != 3 or any(isinstance(v, bool) or not isinstance(v, (int, float))
                                                             or not math.isfinite(v) for v in start)):
        raise InputError(path, f"{where}.start", f"{start!r} is not a pose [x, y, yaw] of finite numbers")
    reg = regions(world)
    goal = e.get("goal")
    if goal not in reg.region:
        raise InputError(path, f"{where}.goal", f"{goal!r} is not a category of {world.name} (it has "
                         f"{', '.join(sorted(reg.region))})")
    fs = world.free_space
    i, j = fs.cell(start[:2])
    if not (fs.contains(start[:2]) and fs.reachable[i, j]):
        raise InputError(path, f"{where}.start", f"{start[:2]} is not on the free space a robot of radius "
                         f"{world.config.robot_radius} m reaches (inside an obstacle, or outside the world)")
    d = float(reg.distance[goal][i, j])
    if not math.isfinite(d):
        raise InputError(path, f"{where}.goal", f"no {goal} can be reached from {start[:2]}")
    eid = e.get("id", k)
    eid = eid if isinstance(eid, int) and not isinstance(eid, bool) else k  # an unusable id: its place
    return Episode(eid, tuple(float(v) for v in start), goal, round(d, 4))
