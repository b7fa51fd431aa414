"""Map-use metrics (docs/tasks.md): how well a semantic map serves object-goal navigation.

For each episode (:mod:`rosmeery_jax.world.episodes`: a start, a goal category) the map
answers the query as a robot using it would: from the start it drives to the nearest (by
geodesic distance from where it stands) of the map's instances labelled with the goal
category, and stops at the first cell of that instance's **approach region** it reaches:
the reachable cells within 1.0 m of one of the instance's points with a line of sight to
it (the rule of the true success regions, applied to the map). If the stop cell lies in a
true success region of the goal category, the episode succeeds; else the robot tries the
nearest instance from there not yet tried, at most ``attempts`` instances in all (the path
accumulates). Path lengths are geodesic on the true free space at the robot's radius.

Per episode, with l* its geodesic distance from the start to the goal's success region, l
the path driven and d_T the geodesic distance from the stop cell to that region:

- ``task_success`` S: 1 if it stopped in a success region, else 0;
- ``task_spl``: S l* / max(l, l*) (Anderson et al. 2018);
- ``task_softspl``: (1 - d_T / l*) l* / max(l, l*), the progress made (Datta et al. 2021);
- ``task_distance``: d_T in metres (Habitat's distance to goal).

Each metric is the mean over the episodes. An episode whose goal the map never labels,
or whose instances cannot be reached, stops at its start (S 0, distance l*). Every
episode advances together: one Dijkstra per instance (SciPy, from its whole approach
region at once), then each attempt an arg-min over instances for all episodes.

Shapes: E episodes, U instances labelled with a goal, V free-space cells.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.sparse import csgraph

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.world import episodes as episodes_
from rosmeery_jax.world.episodes import Episode

TASK_METRICS = ("task_success", "task_spl", "task_softspl", "task_distance")
TASK_SET = "task"  # the name that selects them all
ATTEMPTS = 3


class TaskQuery(NamedTuple):
    """The task metrics a session scores (``names``, in the order of TASK_METRICS) against
    each world's generated set of ``episodes`` (seed 0), trying ``attempts`` instances."""

    names: tuple[str, ...]
    episodes: int = episodes_.DEFAULT_EPISODES
    attempts: int = ATTEMPTS

    def scorer(self, world) -> "TaskScorer":
        return TaskScorer(world, episodes_.generated(world, self.episodes), self.attempts)


class TaskResult(NamedTuple):
    """Per episode (E,): success (bool), path length l (m), geodesic distance l* (m),
    distance to goal at the stop d_T (m), instance stopped at (-1: none), stop cell (E, 2)
    row, col; ``values``: the metrics' means."""

    success: np.ndarray
    path: np.ndarray
    shortest: np.ndarray
    distance: np.ndarray
    instance: np.ndarray
    stop: np.ndarray
    values: dict


def wanted(names) -> tuple[str, ...]:
    """The task metrics among ``names``, in the order of TASK_METRICS."""
    return tuple(n for n in TASK_METRICS if n in names)


def check_attempts(attempts, source, where: str = "task_attempts") -> int:
    """``attempts`` if it is a whole number in [1, 100], else one InputError naming ``where``."""
    if isinstance(attempts, bool) or not isinstance(attempts, int) or not 1 <= attempts <= 100:
        raise InputError(source, where, f"{attempts!r} must be a whole number of instances in [1, 100]")
    return attempts


def score(world, eps: list[Episode], points: np.ndarray, instance: np.ndarray, labels: dict,
          attempts: int = ATTEMPTS) -> TaskResult:
    """The map (points (P, 3), instance (P,), labels {instance id: category or None}) put to
    the episodes ``eps`` of ``world`` (module docstring)."""
    return TaskScorer(world, eps, attempts).score(points, instance, labels)


