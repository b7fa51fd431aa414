"""Where a robot can stand to find an object: the **approach nodes** of a floor cell are the
reachable cells (the robot's centre, :mod:`rosmeery_jax.world.geodesic`'s nodes) whose
centre lies within ``SUCCESS_DISTANCE`` (1.0 m, Habitat's ObjectNav radius) of that cell's
centre, with no wall cell strictly between them (furniture does not block the sight: the
camera sees over most of it; the target cell itself may be a wall's, as a picture on it).

A success region (:mod:`rosmeery_jax.world.episodes`) is the union of the approach nodes of
a category's surface-sample cells; a map instance's approach region is the union of those
of the cells its points lie in. One rule for both, so the built-in knowledge's instance of
an object approaches only cells of that object's true success region.

The sight lines are laid out once per grid as cell offsets; a cell's nodes are computed
when first asked for and kept (:class:`Approach`). Shapes: C cells, K offsets within the
radius, L cells on a sight line, M nodes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from rosmeery_jax.world import geodesic

SUCCESS_DISTANCE = 1.0  # m: Habitat ObjectNav's success radius
CHUNK = 1024  # cells laid out at once ((C, K) nodes)


def _lines(r: int, radius: float):
    """Offsets (K, 2) within ``radius`` cells of a cell; per offset the distinct cells a
    straight line from the target's centre to the offset cell's centre crosses strictly
    between the two, (K, L, 2) padded with the offset itself (reachable, so never a wall),
    and how many there are (K,)."""
    di, dj = np.mgrid[-r:r + 1, -r:r + 1]
    offsets = np.stack([di.ravel(), dj.ravel()], -1)
    offsets = offsets[np.hypot(*offsets.T) <= radius + 1e-9]
    lam = np.linspace(0.0, 1.0, 4 * r + 1)[1:-1]  # a quarter cell apart: no crossed cell missed
    lines = []
    for o in offsets:
        along = np.floor(0.5 + lam[:, None] * o[None, :]).astype(np.int64)
        keep = ~((along == 0).all(-1) | (along == o).all(-1))
        lines.append(np.unique(along[keep], axis=0))
    count = np.array([len(x) for x in lines], np.int64)
    out = np.repeat(offsets[:, None, :], max(int(count.max()), 1), axis=1)
    for k, x in enumerate(lines):
        out[k, :len(x)] = x
    return offsets, out, count


@njit(cache=True, nogil=True)
def _approach_nodes(walls, index, targets, offsets, lines, count):  # pragma: no cover - compiled
    """(C, K) the node of each target's offset cell where it is reachable and no wall lies on
    the line between (else -1): targets (C, 2) rows and columns in the padded grid."""
    out = np.full((targets.shape[0], offsets.shape[0]), -1, np.int64)
    for c in range(targets.shape[0]):
        ti, tj = targets[c, 0], targets[c, 1]
        for k in range(offsets.shape[0]):
            node = index[ti + offsets[k, 0], tj + offsets[k, 1]]
            if node < 0:
                continue
            clear = True
            for m in range(count[k]):
                if walls[ti + lines[k, m, 0], tj + lines[k, m, 1]]:
                    clear = False
                    break
            if clear:
                out[c, k] = node
    return out


class Approach:
    """The approach nodes of a grid's cells (module docstring), kept per cell once asked for.

    ``walls`` (H, W) bool blocks sight; ``graph`` the reachable cells' graph; ``origin``
    (2,) the grid's lower-left corner."""

    def __init__(self, walls: np.ndarray, graph: geodesic.Graph, origin: np.ndarray):
        self.shape, self.graph, self.origin = walls.shape, graph, np.asarray(origin, np.float64)
        self.r = int(math.floor(SUCCESS_DISTANCE / graph.resolution + 1e-9))
        self.offsets, self.lines, self.count = _lines(self.r, SUCCESS_DISTANCE / graph.resolution)
        p = self.r + 1  # a border: no bounds checks
        self.walls = np.pad(np.asarray(walls, bool), p)
        self.index = np.pad(np.asarray(graph.index, np.int64), p, constant_values=-1)
        self.pad = p
        # the nodes kept: cell c's are flat[start[slot[c]] : ... + length[slot[c]]]; the
        # arrays grow by doubling, as a map's cells arrive a few at a time (a copy of every
        # node kept at each arrival cost a session most of the task metrics' time)
        self.slot = np.full(walls.size, -1, np.int64)
        self._start, self._length, self._flat = (np.zeros(0, np.int64) for _ in range(3))
        self.cells_kept, self.nodes_kept = 0, 0

    @property
    def start(self) -> np.ndarray:
        return self._start[:self.cells_kept]

    @property
    def length(self) -> np.ndarray:
        return self._length[:self.cells_kept]

    @property
    def flat(self) -> np.ndarray:
        return self._flat[:self.nodes_kept]

    def cells(self, xy: np.ndarray) -> np.ndarray:
        """(P,) flat cell of each point ``xy`` (P, 2); -1 off the grid."""
        ji = np.floor((np.asarray(xy, np.float64).reshape(-1, 2) - self.origin)
                      / self.graph.resolution).astype(np.int64)
        j, i = ji[:, 0], ji[:, 1]
        inside = (i >= 0) & (i < self.shape[0]) & (j >= 0) & (j < self.shape[1])
        return np.where(inside, i * self.shape[1] + j, -1)

    def slots(self, cells: np.ndarray) -> np.ndarray:
        """(C,) where each flat cell's nodes are kept (laid out first if new)."""
        cells = np.asarray(cells, np.int64)
        new = np.unique(cells[self.slot[cells] < 0])
        for k in range(0, len(new), CHUNK):
            self._lay(new[k:k + CHUNK])
        return self.slot[cells]

    def gather(self, cells: np.ndarray) -> np.ndarray:
        """The approach nodes of each of ``cells`` (flat, -1 ignored) one after the other."""
        s = self.slots(cells[cells >= 0])
        n = self.length[s]
        at = np.repeat(self.start[s] - np.cumsum(n) + n, n) + np.arange(int(n.sum()))
        return self.flat[at]

    def union(self, cells: np.ndarray) -> np.ndarray:
        """The approach nodes of any of ``cells`` (flat, -1 ignored), sorted, each once."""
        return np.unique(self.gather(np.unique(cells)))

    def region(self, cells: np.ndarray) -> np.ndarray:
        """(H, W) bool: the union of the approach nodes of ``cells`` as grid cells."""
        out = np.zeros(self.shape, bool)
        i, j = self.graph.cells[self.union(cells)].T
        out[i, j] = True
        return out

    def _lay(self, cells: np.ndarray) -> None:
        i, j = np.divmod(cells, self.shape[1])
        targets = np.stack([i, j], -1) + self.pad
        found = _approach_nodes(self.walls, self.index, targets, self.offsets, self.lines, self.count)
        keep = found >= 0
        length = keep.sum(1)
        c, n = self.cells_kept, self.nodes_kept
        self._start, self._length = _room(self._start, c + len(cells)), _room(self._length, c + len(cells))
        self._flat = _room(self._flat, n + int(length.sum()))
        self.slot[cells] = c + np.arange(len(cells))
        self._start[c:c + len(cells)] = n + np.cumsum(length) - length
        self._length[c:c + len(cells)] = length
        self._flat[n:n + int(length.sum())] = found[keep]
        self.cells_kept, self.nodes_kept = c + len(cells), n + int(length.sum())


def _room(a: np.ndarray, size: int) -> np.ndarray:
    """``a``, or a copy twice as long, holding at least ``size`` entries."""
    if size <= len(a):
        return a
    grown = np.zeros(max(size, 2 * len(a)), a.dtype)
    grown[:len(a)] = a
    return grown
