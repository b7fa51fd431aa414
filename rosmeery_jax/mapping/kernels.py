"""Compiled kernels of the perceived mapper (numba): the loops numpy would run as many small
array operations. Each gives exactly what the numpy formulation it replaces gives (the
tests compare them), so the maps are bitwise those of before.

- :func:`label_segments`: a depth frame's 4-connected segments (rule 2), by union-find
  over the pixels, numbered in the order of their first pixel as ``scipy.ndimage.label``
  numbers them;
- :func:`back_project`: depth frames' pixels above the floor to world points (the
  arithmetic of the numpy expressions, in their order; the yaw's cosine and sine come from
  numpy, whose cos and sin may round otherwise than the C library's);
- :func:`within_boxes`: which points lie in their instances' grown boxes (rule 7);
- :class:`HashTable`: int64 keys to int64 values, open addressing with linear probing,
  for the mapper's voxel and cell tables (a sorted array grew by a copy per insert).
"""

from __future__ import annotations

import numpy as np
from numba import njit

EMPTY = np.iinfo(np.int64).min  # no key: cube keys are non-negative
_MIX = np.uint64(0x9E3779B97F4A7C15)  # Fibonacci hashing


@njit(cache=True)
def _find(parent, i):
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:  # path compression
        parent[i], i = root, parent[i]
    return root


@njit(cache=True)
def _union(parent, a, b):
    ra, rb = _find(parent, a), _find(parent, b)
    if ra != rb:  # the smaller index stays the root: a segment's root is its first pixel
        if ra < rb:
            parent[rb] = ra
        else:
            parent[ra] = rb


@njit(cache=True)
def label_segments(d, valid, edge_abs, edge_rel):
    """(count, labels (k,)): the ``valid`` pixels of frames ``d`` (F, h, w) cut where two
    4-neighbours lie further apart than ``edge_abs + edge_rel * depth`` (the nearer's), each
    valid pixel's segment in row-major order, segments numbered by their first pixel; no
    segment spans two frames."""
    f, h, w = d.shape
    n = f * h * w
    parent = np.arange(n)
    for k in range(f):
        for r in range(h):
            for c in range(w):
                if not valid[k, r, c]:
                    continue
                i = (k * h + r) * w + c
                if c + 1 < w and valid[k, r, c + 1]:
                    a, b = d[k, r, c], d[k, r, c + 1]
                    if abs(a - b) <= edge_abs + edge_rel * min(a, b):  # in the depth's own precision
                        _union(parent, i, i + 1)
                if r + 1 < h and valid[k, r + 1, c]:
                    a, b = d[k, r, c], d[k, r + 1, c]
                    if abs(a - b) <= edge_abs + edge_rel * min(a, b):
                        _union(parent, i, i + w)
    number = np.full(n, -1, np.int64)
    labels = np.empty(n, np.int64)
    count, m = 0, 0
    for k in range(f):
        for r in range(h):
            for c in range(w):
                if valid[k, r, c]:
                    root = _find(parent, (k * h + r) * w + c)
                    if number[root] < 0:
                        number[root] = count
                        count += 1
                    labels[m] = number[root]
                    m += 1
    return count, labels[:m]


@njit(cache=True)
def back_project(depth, rx, ry, rz, cos, sin, px, py, mount_height, mount_x, floor_z):
    """Frames' depth (F, H, W) (0: no return) along rays rx, ry, rz (H, W) from robots at
    px, py (F,) facing cos, sin (F,): the valid mask (F, H, W) (a return above ``floor_z``),
    and per valid pixel in row-major order its depth, x, y, z (world, float64). ``mount_x``
    comes in the poses' precision, as numpy would take a Python number beside them."""
    f, h, w = depth.shape
    valid = np.zeros((f, h, w), np.bool_)
    k = 0
    for i in range(f):
        for r in range(h):
            for c in range(w):
                if depth[i, r, c] > 0 and mount_height + rz[r, c] * depth[i, r, c] >= floor_z:
                    valid[i, r, c] = True
                    k += 1
    d = np.empty(k, depth.dtype)
    x, y, z = np.empty(k), np.empty(k), np.empty(k)
    m = 0
    for i in range(f):
        ci, si = cos[i], sin[i]
        bx, by = px[i] + mount_x * ci, py[i] + mount_x * si
        for r in range(h):
            for c in range(w):
                if valid[i, r, c]:
                    di = depth[i, r, c]
                    a, b = rx[r, c] * di, ry[r, c] * di
                    d[m] = di
                    x[m] = bx + ci * a - si * b
                    y[m] = by + si * a + ci * b
                    z[m] = mount_height + rz[r, c] * di
                    m += 1
    return valid, d, x, y, z


@njit(cache=True)
def within_boxes(boxes, inst, at, x, y, z, margin):
    """(k,) whether points ``at`` (k,) of x, y, z lie inside the boxes (I, 2, 3) of their
    instances ``inst`` (k,) grown by ``margin`` on every side (lower corner + -margin,
    upper corner + margin, as numpy adds the margins)."""
    out = np.empty(len(at), np.bool_)
    for j in range(len(at)):
        b, p = boxes[inst[j]], at[j]
        out[j] = (x[p] >= b[0, 0] + -margin and y[p] >= b[0, 1] + -margin and z[p] >= b[0, 2] + -margin
                  and x[p] <= b[1, 0] + margin and y[p] <= b[1, 1] + margin and z[p] <= b[1, 2] + margin)
    return out


@njit(cache=True)
def _slot(keys, key, mask):
    h = np.uint64(key) * _MIX
    h ^= h >> np.uint64(29)
    s = np.int64(h & np.uint64(mask))
    while keys[s] != EMPTY and keys[s] != key:
        s = (s + 1) & mask
    return s


@njit(cache=True)
def _get(keys, values, query, out):
    mask = len(keys) - 1
    for j in range(len(query)):
        s = _slot(keys, query[j], mask)
        out[j] = values[s] if keys[s] == query[j] else -1


@njit(cache=True)
def _put(keys, values, new, vals):
    mask = len(keys) - 1
    for j in range(len(new)):
        s = _slot(keys, new[j], mask)
        keys[s], values[s] = new[j], vals[j]


class HashTable:
    """int64 keys (>= 0) to int64 values, looked up and added many at once: ``get(keys)``
    gives -1 for a key not held; ``add(keys, values)`` records keys not held yet. Filled to
    at most half, then doubled."""

    def __init__(self, capacity: int = 1 << 12):
        self._keys = np.full(capacity, EMPTY, np.int64)
        self._values = np.zeros(capacity, np.int64)
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def get(self, keys: np.ndarray) -> np.ndarray:
        out = np.empty(len(keys), np.int64)
        _get(self._keys, self._values, np.ascontiguousarray(keys, np.int64), out)
        return out

    def add(self, keys: np.ndarray, values: np.ndarray) -> None:
        keys = np.ascontiguousarray(keys, np.int64)
        if 2 * (self._n + len(keys)) > len(self._keys):
            held = self._keys != EMPTY
            old_keys, old_values = self._keys[held], self._values[held]
            size = len(self._keys)
            while 2 * (self._n + len(keys)) > size:
                size *= 2
            self._keys, self._values = np.full(size, EMPTY, np.int64), np.zeros(size, np.int64)
            _put(self._keys, self._values, old_keys, old_values)
        _put(self._keys, self._values, keys, np.ascontiguousarray(values, np.int64))
        self._n += len(keys)