class TaskScorer:
    """Scores one robot's maps against one set of episodes as they grow: ``score(points,
    instance, labels) -> TaskResult``, the same result whatever maps came before.

    Kept between maps: the distance fields from the starts and each map cell's nearest
    approach node from every start (:class:`_FromStarts`, shared by the scorers of one
    world and set of starts); the cells of the points already seen and the (instance, cell)
    pairs they make; each instance's nearest approach node from every start (updated by new
    pairs only, ties to the smallest node, so the order of growth does not matter); the
    distance fields from the latest stops (``KEEP_FIELDS``). Old points given other
    instance ids (instances merged) regroup the pairs; any other change starts afresh."""

    KEEP_FIELDS = 64

    def __init__(self, world, eps: list[Episode], attempts: int = ATTEMPTS):
        self.reg, self.attempts = episodes_.regions(world), attempts
        fs, g = world.free_space, self.reg.graph
        self.goals = sorted({e.goal for e in eps})
        self.goal = np.array([self.goals.index(e.goal) for e in eps], np.int64)  # (E,)
        starts = np.array([fs.cell(e.start[:2]) for e in eps], np.int64).reshape(-1, 2)
        self.start = g.index[starts[:, 0], starts[:, 1]]  # (E,) node
        self.width, self.n = fs.reachable.shape[1], fs.reachable.size
        self.region = np.stack([self.reg.region[c].ravel() for c in self.goals])  # (G, H W)
        self.to_goal = np.stack([self.reg.distance[c].ravel() for c in self.goals])
        self.shortest = self.to_goal[self.goal, self._flat(self.start)]
        self.from_starts = _from_starts(self.reg, self.start)
        self.fields: dict[int, np.ndarray] = {}  # node -> (V,) metres from it
        self._clear()

    def _clear(self) -> None:
        e = len(self.goal)
        self.points, self.instance, self.cells = np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
        self.keys = np.zeros(0, np.int64)  # sorted instance * n + cell of the pairs
        self.best = np.zeros((0, e)), np.zeros((0, e), np.int64)  # per instance id: (I, E) metres, node
        self.last = None

    def _flat(self, nodes: np.ndarray) -> np.ndarray:
        i, j = self.reg.graph.cells[nodes].T
        return i * self.width + j

    def score(self, points: np.ndarray, instance: np.ndarray, labels: dict) -> TaskResult:
        """The map: points (P, 3), instance (P,) ids, labels {instance id: category or None}."""
        points, instance = np.asarray(points, np.float64).reshape(-1, 3), np.asarray(instance, np.int64)
        old = len(self.points)
        if not (len(points) >= old and np.array_equal(points[:old], self.points)):
            self._clear()
            old = 0
        elif not np.array_equal(instance[:old], self.instance):
            self._regroup(instance[:old])
        elif len(points) == old and self.last is not None and self.last[0] == labels:
            return self.last[1]
        cells = self.reg.approach.cells(points[old:, :2])
        self.points, self.instance, self.cells = points, instance.copy(), np.r_[self.cells, cells]
        self._add(instance[old:], cells)
        result = self._search(labels)
        self.last = (dict(labels), result)
        return result

    def _regroup(self, instance: np.ndarray) -> None:
        cells = self.cells
        self._clear()
        self.cells = np.zeros(0, np.int64)
        self._add(instance, cells)
        self.cells = cells

    def _add(self, instance: np.ndarray, cells: np.ndarray) -> None:
        """New (instance, cell) pairs: each instance's nearest approach node from each start."""
        on = cells >= 0
        new = np.unique(instance[on] * self.n + cells[on])
        at = np.searchsorted(self.keys, new)
        if len(self.keys):
            fresh = self.keys[np.minimum(at, len(self.keys) - 1)] != new
            new, at = new[fresh], at[fresh]
        if not len(new):
            return
        self.keys = np.insert(self.keys, at, new)  # sorted still
        owner, first = np.unique(new // self.n, return_index=True)
        low, node = _instance_min(*self.from_starts.nearest(new % self.n), first)  # (U, E)
        dist, at = self.best
        if owner[-1] >= len(dist):
            grow = owner[-1] + 1 - len(dist)
            dist, at = np.r_[dist, np.full((grow, dist.shape[1]), np.inf)], np.r_[at, np.full((grow, at.shape[1]), -1)]
        better = (low < dist[owner]) | ((low == dist[owner]) & (node < at[owner]))
        dist[owner], at[owner] = np.where(better, low, dist[owner]), np.where(better, node, at[owner])
        self.best = dist, at

    def _search(self, labels: dict) -> TaskResult:
        """Every episode's search (module docstring) among the instances labelled with a goal."""
        owner = np.unique(self.keys // self.n)
        owner = np.array([i for i in owner.tolist() if labels.get(i) in self.goals], np.int64)  # (U,)
        label = np.array([self.goals.index(labels[i]) for i in owner.tolist()], np.int64)
        e = len(self.goal)
        here, path = self.start.copy(), np.zeros(e)
        done, go = np.zeros(e, bool), np.zeros(e, bool)
        tried = np.zeros((len(owner), e), bool)
        last = np.full(e, -1)
        want = label[:, None] == self.goal[None, :]  # (U, E)
        for attempt in range(self.attempts if len(owner) else 0):
            if attempt == 0:
                dist, node = self.best[0][owner], self.best[1][owner]  # (U, E) each
            else:
                dist, node = self._from_stops(here, owner, ~done & go)
            cost = np.where(want & ~tried & ~done[None, :], dist, np.inf)
            pick = np.argmin(cost, 0)
            go = np.isfinite(cost[pick, np.arange(e)])
            path[go] += cost[pick[go], np.flatnonzero(go)]
            here = np.where(go, node[pick, np.arange(e)], here)
            tried[pick[go], np.flatnonzero(go)] = True
            last = np.where(go, pick, last)
            done |= go & self.region[self.goal, self._flat(here)]
            if not (~done & go).any():
                break
        to_goal = self.to_goal[self.goal, self._flat(here)]
        efficiency = self.shortest / np.maximum(np.maximum(path, self.shortest), 1e-12)
        progress = np.clip(1 - to_goal / np.maximum(self.shortest, 1e-12), 0, 1)
        values = {"task_success": float(done.mean()), "task_spl": float(np.mean(done * efficiency)),
                  "task_softspl": float(np.mean(progress * efficiency)), "task_distance": float(to_goal.mean())}
        chosen = owner[np.maximum(last, 0)] if len(owner) else np.zeros(e, np.int64)
        return TaskResult(done, path, self.shortest, to_goal, np.where(last >= 0, chosen, -1),
                          self.reg.graph.cells[here], values)

    def _from_stops(self, here: np.ndarray, owner: np.ndarray, active: np.ndarray):
        """(U, E) metres from where the ``active`` episodes stopped to each instance of
        ``owner``'s approach region and the node reached first (inf for the others)."""
        e = len(here)
        dist, node = np.full((len(owner), e), np.inf), np.zeros((len(owner), e), np.int64)
        if not active.any():
            return dist, node
        keys = self.keys[np.isin(self.keys // self.n, owner)]
        first = np.searchsorted(keys // self.n, owner)
        stops, row = np.unique(here[active], return_inverse=True)
        missing = np.array([n for n in stops.tolist() if n not in self.fields], np.int64)
        self.fields.update(zip(missing.tolist(), _fields(self.reg.graph, missing)))
        fields = np.stack([self.fields[n] for n in stops.tolist()], 1)  # (V, F)
        d, n = _instance_min(*self.reg.approach.nearest(fields, keys % self.n), first)  # (U, F)
        dist[:, active], node[:, active] = d[:, row], n[:, row]
        while len(self.fields) > self.KEEP_FIELDS:  # the oldest first (dicts keep their order)
            self.fields.pop(next(iter(self.fields)))
        return dist, node


class _FromStarts:
    """A world's distance fields from a set of start nodes (V, E) and, per map cell, the
    nearest of its approach nodes from each start, kept as cells are asked for."""

    def __init__(self, reg, start: np.ndarray):
        self.approach = reg.approach
        self.fields = np.ascontiguousarray(_fields(reg.graph, start).T)  # (V, E)
        self.slot = np.full(len(reg.approach.slot), -1, np.int64)
        self.dist, self.node = np.zeros((0, len(start))), np.zeros((0, len(start)), np.int64)

    def nearest(self, cells: np.ndarray):
        """(Q, E) metres and node from each start to each of ``cells``' approach regions."""
        new = np.unique(cells[self.slot[cells] < 0])
        if len(new):
            d, n = self.approach.nearest(self.fields, new)
            self.slot[new] = len(self.dist) + np.arange(len(new))
            self.dist, self.node = np.r_[self.dist, d], np.r_[self.node, n]
        s = self.slot[cells]
        return self.dist[s], self.node[s]


_STARTS: dict = {}  # (regions, start nodes) -> _FromStarts, the latest few


def _from_starts(reg, start: np.ndarray) -> _FromStarts:
    key = (id(reg), start.tobytes())
    if key not in _STARTS:
        _STARTS[key] = _FromStarts(reg, start)
        while len(_STARTS) > 8:
            _STARTS.pop(next(iter(_STARTS)))
    return _STARTS[key]


def _fields(g, nodes: np.ndarray) -> np.ndarray:
    """(F, V) geodesic metres from each of ``nodes`` (F,) to every node."""
    if not len(nodes):
        return np.zeros((0, len(g.cells)))
    return csgraph.dijkstra(g.matrix, directed=False, indices=nodes)


def _instance_min(dist: np.ndarray, node: np.ndarray, first: np.ndarray):
    """(U, F) from per-cell (Q, F) metres and nodes, cells grouped by instance (instance k's
    from ``first[k]``): each instance's least and its node (the smallest of ties)."""
    if not len(first):
        return np.zeros((0, dist.shape[1])), np.zeros((0, dist.shape[1]), np.int64)
    low = np.minimum.reduceat(dist, first, axis=0)  # (U, F)
    seg = np.repeat(np.arange(len(first)), np.diff(np.r_[first, len(dist)]))
    tied = np.where(dist == low[seg], node, np.iinfo(np.int64).max)
    return low, np.where(np.isfinite(low), np.minimum.reduceat(tied, first, axis=0), -1)
