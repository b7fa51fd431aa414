"""The perceived mapper's compiled passes (numba): a frame's whole cloud, its boxes' points,
rule 7's growth, the claims of rules 3-4 and a publish's wall filter, each one call from
Python in place of tens of numpy calls. They compose the kernels of
:mod:`rosmeery_jax.mapping.kernels` and do the arithmetic of the numpy formulations they
replaced, in their order and precision, so the maps are bitwise those of before (the tests
hold each pass to that formulation).

Two rules of thumb kept them fast: a large table is read once per distinct key (a cloud's
keys repeat, and a read of a large table is a cache miss), and no array is reassigned
inside a hot loop (numba then counts references every turn).

Tables travel as (keys, values, n) (:attr:`HashTable.arrays`) and come back filled.
Shapes: F frames, H x W pixels, k points, S segments, V voxels, C cells, R instances, D boxes.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from rosmeery_jax.mapping.kernels import back_project, group_ids, grow_ranks, label_segments, lookup, put, room
from rosmeery_jax.mapping.voxel_table import NEIGHBOURS, cube_key, first_of_lowest_rank
from rosmeery_jax.raycast.sensors import camera_rays


class Cloud(NamedTuple):
    """F frames' depth pixels above the floor and off the walls: valid (F, H, W) which
    pixels; per point (k,), in row-major order: depth, world x, y, z, and its depth segment
    part; size (S,) each segment's points."""

    valid: np.ndarray
    depth: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    part: np.ndarray
    size: np.ndarray


class Boxed(NamedTuple):
    """One box's points in a frame (rules 1-3): keys (V,) their voxels' keys, ascending; cells
    (C,) their coarse cells' keys; points (V, 3) the first point in each voxel; core (K,) the
    coarse cells of the object's own depth segment, by which rule 4 associates the box."""

    keys: np.ndarray
    cells: np.ndarray
    points: np.ndarray
    core: np.ndarray


def depth_rays(camera, w: int, h: int) -> tuple:
    """The camera's rays at w x h pixels scaled so that a point is ray * depth: x (forward),
    y, z (H, W) each, in the camera's level frame."""
    rays = camera_rays(camera, w, h)  # (H*W, 3) camera frame, unit
    axis = np.array([np.cos(camera.pitch), 0.0, -np.sin(camera.pitch)])
    rays = (rays / (rays @ axis)[:, None]).reshape(h, w, 3)
    return tuple(np.ascontiguousarray(rays[..., i]) for i in range(3))


@njit(cache=True, nogil=True)
def off_walls(x, y, z, walls, held, wall_cell, wall_above):
    """Rule 10 on points x, y, z (k,): the ``wall_cell`` plan-view cells of those higher than
    ``wall_above`` join ``walls``; then which points lie off the walls (k,), the walls table,
    and whether a new wall cell holds map points (``held``: the caller drops them)."""
    wk, wv, wn = walls
    k = len(x)
    cell = np.empty(k, np.int64)
    tall = np.empty(k, np.int64)
    t = 0
    for i in range(k):
        cell[i] = cube_key(x[i], y[i], 0.0, wall_cell)
        if z[i] > wall_above and lookup(wk, wv, cell[i]) < 0:
            tall[t] = cell[i]
            t += 1
    wk, wv = room(wk, wv, wn, t)
    hit = False
    for i in range(t):
        if put(wk, wv, tall[i], 0):
            wn += 1
            hit = hit or lookup(held[0], held[1], tall[i]) >= 0
    keep = np.empty(k, np.bool_)
    for i in range(k):  # neighbouring pixels mostly share a cell: the table is read once for them
        keep[i] = keep[i - 1] if i and cell[i] == cell[i - 1] else lookup(wk, wv, cell[i]) < 0
    return keep, (wk, wv, wn), hit


@njit(cache=True, nogil=True)
def cloud_pass(depth, rx, ry, rz, cos, sin, px, py, mount_height, mount_x, floor_z, walls, held, wall_cell,
               wall_above, edge_abs, edge_rel):
    """Frames' depth (F, H, W) to their cloud: the pixels above the floor back-projected
    (:func:`back_project`), those in a wall's plan-view cell dropped (:func:`off_walls`;
    ``wall_above`` inf: none), then cut into depth segments (:func:`label_segments`).

    Returns valid (F, H, W), per point (k,) depth, x, y, z, segment; size (S,); the walls
    table; and whether a new wall cell holds map points."""
    valid, d, x, y, z = back_project(depth, rx, ry, rz, cos, sin, px, py, mount_height, mount_x, floor_z)
    hit = False
    if np.isfinite(wall_above):
        keep, walls, hit = off_walls(x, y, z, walls, held, wall_cell, wall_above)
        m = 0
        for i in range(len(keep)):  # the points kept move to the front, in order
            if keep[i]:
                d[m], x[m], y[m], z[m] = d[i], x[i], y[i], z[i]
                m += 1
        if m < len(keep):
            flat, j = valid.reshape(-1), 0
            for p in range(len(flat)):  # valid[valid] = keep
                if flat[p]:
                    flat[p] = keep[j]
                    j += 1
            d, x, y, z = d[:m], x[:m], y[:m], z[:m]
    count, part = label_segments(depth, valid, edge_abs, edge_rel)
    size = np.zeros(count, np.int64)
    for p in part:
        size[p] += 1
    return valid, d, x, y, z, part, size, walls, hit


