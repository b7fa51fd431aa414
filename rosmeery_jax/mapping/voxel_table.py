"""Points keyed by the cube they fall in, for the perceived mapper
(:mod:`rosmeery_jax.mapping.perceived`): cube keys, a buffer that grows at its end, a table
of keys to instances looked up many at once, and the first claim on each key.

A frame looks up thousands of keys at once, so the table answers them in one vectorised
search over sorted arrays rather than key by key. Shapes: K keys, n rows."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from rosmeery_jax.mapping.kernels import group_ids


def cube_keys(xyz: tuple, size: float) -> np.ndarray:
    """Cube keys of points (x, y, z arrays): 21 bits per axis (a 100 km cube at 5 cm)."""
    kind = np.result_type(*xyz, np.float32)  # the division in the points' own precision, as numpy divides
    x, y, z = (np.ascontiguousarray(a, kind) for a in np.broadcast_arrays(*xyz))
    return _cube_keys(x.ravel(), y.ravel(), z.ravel(), kind.type(size)).reshape(x.shape)


@njit(cache=True)
def _cube_keys(x, y, z, size):
    out = np.empty(len(x), np.int64)
    for i in range(len(x)):
        out[i] = ((np.int64(np.floor(x[i] / size)) + (1 << 20)) << 42) | \
                 ((np.int64(np.floor(y[i] / size)) + (1 << 20)) << 21) | (np.int64(np.floor(z[i] / size)) + (1 << 20))
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


class KeyTable:
    """Cube keys to instances, looked up many keys at once. Keys are held in two sorted
    arrays, each searched in one vectorised call: most in the main one, the latest in a
    small one, merged into the main one once they are many (so an add costs a copy of the
    small one, not of the whole table). Most keys a frame looks up are in no table (walls
    and furniture no detection named): a bitmap of the keys' hashes (256 KiB) answers those
    at once."""

    _BITS = 18

    def __init__(self):
        self._main, self._latest = _Sorted.empty(), _Sorted.empty()
        self._seen = np.zeros(1 << self._BITS, bool)

    def __len__(self) -> int:
        return len(self._main.keys) + len(self._latest.keys)

    def _hash(self, keys: np.ndarray) -> np.ndarray:
        return (keys.view(np.uint64) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - self._BITS)  # Fibonacci hashing

    def get(self, keys: np.ndarray) -> np.ndarray:
        """(K,) the instances the table holds for int64 ``keys`` (K,), -1 where it holds none."""
        out = np.full(len(keys), -1, np.int64)
        maybe = np.flatnonzero(self._seen[self._hash(keys)])
        for held, insts in (self._main, self._latest):  # each _Sorted: keys, their instances
            if len(held) and len(maybe):
                at = np.minimum(np.searchsorted(held, keys[maybe]), len(held) - 1)
                found = held[at] == keys[maybe]
                out[maybe[found]] = insts[at[found]]
                maybe = maybe[~found]
        return out

    def add(self, keys: np.ndarray, insts: np.ndarray) -> None:
        """Record instances ``insts`` (K,) for distinct int64 ``keys`` (K,), none of them in the table yet."""
        self._seen[self._hash(keys)] = True
        self._latest = self._latest.insert(keys, insts)
        if len(self._latest.keys) > max(1024, len(self._main.keys) // 16):
            self._main, self._latest = self._main.insert(*self._latest), _Sorted.empty()


class _Sorted(NamedTuple):
    """Keys (K,) ascending and their instances (K,)."""

    keys: np.ndarray
    insts: np.ndarray

    @classmethod
    def empty(cls) -> "_Sorted":
        return cls(np.zeros(0, np.int64), np.zeros(0, np.int64))

    def insert(self, keys: np.ndarray, insts: np.ndarray) -> "_Sorted":
        """These with ``keys`` (K,), none of them held yet, and their ``insts`` (K,) added."""
        order = np.argsort(keys)
        at = np.searchsorted(self.keys, keys[order])
        return _Sorted(np.insert(self.keys, at, keys[order]), np.insert(self.insts, at, insts[order]))


def first_claims(keys: np.ndarray, rank: np.ndarray) -> np.ndarray:
    """Of entries with keys (K,) and ranks (K,), the first of the lowest rank for each key:
    their indices, ordered by rank, then key. One pass over a hash table of the keys, then a
    sort of the claims alone (most entries repeat a key)."""
    if not len(keys):
        return np.zeros(0, np.int64)
    keys, rank = np.ascontiguousarray(keys, np.int64), np.ascontiguousarray(rank, np.int64)
    first = _first_claims(keys, rank)
    return first[np.lexsort((keys[first], rank[first]))]


@njit(cache=True)
def _first_claims(keys, rank):
    group, count = group_ids(keys)
    best = np.full(count, -1, np.int64)
    for i in range(len(keys)):
        g = group[i]
        if best[g] < 0 or rank[i] < rank[best[g]]:  # a lower rank claims it; of equal ranks the first stays
            best[g] = i
    return best
