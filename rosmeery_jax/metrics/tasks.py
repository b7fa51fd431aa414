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
    reg = episodes_.regions(world)
    g, fs = reg.graph, world.free_space
    goals = [e.goal for e in eps]
    starts = np.array([fs.cell(e.start[:2]) for e in eps], np.int64).reshape(-1, 2)
    ids = [i for i in np.unique(instance).tolist() if labels.get(i) in set(goals)]
    dist, source, label = _approaches(world, g, points, instance, ids, labels)  # (U, V), (U, V), (U,)
    e = len(eps)
    here = g.index[starts[:, 0], starts[:, 1]]  # (E,) node
    path = np.zeros(e)
    done = np.zeros(e, bool)
    tried = np.zeros((len(ids), e), bool)
    last = np.full(e, -1)
    want = label[:, None] == np.array(goals, object)[None, :]  # (U, E)
    for _ in range(attempts if ids else 0):  # no instance labelled with a goal: every robot stays put
        cost = np.where(want & ~tried & ~done[None, :], dist[:, here], np.inf)  # (U, E)
        pick = np.argmin(cost, 0)
        go = np.isfinite(cost[pick, np.arange(e)])
        path[go] += cost[pick[go], np.flatnonzero(go)]
        here = np.where(go, source[pick, here], here)
        tried[pick[go], np.flatnonzero(go)] = True
        last = np.where(go, pick, last)
        done |= go & _at(reg.region, goals, g.cells[here])
    cell = g.cells[here]
    shortest, to_goal = _at(reg.distance, goals, starts), _at(reg.distance, goals, cell)
    success = done
    efficiency = shortest / np.maximum(np.maximum(path, shortest), 1e-12)
    values = {"task_success": float(success.mean()), "task_spl": float(np.mean(success * efficiency)),
              "task_softspl": float(np.mean(np.clip(1 - to_goal / np.maximum(shortest, 1e-12), 0, 1) * efficiency)),
              "task_distance": float(to_goal.mean())}
    chosen = np.array([ids[k] if k >= 0 else -1 for k in last], np.int64)
    return TaskResult(success, path, shortest, to_goal, chosen, cell, values)


def _at(per_goal: dict, goals: list[str], cells: np.ndarray) -> np.ndarray:
    """(E,) each episode's value of its goal's map (H, W) at its cell (E, 2)."""
    return np.array([per_goal[goal][i, j] for goal, (i, j) in zip(goals, cells)])


def _approaches(world, g, points: np.ndarray, instance: np.ndarray, ids: list, labels: dict):
    """Per instance of ``ids``: the geodesic distance (V,) from every cell to its approach
    region and the region's cell each cell reaches first (V,), and its label (U,)."""
    v = len(g.cells)
    dist = np.full((len(ids), v), np.inf)
    source = np.tile(np.arange(v), (len(ids), 1))
    for k, i in enumerate(ids):
        region = episodes_.approach_region(world, points[instance == i, :2])
        nodes = g.index[region]
        nodes = nodes[nodes >= 0]
        if not len(nodes):
            continue
        d, _, src = csgraph.dijkstra(g.matrix, directed=False, indices=nodes, min_only=True,
                                     return_predecessors=True)
        dist[k] = d
        source[k] = np.where(src >= 0, src, np.arange(v))
    return dist, source, np.array([labels.get(i) for i in ids], object)