@njit(cache=True, nogil=True)
def grow_pass(x, y, z, part, segments, cell_size, voxel, claimed, near, root, extent, margin, share):
    """Rule 7 on a cloud (points x, y, z, segment ``part`` (k,), ``segments`` S): each
    segment's instance (:func:`grow_ranks`, over its distinct ``cell_size`` cells, the
    instances holding them read from ``claimed`` and ``near`` through ``root`` (I + 1,), the
    instances after merges) and the points that join it: in a cell beside it and within
    ``margin`` of its ``extent`` (I, 2, 3) (inf: anywhere).

    Returns the instances grown (R,), in rank order; the points taken (t,) (indices), their
    ranks, voxel keys and cell keys (t,) each."""
    k = len(x)
    cell = np.empty(k, np.int64)
    for i in range(k):
        cell[i] = cube_key(x[i], y[i], z[i], cell_size)
    cell_ix, n_cells = group_ids(cell)
    held, beside = np.full(n_cells, -2, np.int64), np.full(n_cells, -2, np.int64)  # -2: not read
    candidate = np.zeros(segments, np.bool_)  # segments holding a held cell: only they can grow
    for i in range(k):  # each cell read once, at its first point
        if held[cell_ix[i]] == -2:
            held[cell_ix[i]] = root[lookup(claimed[0], claimed[1], cell[i])]
        candidate[part[i]] |= held[cell_ix[i]] >= 0
    at = np.empty(k, np.int64)  # the points of candidate segments
    n = 0
    for i in range(k):
        if candidate[part[i]]:
            at[n] = i
            n += 1
            if beside[cell_ix[i]] == -2:
                beside[cell_ix[i]] = root[lookup(near[0], near[1], cell[i])]
    at = at[:n]
    ranked, grown = grow_ranks(part[at], cell_ix[at], held, beside, segments, n_cells, share)
    rank = np.full(k, -1, np.int64)
    rank[at] = ranked
    take = np.empty(k, np.int64)
    t = 0
    if len(grown):
        anywhere = not np.isfinite(margin)
        for i in range(k):
            if rank[i] < 0:
                continue
            if not anywhere:
                b = extent[grown[rank[i]]]
                if not (x[i] >= b[0, 0] + -margin and y[i] >= b[0, 1] + -margin and z[i] >= b[0, 2] + -margin
                        and x[i] <= b[1, 0] + margin and y[i] <= b[1, 1] + margin and z[i] <= b[1, 2] + margin):
                    continue
            take[t] = i
            t += 1
    take = take[:t]
    return grown, take, rank[take], _keys_of(x, y, z, take, voxel), cell[take]


@njit(cache=True, nogil=True)
def _by_rank(at, rank, ranks):
    """Indices ``at`` ordered by their ``rank`` (below ``ranks``), stably (a counting sort),
    and each rank's bounds among them (ranks + 1,)."""
    bounds = np.zeros(ranks + 1, np.int64)
    for i in at:
        bounds[rank[i] + 1] += 1
    for r in range(ranks):
        bounds[r + 1] += bounds[r]
    fill = bounds[:-1].copy()
    order = np.empty(len(at), np.int64)
    for i in at:
        order[fill[rank[i]]] = i
        fill[rank[i]] += 1
    return order, bounds


