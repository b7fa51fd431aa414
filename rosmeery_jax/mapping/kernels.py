"""Compiled kernels of the perceived mapper (numba): the loops numpy would run as many small
array operations. Each gives exactly what the numpy formulation it replaces gives (the
tests compare them), so the maps are bitwise those of before.

- :func:`label_segments`: a depth frame's 4-connected segments (rule 2), by union-find
  over the pixels, numbered in the order of their first pixel as ``scipy.ndimage.label``
  numbers them;
- :func:`back_project`: depth frames' pixels above the floor to world points (the
  arithmetic of the numpy expressions, in their order; the yaw's cosine and sine come from
  numpy, whose cos and sin may round otherwise than the C library's);
- :func:`grow_ranks`: rule 7's choice of the instance each segment grows, from the
  distinct (segment, cell) pairs of a cloud, without sorting its points;
- :class:`HashTable`: int64 keys to int64 values, open addressing with linear probing,
  for the mapper's voxel and cell tables (a sorted array grew by a copy per insert).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
from numba import njit

COMPILED_TOGETHER = ("kernels.py", "voxel_table.py", "passes.py")  # files whose njit code calls each other's


def drop_stale_cache(folder: Path = Path(__file__).parent, names: tuple[str, ...] = COMPILED_TOGETHER) -> bool:
    """Numba's disk cache checks only a function's own file, so a pass keeps the kernels of
    another file it was compiled with: when any of ``names`` in ``folder`` changed since the
    cache was written, the cache (``__pycache__/*.nbi``, ``*.nbc``) is dropped, to be
    compiled afresh. Whether it was dropped; a cache that cannot be written is left alone."""
    stamp = hashlib.sha256(b"".join((folder / n).read_bytes() for n in names)).hexdigest()
    cache = folder / "__pycache__"
    mark = cache / "numba-sources.sha256"
    try:
        if mark.is_file() and mark.read_text() == stamp:
            return False
        for f in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
            f.unlink(missing_ok=True)
        cache.mkdir(exist_ok=True)
        mark.write_text(stamp)
    except OSError:
        return False
    return True


drop_stale_cache()

EMPTY = np.iinfo(np.int64).min  # no key: cube keys are non-negative
_MIX = np.uint64(0x9E3779B97F4A7C15)  # Fibonacci hashing


@njit(cache=True, nogil=True)
def _find(parent, i):
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:  # path compression
        parent[i], i = root, parent[i]
    return root


@njit(cache=True, nogil=True)
def _union(parent, a, b):
    ra, rb = _find(parent, a), _find(parent, b)
    if ra != rb:  # the smaller index stays the root: a segment's root is its first pixel
        if ra < rb:
            parent[rb] = ra
        else:
            parent[ra] = rb


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
def _number(keys, slot_key, slot_id, ids):
    """Number ``keys`` by first appearance into ``ids`` with an empty table (slot_key,
    slot_id): their count, or -1 once the table is more than half full."""
    mask, count = len(slot_id) - 1, 0
    for i in range(len(keys)):
        if i and keys[i] == keys[i - 1]:  # neighbouring pixels mostly repeat a key
            ids[i] = ids[i - 1]
            continue
        h = np.uint64(keys[i]) * _MIX
        h ^= h >> np.uint64(29)
        s = np.int64(h & np.uint64(mask))
        while slot_id[s] >= 0 and slot_key[s] != keys[i]:
            s = (s + 1) & mask
        if slot_id[s] < 0:
            if 2 * (count + 1) > len(slot_id):
                return -1
            slot_key[s], slot_id[s] = keys[i], count
            count += 1
        ids[i] = slot_id[s]
    return count


@njit(cache=True, nogil=True)
def group_ids(keys):
    """(ids (K,), G): each of int64 ``keys`` (K,) numbered by the first appearance of its
    value, and the number of distinct values; one pass over a hash table, begun with a
    quarter as many slots as keys (a cloud's keys repeat: a table sized for every key costs
    more to clear than to use) and begun again four times as large when it fills."""
    size = 1024
    while 4 * size < len(keys):  # a quarter as many slots as keys: most repeat
        size *= 2
    ids = np.empty(len(keys), np.int64)
    while True:
        count = _number(keys, np.empty(size, np.int64), np.full(size, -1, np.int64), ids)
        if count >= 0:
            return ids, count
        size *= 4


@njit(cache=True, nogil=True)
def grow_ranks(part, cell, held, beside, segments, cells, share):
    """Rule 7 on one cloud: points' segments ``part`` (k,) and cells ``cell`` (k,) (indices
    into the cells' ``held`` (C,): the instance holding each, -1 none, and ``beside`` (C,):
    the instance seen in it or next to it). A segment grows the instance holding the most of
    its distinct cells (the smaller of those tied) if that is at least ``share`` of them.
    Returns each point's rank (k,) (-1: it joins nothing), and the instances grown (R,) in
    rank order: the order of the first segment each grows. A point joins its segment's
    instance only where its cell is beside it."""
    pair, n_pairs = group_ids(part * cells + cell)  # the distinct (segment, cell) pairs
    seen = np.zeros(n_pairs, np.bool_)
    cells_of = np.zeros(segments, np.int64)  # distinct cells per segment
    width = 1
    for c in range(cells):
        width = max(width, held[c] + 1)
    inst_keys = np.empty(len(part), np.int64)
    m = 0
    for j in range(len(part)):
        if not seen[pair[j]]:
            seen[pair[j]] = True
            cells_of[part[j]] += 1
            if held[cell[j]] >= 0:
                inst_keys[m] = part[j] * width + held[cell[j]]
                m += 1
    owner = np.full(segments, -1, np.int64)
    if m:
        group, n_groups = group_ids(inst_keys[:m])
        counts = np.zeros(n_groups, np.int64)
        key_of = np.empty(n_groups, np.int64)
        for i in range(m):
            counts[group[i]] += 1
            key_of[group[i]] = inst_keys[i]
        most = np.zeros(segments, np.int64)
        for g in range(n_groups):
            s, inst = key_of[g] // width, key_of[g] % width
            if counts[g] > most[s] or (counts[g] == most[s] and inst < owner[s]):
                most[s], owner[s] = counts[g], inst
        for s in range(segments):
            if owner[s] >= 0 and not most[s] >= share * cells_of[s]:
                owner[s] = -1
    order = np.full(width, -1, np.int64)  # each instance's rank
    grown = np.empty(segments, np.int64)
    r = 0
    for s in range(segments):
        if owner[s] >= 0 and order[owner[s]] < 0:
            order[owner[s]] = r
            grown[r] = owner[s]
            r += 1
    rank = np.full(len(part), -1, np.int64)
    for j in range(len(part)):
        o = owner[part[j]]
        if o >= 0 and beside[cell[j]] == o:
            rank[j] = order[o]
    return rank, grown[:r]


@njit(cache=True, nogil=True)
def _slot(keys, key, mask):
    h = np.uint64(key) * _MIX
    h ^= h >> np.uint64(29)
    s = np.int64(h & np.uint64(mask))
    while keys[s] != EMPTY and keys[s] != key:
        s = (s + 1) & mask
    return s


@njit(cache=True, nogil=True)
def lookup(keys, values, key):
    """The value of ``key`` in a table's arrays (:class:`HashTable`), -1 if not held."""
    s = _slot(keys, key, len(keys) - 1)
    return values[s] if keys[s] == key else -1


@njit(cache=True, nogil=True)
def room(keys, values, n, extra):
    """A table's arrays (keys, values) holding ``n`` keys with room for ``extra`` more: the
    same, or doubled until those would fill it to at most half. (Called before a loop that
    :func:`put` s: arrays reassigned inside a loop cost reference counting every turn.)"""
    size = len(keys)
    while 2 * (n + extra) > size:
        size *= 2
    if size == len(keys):
        return keys, values
    old_keys, old_values = keys, values
    keys, values = np.full(size, EMPTY, np.int64), np.zeros(size, np.int64)
    for j in range(len(old_keys)):
        if old_keys[j] != EMPTY:
            s = _slot(keys, old_keys[j], size - 1)
            keys[s], values[s] = old_keys[j], old_values[j]
    return keys, values


@njit(cache=True, nogil=True)
def put(keys, values, key, value):
    """Record ``key`` -> ``value`` in a table's arrays that have room (:func:`room`), if the
    key is not held yet; whether it was new."""
    s = _slot(keys, key, len(keys) - 1)
    if keys[s] == key:
        return False
    keys[s], values[s] = key, value
    return True


@njit(cache=True, nogil=True)
def _get(keys, values, query, out):
    for j in range(len(query)):
        out[j] = lookup(keys, values, query[j])


@njit(cache=True, nogil=True)
def _add(keys, values, n, new, vals):
    keys, values = room(keys, values, n, len(new))
    for j in range(len(new)):
        n += put(keys, values, new[j], vals[j])
    return keys, values, n


class HashTable:
    """int64 keys (>= 0) to int64 values, looked up and added many at once: ``get(keys)``
    gives -1 for a key not held; ``add(keys, values)`` records keys not held yet. Filled to
    at most half, then doubled. Compiled code reads and fills its arrays (``arrays``, then
    ``update``) with :func:`lookup`, :func:`room` and :func:`put`."""

    def __init__(self, capacity: int = 1 << 12):
        self._keys = np.full(capacity, EMPTY, np.int64)
        self._values = np.zeros(capacity, np.int64)
        self._n = 0

    def __len__(self) -> int:
        return self._n

    @property
    def arrays(self) -> tuple:
        """(keys, values, n): the table as compiled code takes it."""
        return self._keys, self._values, self._n

    def update(self, arrays: tuple) -> None:
        """Take back the table's (keys, values, n) from compiled code that filled it."""
        self._keys, self._values, self._n = arrays

    def get(self, keys: np.ndarray) -> np.ndarray:
        out = np.empty(len(keys), np.int64)
        _get(self._keys, self._values, np.ascontiguousarray(keys, np.int64), out)
        return out

    def add(self, keys: np.ndarray, values: np.ndarray) -> None:
        self.update(_add(*self.arrays, np.ascontiguousarray(keys, np.int64), np.ascontiguousarray(values, np.int64)))
