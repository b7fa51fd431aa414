"""The perceived mapper's compiled passes give, bit for bit, what the numpy formulations they
replaced give; those formulations are kept here as the references."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rosmeery_jax.mapping.config import PerceivedConfig
from rosmeery_jax.mapping.kernels import HashTable, back_project, grow_ranks, label_segments
from rosmeery_jax.mapping.passes import boxes_pass, claim_pass, cloud_pass, grow_pass, off_walls, publish_pass
from rosmeery_jax.mapping.voxel_table import NEIGHBOURS, cube_keys, first_of_lowest_rank

CFG = PerceivedConfig()


def _claims(keys, rank):
    """The first entry of the lowest rank of each key, ordered by rank, then key."""
    if not len(keys):
        return np.zeros(0, np.int64)
    first = first_of_lowest_rank(np.asarray(keys, np.int64), np.asarray(rank, np.int64))
    return first[np.lexsort((keys[first], rank[first]))]


def _table(rng, n, values=5):
    t = HashTable(16)
    keys = np.unique(rng.integers(0, 40, n)) << 21
    t.add(keys, rng.integers(0, values, len(keys)))
    return t


def _copy(t: HashTable) -> HashTable:
    out = HashTable(16)
    out.update(tuple(a.copy() if isinstance(a, np.ndarray) else a for a in t.arrays))
    return out


def _same_table(a: HashTable, b: HashTable, probe: np.ndarray) -> None:
    assert len(a) == len(b)
    np.testing.assert_array_equal(a.get(probe), b.get(probe))


def _frame(rng, f=1, h=12, w=16):
    """Depth frames of a few surfaces, with no-return pixels, and world points for them."""
    depth = rng.choice([0.0, 0.8, 1.0, 1.5, 2.6], (f, h, w)).astype(np.float32)
    depth += np.where(depth > 0, rng.normal(0, 0.005, depth.shape), 0).astype(np.float32)
    rays = tuple(rng.normal(0, 1, (h, w)) for _ in range(3))
    pose = rng.normal(0, 1, (f, 3)).astype(np.float32)
    return depth, rays, pose


def _numpy_cloud(depth, rays, pose, walls, held, cfg):
    """The cloud as numpy built it: back-projection, rule 10, segments."""
    valid, d, x, y, z = back_project(depth, *rays, np.cos(pose[:, 2]), np.sin(pose[:, 2]), pose[:, 0].copy(),
                                     pose[:, 1].copy(), 0.5, np.float32(0.1), cfg.floor_z)
    keep, hit = _numpy_off_walls(x, y, z, walls, held, cfg)
    valid[valid] = keep
    d, x, y, z = d[keep], x[keep], y[keep], z[keep]
    count, part = label_segments(depth, valid, np.float32(cfg.edge_abs), np.float32(cfg.edge_rel))
    return (valid, d, x, y, z, part, np.bincount(part, minlength=count)), hit


def _numpy_off_walls(x, y, z, walls, held, cfg):
    cell = cube_keys((x, y, np.zeros_like(x)), cfg.wall_cell)
    tall = np.unique(cell[z > cfg.wall_above])
    tall = tall[walls.get(tall) < 0]
    walls.add(tall, np.zeros(len(tall), np.int64))
    return walls.get(cell) < 0, bool((held.get(tall) >= 0).any())


def test_the_cloud_pass_is_the_numpy_cloud():
    rng = np.random.default_rng(0)
    for trial in range(60):
        depth, rays, pose = _frame(rng, f=int(rng.integers(1, 4)))
        cfg = replace(CFG, wall_above=float(rng.choice([0.3, 1.0, np.inf])), wall_cell=0.5)
        walls, held = HashTable(16), HashTable(16)
        cells = cube_keys((rng.normal(0, 2, 20), rng.normal(0, 2, 20), np.zeros(20)), cfg.wall_cell)
        walls.add(np.unique(cells[:5]), np.zeros(len(np.unique(cells[:5])), np.int64))
        held.add(np.unique(cells), np.zeros(len(np.unique(cells)), np.int64))
        want_walls, got_walls = _copy(walls), _copy(walls)
        if np.isfinite(cfg.wall_above):
            want, hit = _numpy_cloud(depth, rays, pose, want_walls, held, cfg)
        else:
            want, hit = _numpy_cloud(depth, rays, pose, HashTable(16), held, replace(cfg, wall_above=np.inf)), False
            want = want[0]
        *got, arrays, got_hit = cloud_pass(
            depth, *rays, np.cos(pose[:, 2]), np.sin(pose[:, 2]), pose[:, 0].copy(), pose[:, 1].copy(), 0.5,
            np.float32(0.1), cfg.floor_z, got_walls.arrays, held.arrays, cfg.wall_cell, cfg.wall_above,
            np.float32(cfg.edge_abs), np.float32(cfg.edge_rel))
        got_walls.update(arrays)
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)
        assert got_hit == hit, trial
        _same_table(got_walls, want_walls, np.r_[cells, cube_keys((got[2], got[3], 0 * got[2]), cfg.wall_cell)])


def test_off_walls_and_publish_are_the_numpy_wall_filter():
    rng = np.random.default_rng(1)
    for _ in range(60):
        pts = rng.normal(0, 1, (int(rng.integers(0, 40)), 3)) * [1, 1, 2]
        walls, held = _table(rng, 8, 1), _table(rng, 8, 1)
        cfg = replace(CFG, wall_cell=0.5, wall_above=0.8)
        want_walls, want_held = _copy(walls), _copy(held)
        keep, hit = _numpy_off_walls(pts[:, 0], pts[:, 1], pts[:, 2], want_walls, held, cfg)
        got, arrays, got_hit = off_walls(*pts.T.copy(), walls.arrays, held.arrays, cfg.wall_cell, cfg.wall_above)
        walls.update(arrays)
        np.testing.assert_array_equal(got, keep)
        assert got_hit == hit
        cell = cube_keys((pts[:, 0], pts[:, 1], np.zeros(len(pts))), cfg.wall_cell)
        _same_table(walls, want_walls, cell)
        off = want_walls.get(cell) < 0  # publish: the points off the walls, their cells held
        new = np.unique(cell[off])
        new = new[want_held.get(new) < 0]
        want_held.add(new, np.zeros(len(new), np.int64))
        kept, arrays = publish_pass(pts, walls.arrays, held.arrays, cfg.wall_cell)
        held.update(arrays)
        np.testing.assert_array_equal(kept, pts[off])
        _same_table(held, want_held, cell)


def _numpy_box_owner(boxes, shape):
    h, w = shape
    owner, best = np.full(shape, -1, np.int64), np.full(shape, np.inf)
    for i, (x1, y1, x2, y2) in enumerate(boxes):
        rows = np.s_[int(np.clip(np.floor(y1), 0, h)):int(np.clip(np.ceil(y2) + 1, 0, h))]
        cols = np.s_[int(np.clip(np.floor(x1), 0, w)):int(np.clip(np.ceil(x2) + 1, 0, w))]
        v, u = np.arange(h)[rows, None] + 0.5, np.arange(w)[None, cols] + 0.5
        inside = np.maximum(np.abs(u - (x1 + x2) / 2) / max((x2 - x1) / 2, 1e-6),
                            np.abs(v - (y1 + y2) / 2) / max((y2 - y1) / 2, 1e-6))
        take = (inside <= 1) & (inside < best[rows, cols])
        owner[rows, cols][take], best[rows, cols][take] = i, inside[take]
    return owner


def _numpy_box_points(d, x, y, z, part, size, mine, cfg):
    """Rule 2 for one box, then its voxels, cells and core, as numpy took them."""
    n = len(mine)
    p = part[mine]
    count = np.bincount(p, minlength=len(size))
    inside = (count > 0) & (count >= cfg.inside * size)
    fit = inside & (count >= cfg.min_share * n)
    take, core = mine[:0], None
    if fit.any():
        near = np.full(len(size), np.inf, d.dtype)
        np.minimum.at(near, p, d[mine])
        front = inside & (count >= min(cfg.front_share, cfg.min_share) * n)
        obj = int(np.flatnonzero(fit)[np.argmin(near[fit])])
        if not near[obj] > near[front].min() + cfg.behind:
            parts = inside & (count >= cfg.part_share * n) & (near >= near[obj]) & (near <= near[obj] + cfg.part_behind)
            parts[obj] = True
            core = mine[p == obj] if parts.sum() > 1 else None
            take = mine[parts[p]]
    keys, first = np.unique(cube_keys((x[take], y[take], z[take]), cfg.voxel), return_index=True)
    cells = np.unique(cube_keys((x[take], y[take], z[take]), cfg.cell))
    core = cells if core is None else np.unique(cube_keys((x[core], y[core], z[core]), cfg.cell))
    return keys, cells, np.stack([x[take][first], y[take][first], z[take][first]], -1), core


@pytest.mark.parametrize("cfg", [CFG, replace(CFG, part_share=0.0, part_behind=1.0, behind=0.1, min_share=0.05),
                                 replace(CFG, cell=CFG.voxel, inside=0.2)])
def test_the_boxes_pass_is_the_numpy_box_points(cfg):
    rng = np.random.default_rng(2)
    for trial in range(80):
        depth, rays, pose = _frame(rng)
        valid, d, x, y, z = back_project(depth, *rays, np.cos(pose[:, 2]), np.sin(pose[:, 2]), pose[:, 0].copy(),
                                         pose[:, 1].copy(), 0.5, np.float32(0.1), -np.inf)
        x, y, z = (np.round(a * 8) / 40 for a in (x, y, z))  # points share voxels and cells
        count, part = label_segments(depth, valid, np.float32(cfg.edge_abs), np.float32(cfg.edge_rel))
        size = np.bincount(part, minlength=count)
        corner = rng.uniform(-2, 14, (int(rng.integers(0, 4)), 2))
        boxes = np.c_[corner, corner + rng.uniform(0, 10, corner.shape)].astype(np.float64)
        owner = _numpy_box_owner(boxes, depth.shape[1:])[valid[0]]
        keys, points, key_at, cells, cell_at, core, core_at = boxes_pass(
            boxes, valid[0], d, x, y, z, part, size, cfg.voxel, cfg.cell, cfg.inside, cfg.min_share,
            cfg.front_share, np.float32(cfg.behind), cfg.part_share, np.float32(cfg.part_behind))
        assert len(key_at) == len(cell_at) == len(core_at) == len(boxes) + 1
        for b in range(len(boxes)):
            want = _numpy_box_points(d, x, y, z, part, size, np.flatnonzero(owner == b), cfg)
            got = (keys[key_at[b]:key_at[b + 1]], cells[cell_at[b]:cell_at[b + 1]], points[key_at[b]:key_at[b + 1]],
                   core[core_at[b]:core_at[b + 1]])
            for g, w in zip(got, want):
                np.testing.assert_array_equal(g, w, err_msg=f"trial {trial}, box {b}")


def _numpy_claim(insts, keys, rank, cells, cell_rank, owner, claimed, near):
    """Rules 3-4 as numpy claimed: the voxels taken (ordered by rank, then key)."""
    new = _claims(keys, rank)
    new = new[owner.get(keys[new]) < 0]
    owner.add(keys[new], insts[rank[new]])
    fresh = _claims(cells, cell_rank)
    fresh = fresh[claimed.get(cells[fresh]) < 0]
    claimed.add(cells[fresh], insts[cell_rank[fresh]])
    around = (cells[fresh][:, None] + NEIGHBOURS).ravel()
    around_rank = np.repeat(cell_rank[fresh], len(NEIGHBOURS))
    first = _claims(around, around_rank)
    first = first[near.get(around[first]) < 0]
    near.add(around[first], insts[around_rank[first]])
    return new


def test_the_claim_pass_is_the_numpy_claim():
    rng = np.random.default_rng(3)
    for _ in range(150):
        r = int(rng.integers(1, 4))
        insts = rng.choice(8, r, replace=False).astype(np.int64)
        keys = rng.integers(0, 40, int(rng.integers(0, 60))).astype(np.int64) << 21
        cells = rng.integers(0, 40, int(rng.integers(0, 60))).astype(np.int64) << 21
        rank, cell_rank = rng.integers(0, r, len(keys)), rng.integers(0, r, len(cells))
        tables = [_table(rng, 10) for _ in range(3)]
        want_tables = [_copy(t) for t in tables]
        want = _numpy_claim(insts, keys, rank, cells, cell_rank, *want_tables)
        got, at, *arrays = claim_pass(insts, keys, rank, cells, cell_rank, *(t.arrays for t in tables))
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(at, np.searchsorted(rank[got], np.arange(r + 1)))  # each rank's bounds
        probe = np.r_[keys, (cells[:, None] + NEIGHBOURS).ravel()]
        for t, a, w in zip(tables, arrays, want_tables):
            t.update(a)
            _same_table(t, w, probe)


def test_the_grow_pass_is_the_numpy_growth():
    """Rule 7 as numpy grew: each distinct cell looked up once, grow_ranks, then the points
    within reach of their instance's grown 3D box."""
    rng = np.random.default_rng(4)
    for trial in range(150):
        k, segments = int(rng.integers(1, 80)), int(rng.integers(1, 6))
        x, y, z = (rng.integers(0, 6, k) * 0.05 + rng.uniform(0, 0.049, k) for _ in range(3))
        part = rng.integers(0, segments, k)
        root = np.r_[rng.integers(0, 4, 4), -1]  # instances 0-3 after merges
        extent = np.sort(rng.uniform(-0.1, 0.4, (4, 2, 3)), axis=1)
        margin, share = float(rng.choice([0.0, 0.05, np.inf])), float(rng.choice([0.0, 0.5]))
        cell = cube_keys((x, y, z), 0.05)
        claimed, near = HashTable(16), HashTable(16)
        some = np.unique(cell)[rng.random(len(np.unique(cell))) < 0.5]
        claimed.add(some, rng.integers(0, 4, len(some)))
        near.add(np.unique(cell), rng.integers(0, 4, len(np.unique(cell))))
        cells, cell_ix = np.unique(cell, return_inverse=True)
        held, beside = root[claimed.get(cells)], root[near.get(cells)]
        rank, grown = grow_ranks(part, cell_ix.astype(np.int64), held, beside, segments, len(cells), share)
        take = np.flatnonzero(rank >= 0)
        if len(take) and np.isfinite(margin):
            box = extent[grown[rank[take]]] + np.array([[-margin], [margin]])
            xyz = np.stack([x[take], y[take], z[take]], -1)
            take = take[((xyz >= box[:, 0]) & (xyz <= box[:, 1])).all(-1)]
        got = grow_pass(x, y, z, part, segments, 0.05, 0.025, claimed.arrays, near.arrays, root, extent, margin, share)
        want = (grown, take, rank[take], cube_keys((x[take], y[take], z[take]), 0.025), cell[take])
        if len(grown):  # grow_ranks numbers its own cells: the instances grown and their ranks agree
            for g, w in zip(got, want):
                np.testing.assert_array_equal(g, w, err_msg=f"trial {trial}")
        else:
            assert not len(got[0]) and not len(got[1])


def test_the_compiled_cache_is_dropped_when_a_file_compiled_with_it_changes(tmp_path):
    from rosmeery_jax.mapping.kernels import drop_stale_cache

    names = ("a.py", "b.py")
    for n in names:
        (tmp_path / n).write_text("x = 1\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    old = [cache / "b.f-1.py311.nbi", cache / "b.f-1.py311.1.nbc"]
    for f in [*old, cache / "b.cpython-311.pyc"]:
        f.write_bytes(b"compiled")
    assert drop_stale_cache(tmp_path, names) and not any(f.exists() for f in old)  # no record: dropped
    for f in old:
        f.write_bytes(b"compiled")
    assert not drop_stale_cache(tmp_path, names) and all(f.exists() for f in old)  # unchanged: kept
    (tmp_path / "a.py").write_text("x = 2\n")  # a kernel the cached code of b.py calls
    assert drop_stale_cache(tmp_path, names) and not any(f.exists() for f in old)
    assert (cache / "b.cpython-311.pyc").exists()  # Python's own cache is not numba's
