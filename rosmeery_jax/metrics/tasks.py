"""Map-use metrics (docs/tasks.md): how well a semantic map serves object-goal navigation.

For each episode (:mod:`rosmeery_jax.world.episodes`: a start, a goal category) the map
answers the query as a robot using it would: from the start it drives to the nearest (by
geodesic distance from where it stands) of the map's instances labelled with the goal
category, and stops at the first node of that instance's approach region it reaches (the
approach nodes of the cells its points lie in: :mod:`rosmeery_jax.world.approach`, the
rule of the true success regions). If the stop lies in a true success region of the goal
category, the episode succeeds; else the robot tries the nearest instance from there not
yet tried, at most ``attempts`` instances in all (the path accumulates). Path lengths are
geodesic on the true free space at the robot's radius.

Per episode, with l* its geodesic distance from the start to the goal's success region, l
the path driven and d_T the geodesic distance from the stop to that region:

- ``task_success`` S: 1 if it stopped in a success region, else 0;
- ``task_spl``: S l* / max(l, l*) (Anderson et al. 2018);
- ``task_softspl``: (1 - d_T / l*) l* / max(l, l*), the progress made (Datta et al. 2021);
- ``task_distance``: d_T in metres (Habitat's distance to goal).

Each metric is the mean over the episodes. An episode whose goal the map never labels,
or whose instances cannot be reached, stops at its start (S 0, distance l*). Every
episode advances together: each attempt is an arg-min over instances for all episodes;
the distances from the starts are kept per instance as the map grows (:class:`TaskScorer`),
those from later stops come from one SciPy Dijkstra per distinct stop.

Shapes: E episodes, U instances labelled with a goal, V free-space cells (graph nodes), F
fields.
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

    Kept between maps: the distance fields from the starts (shared by the scorers of one
    world and set of starts); the cells of the points already seen and the (instance, cell)
    pairs they make; each instance's approach nodes (V,) and its nearest one from every
    start, updated by the nodes its new cells add (ties to the smallest node, so the order
    of growth does not matter); the distance fields from the latest stops
    (``KEEP_FIELDS``). Old points given other instance ids (instances merged) regroup the
    pairs; any other change starts afresh."""

    KEEP_FIELDS = 64

    def __init__(self, world, eps: list[Episode], attempts: int = ATTEMPTS):
        self.reg, self.attempts = episodes_.regions(world), attempts
        self.episodes = list(eps)
        fs, g = world.free_space, self.reg.graph
        self.goals = sorted({e.goal for e in eps})
        self.goal = np.array([self.goals.index(e.goal) for e in eps], np.int64)  # (E,)
        starts = np.array([fs.cell(e.start[:2]) for e in eps], np.int64).reshape(-1, 2)
        self.start = g.index[starts[:, 0], starts[:, 1]]  # (E,) node
        self.width, self.n = fs.reachable.shape[1], fs.reachable.size
        self.region = np.stack([self.reg.region[c].ravel() for c in self.goals])  # (G, H W)
        self.to_goal = np.stack([self.reg.distance[c].ravel() for c in self.goals])
        self.shortest = self.to_goal[self.goal, self._flat(self.start)]
        self.from_starts = _from_starts(self.reg, self.start)  # (V, E)
        self.fields: dict[int, np.ndarray] = {}  # node -> (V,) metres from it
        self._clear()

    def _clear(self) -> None:
        self.points, self.instance, self.cells = np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
        self.keys = np.zeros(0, np.int64)  # sorted instance * n + cell of the pairs
        self.reach: dict[int, np.ndarray] = {}  # instance -> (V,) bool, its approach nodes
        self.best: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # instance -> (E,) metres, (E,) node from the starts
        self.last = None

    def _flat(self, nodes: np.ndarray) -> np.ndarray:
        i, j = self.reg.graph.cells[nodes].T
        return i * self.width + j

    def score(self, points: np.ndarray, instance: np.ndarray, labels: dict) -> TaskResult:
        """The map: points (P, 3), instance (P,) ids, labels {instance id: category or None}."""
        points, instance = np.asarray(points).reshape(-1, 3), np.asarray(instance, np.int64)
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

    def route(self, points: np.ndarray, instance: np.ndarray, labels: dict) -> tuple[np.ndarray, np.ndarray]:
        """The instances each episode would try, in order, whatever it finds at each: (E, A)
        instance ids (-1: none left) and (E, A, 2) row, col of the approach node it would
        stop at (the plan of an executed task: docs/tasks.md)."""
        self.score(points, instance, labels)
        return self._search(labels, chain=True)

    def _regroup(self, instance: np.ndarray) -> None:
        cells = self.cells
        self._clear()
        self._add(instance, cells)
        self.cells = cells

    def _add(self, instance: np.ndarray, cells: np.ndarray) -> None:
        """New (instance, cell) pairs: the approach nodes they add to their instances, and
        each instance's nearest approach node from each start."""
        on = cells >= 0
        new = np.unique(instance[on] * self.n + cells[on])
        at = np.searchsorted(self.keys, new)
        if len(self.keys):
            fresh = self.keys[np.minimum(at, len(self.keys) - 1)] != new
            new, at = new[fresh], at[fresh]
        self.keys = np.insert(self.keys, at, new)  # sorted still
        owner, first = np.unique(new // self.n, return_index=True)
        for i, cells_i in zip(owner.tolist(), np.split(new % self.n, first[1:])):
            mask = self.reach.setdefault(i, np.zeros(len(self.from_starts), bool))
            nodes = self.reg.approach.gather(cells_i)
            nodes = np.unique(nodes[~mask[nodes]])  # most are known already
            if not len(nodes):
                continue
            mask[nodes] = True
            low, node = _nearest(self.from_starts, nodes)  # (E,) each
            if i in self.best:
                dist, at_node = self.best[i]
                better = (low < dist) | ((low == dist) & (node < at_node))
                low, node = np.where(better, low, dist), np.where(better, node, at_node)
            self.best[i] = low, node

    def _search(self, labels: dict, chain: bool = False):
        """Every episode's search (module docstring) among the instances labelled with a
        goal; with ``chain``, the whole sequence of attempts whatever each finds, as
        :meth:`route` returns it."""
        owner = np.array(sorted(i for i in self.best if labels.get(i) in self.goals), np.int64)  # (U,)
        label = np.array([self.goals.index(labels[i]) for i in owner.tolist()], np.int64)
        e = len(self.goal)
        here, path = self.start.copy(), np.zeros(e)
        done, go = np.zeros(e, bool), np.zeros(e, bool)
        tried = np.zeros((len(owner), e), bool)
        last = np.full(e, -1)
        want = label[:, None] == self.goal[None, :]  # (U, E)
        picks, stops = np.full((e, self.attempts), -1), np.zeros((e, self.attempts, 2), np.int64)
        for attempt in range(self.attempts if len(owner) else 0):
            if attempt == 0:
                dist = np.stack([self.best[i][0] for i in owner.tolist()])  # (U, E)
                node = np.stack([self.best[i][1] for i in owner.tolist()])
            else:
                dist, node = self._from_stops(here, owner, want & ~tried & (~done & go)[None, :])
            cost = np.where(want & ~tried & ~done[None, :], dist, np.inf)
            pick = np.argmin(cost, 0)
            go = np.isfinite(cost[pick, np.arange(e)])
            path[go] += cost[pick[go], np.flatnonzero(go)]
            here = np.where(go, node[pick, np.arange(e)], here)
            tried[pick[go], np.flatnonzero(go)] = True
            last = np.where(go, pick, last)
            picks[go, attempt], stops[go, attempt] = owner[pick[go]], self.reg.graph.cells[here[go]]
            if not chain:
                done |= go & self.region[self.goal, self._flat(here)]
            if not (~done & go).any():
                break
        if chain:
            return picks, stops
        to_goal = self.to_goal[self.goal, self._flat(here)]
        efficiency = self.shortest / np.maximum(np.maximum(path, self.shortest), 1e-12)
        progress = np.clip(1 - to_goal / np.maximum(self.shortest, 1e-12), 0, 1)
        values = {"task_success": float(done.mean()), "task_spl": float(np.mean(done * efficiency)),
                  "task_softspl": float(np.mean(progress * efficiency)), "task_distance": float(to_goal.mean())}
        chosen = owner[np.maximum(last, 0)] if len(owner) else np.zeros(e, np.int64)
        return TaskResult(done, path, self.shortest, to_goal, np.where(last >= 0, chosen, -1),
                          self.reg.graph.cells[here], values)

    def _from_stops(self, here: np.ndarray, owner: np.ndarray, open_: np.ndarray):
        """(U, E) metres from where each episode stopped to each instance of ``owner`` it may
        still try (``open_`` (U, E)), and the approach node reached first (inf elsewhere)."""
        e = len(here)
        dist, node = np.full((len(owner), e), np.inf), np.zeros((len(owner), e), np.int64)
        active = open_.any(0)
        if not active.any():
            return dist, node
        stops, row = np.unique(here[active], return_inverse=True)
        missing = np.array([n for n in stops.tolist() if n not in self.fields], np.int64)
        self.fields.update(zip(missing.tolist(), _fields(self.reg.graph, missing)))
        fields = np.stack([self.fields[n] for n in stops.tolist()], 1)  # (V, F)
        for k in np.flatnonzero(open_.any(1)):
            d, n = _nearest(fields, np.flatnonzero(self.reach[int(owner[k])]))  # (F,)
            dist[k, active], node[k, active] = d[row], n[row]
        while len(self.fields) > self.KEEP_FIELDS:  # the oldest first (dicts keep their order)
            self.fields.pop(next(iter(self.fields)))
        return dist, node


def _nearest(fields: np.ndarray, nodes: np.ndarray):
    """(F,) each field's (columns of ``fields`` (V, F)) least value over ``nodes`` (M,),
    sorted ascending, and the node holding it (the smallest of ties: argmin's first)."""
    values = fields[nodes]
    at = np.argmin(values, 0)
    return values[at, np.arange(values.shape[1])], nodes[at]


_STARTS: dict = {}  # (regions, start nodes) -> (V, E) distance fields, the latest few


def _from_starts(reg, start: np.ndarray) -> np.ndarray:
    key = (id(reg), start.tobytes())
    if key not in _STARTS:
        _STARTS[key] = np.ascontiguousarray(_fields(reg.graph, start).T)
        while len(_STARTS) > 8:
            _STARTS.pop(next(iter(_STARTS)))
    return _STARTS[key]


def _fields(g, nodes: np.ndarray) -> np.ndarray:
    """(F, V) geodesic metres from each of ``nodes`` (F,) to every node."""
    if not len(nodes):
        return np.zeros((0, len(g.cells)))
    return csgraph.dijkstra(g.matrix, directed=False, indices=nodes)
