"""Points keyed by the cube they fall in, for the perceived mapper
(:mod:`rosmeery_jax.mapping.perceived`): cube keys, a buffer that grows at its end, and the
first claim on each key (the table of keys to instances is
:class:`rosmeery_jax.mapping.kernels.HashTable`). Shapes: K keys, n rows."""

from __future__ import annotations

import numpy as np
from numba import njit

from rosmeery_jax.mapping.kernels import group_ids


def cube_keys(xyz: tuple, size: float) -> np.ndarray:
    """Cube keys of points (x, y, z arrays): 21 bits per axis (a 100 km cube at 5 cm)."""
    kind = np.result_type(*xyz, np.float32)  # the division in the points' own precision, as numpy divides
    x, y, z = (np.ascontiguousarray(a, kind) for a in np.broadcast_arrays(*xyz))
    return _cube_keys(x.ravel(), y.ravel(), z.ravel(), kind.type(size)).reshape(x.shape)


@njit(cache=True, nogil=True)
def cube_key(x, y, z, size):
    """The cube key of one point, for compiled code (:func:`cube_keys`' arithmetic)."""
    return ((np.int64(np.floor(x / size)) + (1 << 20)) << 42) | \
        ((np.int64(np.floor(y / size)) + (1 << 20)) << 21) | (np.int64(np.floor(z / size)) + (1 << 20))


@njit(cache=True, nogil=True)
def _cube_keys(x, y, z, size):
    out = np.empty(len(x), np.int64)
    for i in range(len(x)):
        out[i] = cube_key(x[i], y[i], z[i], size)
    return out


# key offsets of a cube and its 26 neighbours (the bit layout of cube_keys)
NEIGHBOURS = np.array([(dx << 42) + (dy << 21) + dz for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)],
                      np.int64)


class Rows:
    """An array that only grows at its end, (n, *shape): appended in amortised constant time
    per row (the capacity doubles); ``rows`` is a view of the first n rows, which later
    appends never change."""

    def __init__(self, shape: tuple, dtype):
        self._buf, self._n = np.zeros((16, *shape), dtype), 0

    @classmethod
    def of(cls, rows: np.ndarray) -> "Rows":
        """A new buffer holding a copy of ``rows`` (n, *shape)."""
        out = cls(rows.shape[1:], rows.dtype)
        out.append(rows)
        return out

    def append(self, rows: np.ndarray) -> None:
        n = self._n + len(rows)
        if n > len(self._buf):
            buf = np.zeros((max(n, 2 * len(self._buf)), *self._buf.shape[1:]), self._buf.dtype)
            buf[:self._n] = self._buf[:self._n]
            self._buf = buf
        self._buf[self._n:n] = rows
        self._n = n

    @property
    def rows(self) -> np.ndarray:
        return self._buf[:self._n]


@njit(cache=True, nogil=True)
def first_of_lowest_rank(keys, rank):
    """Of entries with int64 keys (K,) and ranks (K,), the first of the lowest rank for each
    distinct key: their indices, one per key (in no set order). One pass over a hash table."""
    group, count = group_ids(keys)
    best = np.full(count, -1, np.int64)
    for i in range(len(keys)):
        g = group[i]
        if best[g] < 0 or rank[i] < rank[best[g]]:  # a lower rank claims it; of equal ranks the first stays
            best[g] = i
    return best