@njit(cache=True, nogil=True)
def claim_pass(insts, keys, rank, cells, cell_rank, owner, claimed, near):
    """Rules 3-4: instances ``insts`` (R,), one after the other, take the voxels ``keys``
    (V,) of their points (each of instance ``insts[rank]``) that no instance holds in
    ``owner``, and record their ``cells`` (C,) (of ``insts[cell_rank]``) in ``claimed``, and
    a cell newly claimed and its 26 neighbours in ``near``, where none is recorded: each
    voxel or cell goes to the first entry of the lowest rank that reaches it.

    Returns the voxels taken (indices into ``keys``), ordered by rank, then key, with each
    rank's bounds among them (R + 1,), and the three tables."""
    ok, ov, on = owner
    first = _by_rank(first_of_lowest_rank(keys, rank), rank, len(insts))[0]  # a large table read once per key
    new = np.empty(len(first), np.int64)
    m = 0
    ok, ov = room(ok, ov, on, len(first))
    for i in first:
        if put(ok, ov, keys[i], insts[rank[i]]):
            on += 1
            new[m] = i
            m += 1
    new = new[:m]
    new, at = _by_rank(new[np.argsort(keys[new])], rank, len(insts))  # by rank, then key (the keys are distinct)
    ck, cv, cn = claimed
    nk, nv, nn = near
    first = _by_rank(first_of_lowest_rank(cells, cell_rank), cell_rank, len(insts))[0]
    ck, cv = room(ck, cv, cn, len(first))
    fresh = np.empty(len(first), np.int64)
    f = 0
    for i in first:
        if put(ck, cv, cells[i], insts[cell_rank[i]]):  # a cell newly claimed: it and its neighbours are near it
            fresh[f] = i
            f += 1
    cn += f
    nk, nv = room(nk, nv, nn, len(NEIGHBOURS) * f)
    for i in fresh[:f]:
        for off in NEIGHBOURS:
            nn += put(nk, nv, cells[i] + off, insts[cell_rank[i]])
    return new, at, (ok, ov, on), (ck, cv, cn), (nk, nv, nn)


@njit(cache=True, nogil=True)
def _box_owner(boxes, valid):
    """(k,) the box each valid pixel (valid (H, W), row-major) lies most inside (rule 1), -1
    outside every box; each box is measured over its own rows and columns only."""
    h, w = valid.shape
    owner = np.full((h, w), -1, np.int64)
    best = np.full((h, w), np.inf)
    for i in range(len(boxes)):
        x1, y1, x2, y2 = boxes[i, 0], boxes[i, 1], boxes[i, 2], boxes[i, 3]
        r0, r1 = int(min(max(np.floor(y1), 0), h)), int(min(max(np.ceil(y2) + 1, 0), h))
        c0, c1 = int(min(max(np.floor(x1), 0), w)), int(min(max(np.ceil(x2) + 1, 0), w))
        cx, cy, hw, hh = (x1 + x2) / 2, (y1 + y2) / 2, max((x2 - x1) / 2, 1e-6), max((y2 - y1) / 2, 1e-6)
        for r in range(r0, r1):
            for c in range(c0, c1):
                inside = max(abs((c + 0.5) - cx) / hw, abs((r + 0.5) - cy) / hh)
                if inside <= 1 and inside < best[r, c]:
                    owner[r, c], best[r, c] = i, inside
    out = np.empty(valid.sum(), np.int64)
    k = 0
    for r in range(h):
        for c in range(w):
            if valid[r, c]:
                out[k] = owner[r, c]
                k += 1
    return out


@njit(cache=True, nogil=True)
def _distinct(keys):
    """The distinct ``keys`` ascending and the index of each one's first entry (np.unique's
    with ``return_index``): grouped by a hash table, then only the distinct ones sorted."""
    ids, n = group_ids(keys)
    first = np.full(n, -1, np.int64)
    for i in range(len(keys)):
        if first[ids[i]] < 0:
            first[ids[i]] = i
    out = keys[first]
    order = np.argsort(out)  # distinct: any sort gives the same order
    return out[order], first[order]


@njit(cache=True, nogil=True)
def _keys_of(x, y, z, take, size):
    """(t,) the cube keys (``size``) of points ``take`` (t,) (indices into x, y, z)."""
    out = np.empty(len(take), np.int64)
    for j in range(len(take)):
        out[j] = cube_key(x[take[j]], y[take[j]], z[take[j]], size)
    return out


@njit(cache=True, nogil=True)
def _object_points(pts, part, depth, size, count, near, inside, min_share, front_share, behind, part_share,
                   part_behind):
    """Rule 2 for one box, its points ``pts`` (n,) (indices, ascending): of the segments with
    at least ``inside`` of their points in the box, the nearest holding ``min_share`` of the
    box's points, unless one holding ``front_share`` stands ``behind`` nearer; with its
    parts, those holding ``part_share`` at most ``part_behind`` behind it. Returns the points
    taken, those of the object's own segment, and whether that segment is all it took.
    ``count`` and ``near`` (S,) are scratch: zeros, and left so."""
    n = len(pts)
    for p in pts:
        count[part[p]] += 1
    near[:] = np.inf
    for p in pts:  # each segment's nearest point in the box
        near[part[p]] = min(near[part[p]], depth[p])
    obj = -1  # the fit: the nearest segment holding min_share of the box
    front = np.empty(1, near.dtype)  # the nearest segment holding front_share, in the depth's precision
    front[0] = np.inf
    for s in range(len(size)):
        ins = count[s] > 0 and count[s] >= inside * size[s]
        if ins and count[s] >= min_share * n and (obj < 0 or near[s] < near[obj]):
            obj = s
        if ins and count[s] >= min(front_share, min_share) * n:
            front[0] = min(front[0], near[s])
    take, core, whole = pts[:0], pts[:0], True
    if obj >= 0 and not near[obj] > front[0] + behind:  # no thin thing in front of it
        parts = np.zeros(len(size), np.bool_)
        for s in range(len(size)):
            parts[s] = (count[s] > 0 and count[s] >= inside * size[s] and count[s] >= part_share * n
                        and near[s] >= near[obj] and near[s] <= near[obj] + part_behind)
        parts[obj] = True
        whole = parts.sum() <= 1
        take, core = np.empty(n, np.int64), np.empty(n, np.int64)
        m, c = 0, 0
        for p in pts:
            if parts[part[p]]:
                take[m] = p
                m += 1
            if part[p] == obj:
                core[c] = p
                c += 1
        take, core = take[:m], core[:c]
    for p in pts:
        count[part[p]] = 0
    return take, core, whole


