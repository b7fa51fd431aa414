"""Geodesic distances on a world's true free space, at the robot's radius (the
``reachable`` cells of :class:`~rosmeery_jax.world.freespace.FreeSpace`).

The cells form a graph: each reachable cell joined to its 8 neighbours that are reachable
too, a side step costing one cell, a diagonal sqrt(2) (a diagonal only where both cells
beside it are reachable, so no path cuts a corner of an obstacle). Distances are SciPy's
compiled Dijkstra (``scipy.sparse.csgraph.dijkstra``) from one source or from many at once
(the distance to the nearest). An 8-connected grid overestimates a straight Euclidean
distance by at most 8 % (at 22.5 degrees off an axis), none along an axis or a diagonal.

Shapes: H x W cells, C source cells.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from rosmeery_jax.world.freespace import FreeSpace


class Graph(NamedTuple):
    """The reachable cells as a sparse graph: ``index`` (H, W) int64 node of each cell (-1
    unreachable), ``cells`` (V, 2) row, col of each node, ``matrix`` the edge lengths in
    metres, ``resolution`` metres per cell."""

    index: np.ndarray
    cells: np.ndarray
    matrix: sparse.csr_matrix
    resolution: float


STEPS = ((0, 1, 1.0), (1, 0, 1.0), (1, 1, math.sqrt(2)), (1, -1, math.sqrt(2)))  # each undirected edge once


def graph(fs: FreeSpace) -> Graph:
    """The reachable cells of ``fs`` and their 8-neighbour edges."""
    ok = np.pad(np.asarray(fs.reachable, bool), 1)  # a border of unreachable cells: no bounds checks
    index = np.full(ok.shape, -1, np.int64)
    cells = np.argwhere(ok)
    index[ok] = np.arange(len(cells))
    i, j = cells.T
    rows, cols, lengths = [], [], []
    for di, dj, length in STEPS:
        linked = ok[i + di, j + dj]
        if di and dj:  # a diagonal only past two reachable side cells: no corner cut
            linked &= ok[i + di, j] & ok[i, j + dj]
        rows.append(index[i, j][linked])
        cols.append(index[i + di, j + dj][linked])
        lengths.append(np.full(int(linked.sum()), length * fs.resolution))
    r, c, v = (np.concatenate(x) for x in (rows, cols, lengths))
    matrix = sparse.csr_matrix((v, (r, c)), shape=(len(cells), len(cells)))
    return Graph(index[1:-1, 1:-1], cells - 1, matrix, float(fs.resolution))


def field(g: Graph, sources: np.ndarray) -> np.ndarray:
    """(H, W) metres from the nearest of the ``sources`` (C, 2) row, col cells (unreachable
    ones ignored) along the graph; inf where no source reaches (and off the graph)."""
    nodes = g.index[sources[:, 0], sources[:, 1]] if len(sources) else np.zeros(0, np.int64)
    nodes = np.unique(nodes[nodes >= 0])
    out = np.full(g.index.shape, np.inf)
    if not len(nodes):
        return out
    d = csgraph.dijkstra(g.matrix, directed=False, indices=nodes, min_only=True)
    out[g.cells[:, 0], g.cells[:, 1]] = d
    return out