@njit(cache=True, nogil=True)
def boxes_pass(boxes, valid, depth, x, y, z, part, size, voxel, cell, inside, min_share, front_share, behind,
               part_share, part_behind):
    """Rules 1-3 for every box (D, 4) of one frame's cloud (valid (H, W); per point (k,)
    depth, x, y, z, segment ``part``; ``size`` (S,) each segment's points): the pixels each
    box holds most (rule 1), its object's points among them (:func:`_object_points`, rule 2),
    binned into voxels and cells (rules 3-4). ``behind`` and ``part_behind`` come in the
    depth's precision, as numpy adds them.

    Returns per box, end to end, each with its bounds (D + 1,): its voxel keys ascending and
    their first points (V, 3); its cells ascending; its core cells (those of the object's
    own segment, or its cells when that segment is all it took)."""
    owner = _box_owner(boxes, valid)
    d_boxes = len(boxes)
    mine, mine_at = _by_rank(np.flatnonzero(owner >= 0), owner, d_boxes)  # each box's points, ascending
    n = len(mine)  # a box gives at most a key, cell and core cell per point it holds
    keys, points, cells, core = np.empty(n, np.int64), np.empty((n, 3)), np.empty(n, np.int64), np.empty(n, np.int64)
    key_at, cell_at, core_at = np.zeros(d_boxes + 1, np.int64), np.zeros(d_boxes + 1, np.int64), \
        np.zeros(d_boxes + 1, np.int64)
    count, near = np.zeros(len(size), np.int64), np.empty(len(size), depth.dtype)
    for b in range(d_boxes):
        take, own, whole = _object_points(mine[mine_at[b]:mine_at[b + 1]], part, depth, size, count, near, inside,
                                          min_share, front_share, behind, part_share, part_behind)
        k, first = _distinct(_keys_of(x, y, z, take, voxel))
        key_at[b + 1] = key_at[b] + len(k)
        keys[key_at[b]:key_at[b + 1]] = k
        for j in range(len(first)):
            q = key_at[b] + j
            points[q, 0], points[q, 1], points[q, 2] = x[take[first[j]]], y[take[first[j]]], z[take[first[j]]]
        c = k if cell == voxel else _distinct(_keys_of(x, y, z, take, cell))[0]
        cell_at[b + 1] = cell_at[b] + len(c)
        cells[cell_at[b]:cell_at[b + 1]] = c
        o = c if whole else _distinct(_keys_of(x, y, z, own, cell))[0]
        core_at[b + 1] = core_at[b] + len(o)
        core[core_at[b]:core_at[b + 1]] = o
    return keys[:key_at[-1]], points[:key_at[-1]], key_at, cells[:cell_at[-1]], cell_at, core[:core_at[-1]], core_at


@njit(cache=True, nogil=True)
def publish_pass(pts, walls, held, wall_cell):
    """Rule 10 for points entering the map (pts (n, 3)): those off the walls' plan-view
    ``wall_cell`` cells (m, 3), in order, and the ``held`` table with their cells added."""
    hk, hv, hn = held
    keep = np.empty(len(pts), np.int64)
    new = np.empty(len(pts), np.int64)
    m, t = 0, 0
    for i in range(len(pts)):
        cell = cube_key(pts[i, 0], pts[i, 1], 0.0, wall_cell)
        if lookup(walls[0], walls[1], cell) < 0:
            keep[m] = i
            m += 1
            if lookup(hk, hv, cell) < 0:
                new[t] = cell
                t += 1
    hk, hv = room(hk, hv, hn, t)
    for i in range(t):
        hn += put(hk, hv, new[i], 0)
    return pts[keep[:m]], (hk, hv, hn)
