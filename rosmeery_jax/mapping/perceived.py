"""The perceived mapper: a semantic map built only from what the robot perceives, with no
ground truth. Per detector frame, the depth pixels of each detection's own depth segment
are back-projected with the robot's pose into voxels and join an instance by overlap; the
map is scored by the same evaluator as a user's map (:mod:`rosmeery_jax.metrics.map_score`).
Its ten rules, with their settings (:class:`~rosmeery_jax.mapping.config.PerceivedConfig`,
each field naming its rule), are specified in docs/mapping.md.

Policies still decide on the built-in knowledge: this mapper only scores what a mapper fed
the same frames would hold. Shapes: H x W the detector frame, D detections, V voxels, I
instances, F frames, N objects.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, NamedTuple

import numpy as np

from rosmeery_jax.mapping.config import PerceivedConfig
from rosmeery_jax.mapping.kernels import HashTable
from rosmeery_jax.mapping.passes import (
    Boxed,
    Cloud,
    boxes_pass,
    claim_pass,
    cloud_pass,
    depth_rays,
    grow_pass,
    off_walls,
    publish_pass,
)
from rosmeery_jax.mapping.protocol import Camera, DepthFrame, Frame, Mapper, MapState
from rosmeery_jax.mapping.voxel_table import Rows, cube_keys


class _Seen(NamedTuple):
    """The latest frame (pose, depth, boxes), its cloud and each box's points (:class:`Boxed`),
    kept while the frame repeats."""

    pose: np.ndarray
    depth: np.ndarray
    boxes: np.ndarray
    cloud: Cloud
    voxels: list


class PerceivedMapper(Mapper):
    """One env's perceived map, fed frame by frame (host side, numpy), through the mapper
    protocol (:mod:`rosmeery_jax.mapping.protocol`)."""

    name = "perceived"

    def __init__(self, camera: Camera, categories: tuple[str, ...] = (), cfg: PerceivedConfig = PerceivedConfig()):
        super().__init__(camera, categories)
        self.cfg = cfg
        camera = self.config = camera.config  # the benchmark's camera settings: mount and rays
        w, h = camera.rgb_width, camera.rgb_height
        self.rays = depth_rays(camera, w, h)  # the detector frame's
        self.sweep_rays = depth_rays(camera, camera.width, camera.height)  # the depth camera's of every step
        self.sweep_cfg = replace(cfg, edge_rel=cfg.edge_rel * camera.focal(w) / camera.focal(camera.width))
        # (its neighbouring pixels lie further apart in angle: the same surface tilt gives a larger depth step)
        self.owner = HashTable()  # voxel key -> instance that claimed it
        self.cells = HashTable()  # coarse cell key -> the first instance seen in it or beside it
        self.claimed = HashTable()  # coarse cell key -> the first instance seen in it
        self.pending: list[list[np.ndarray]] = []  # per instance: point batches not in the map yet
        self.views: list[int] = []  # per instance: detections that support it
        self.parent: list[int] = []  # per instance: the instance it was merged into (itself if none)
        self.label: list[int] = []  # per instance: the held label (-1 none) and its confidence (rule 5)
        self.conf: list[float] = []
        self.points = Rows((3,), np.float64)  # the map's points, in the order they entered it
        self.point_instance = Rows((), np.int64)
        self.held = HashTable()  # plan-view cell key -> 0 where the map holds a point (rule 10)
        self.box: list[np.ndarray] = []  # per instance: its points' plan-view box (2, 2) (x, y corners),
        self.count: list[int] = []  # and how many, merged instances' included (rule 9)
        self.extent = Rows((2, 3), np.float64)  # per instance: its detections' points' 3D box (2, 3) (rule 7)
        self._changed: set[int] = set()  # instances whose points changed since rule 9 last ran
        self.walls = HashTable()  # plan-view cell key -> 0 where a wall stands (rule 10)
        names = np.array(categories, dtype=object)
        self._bare, self._placed = np.isin(names, cfg.bare), np.isin(names, cfg.placed)  # per category
        self._last: _Seen | None = None  # the latest frame
        self._repeat = False  # whether the latest frame repeats the one before
        self._swept: list[tuple] = []  # depth frames (pose, depth) since the latest detector frame (rule 8)
        self._last_swept: tuple | None = None  # the latest depth frame kept
        self._root: np.ndarray | None = None  # _roots(), while no instance is added or merged

    @property
    def instances(self) -> int:
        """Instances in the map (confirmed, and not merged into another)."""
        root = self._roots()
        return sum(root[i] == i and self._confirmed(i) for i in range(len(self.parent)))

    def _confirmed(self, inst: int) -> bool:
        """Whether instance ``inst`` is confirmed (rule 6)."""
        views, conf, cfg = self.views[inst], self.conf[inst], self.cfg  # conf: a float32, compared as numpy does
        # an instance's confidence is that of a detection it took, so alone_conf implies a view
        return bool(views >= cfg.min_views and conf >= cfg.min_conf or conf >= cfg.alone_conf)

    def add(self, frame: Frame) -> None:
        self.fold(frame.pose, frame.depth, frame.boxes, frame.labels, frame.confidences)

    def add_depth(self, frame: DepthFrame) -> None:
        """Rule 8: keep the depth camera of a step between detector frames (every
        ``depth_every``-th step; a robot at rest sends the same frame: kept once), to be
        folded with the others when the map is next read or the next detector frame comes."""
        n = self.cfg.depth_every
        if self.cfg.grow <= 0 or n <= 0 or frame.step % n:
            return
        last = self._last_swept
        if last is not None and np.array_equal(last[0], frame.pose) and np.array_equal(last[1], frame.depth):
            return
        self._last_swept = (np.array(frame.pose), np.array(frame.depth))
        self._swept.append(self._last_swept)

    def _fold_swept(self) -> None:
        """Rule 8: the depth frames kept since the latest detector frame, judged together
        against the map as it stood after it (rule 7 on all their segments at once)."""
        if self._swept:
            poses, depths = (np.stack(a) for a in zip(*self._swept))
            self._swept = []
            self._grow(self._cloud(poses, depths, self.sweep_rays, self.sweep_cfg))
            self._absorb()

    def semantic_map(self) -> MapState:
        """The map of every frame folded so far: confirmed instances only, merged ids resolved.
        Points join the end, and leave only when a wall is found where they lie (rule 10),
        so the scorer ties each point once but after those rare changes."""
        self._fold_swept()
        instance = self._roots()[self.point_instance.rows]  # merged ids resolved to their last instance
        return MapState(self.points.rows, instance, np.array(self.label, np.int32), np.array(self.conf, np.float32))

    def fold(self, pose: np.ndarray, depth: np.ndarray, boxes: np.ndarray, label: np.ndarray,
             conf: np.ndarray) -> None:
        """Fold one frame: pose (3,) x, y, yaw; depth (H, W) (0 = no return); boxes (D, 4)
        pixel corners x1, y1, x2, y2; label (D,) category index (-1 = padding); conf (D,)."""
        self._fold_swept()
        keep = np.asarray(label) >= 0
        boxes, label, conf = np.asarray(boxes)[keep], np.asarray(label)[keep], np.asarray(conf)[keep]
        taken: set[int] = set()  # the instances this frame's detections joined so far
        for boxed, k, c in zip(self._frame_voxels(pose, depth, boxes), label, conf):
            pts = boxed.points
            if len(pts) < max(self.cfg.min_voxels, 1):
                continue
            inst = self._associate(boxed.core, int(k), taken)
            taken.add(inst)
            self._claim(np.array([inst]), boxed.keys, pts, boxed.cells)
            _cover(self.extent.rows[inst], pts.min(0), pts.max(0))
            if np.float32(c) > self.conf[inst]:  # the most confident so far; ties keep the older
                self.label[inst], self.conf[inst] = int(k), np.float32(c)
            self.views[inst] += 1
            self._publish(inst)
        if self.cfg.grow > 0 and not self._repeat:  # a repeated frame holds nothing new to grow into
            self._grow(self._last.cloud)
        self._absorb()

    def _claim(self, insts: np.ndarray, keys: np.ndarray, points: np.ndarray | Callable, cells: np.ndarray,
               rank: np.ndarray | int = 0, cell_rank: np.ndarray | int = 0) -> None:
        """Instances ``insts`` (R,), one after the other, take the unclaimed voxels of their
        points (keys (V,), each of instance ``insts[rank]``; ``points`` (V, 3), or a function
        giving the points (n, 3) of the voxels taken (indices into keys)) and record their coarse ``cells`` (C,) (of
        ``insts[cell_rank]``) (rules 3-4): a voxel or cell goes to the first instance that
        reaches it, and its first point in that instance's points stays."""
        rank, cell_rank = _ranks(rank, len(keys)), _ranks(cell_rank, len(cells))
        new, at, *tables = claim_pass(np.ascontiguousarray(insts, np.int64), np.ascontiguousarray(keys, np.int64),
                                      rank, np.ascontiguousarray(cells, np.int64), cell_rank, self.owner.arrays,
                                      self.claimed.arrays, self.cells.arrays)
        for table, arrays in zip((self.owner, self.claimed, self.cells), tables):
            table.update(arrays)
        taken = points(new) if callable(points) else points[new]  # ordered by instance: one batch each
        for inst, a, b in zip(insts.tolist(), at[:-1].tolist(), at[1:].tolist()):
            if b > a:
                self.pending[inst].append(taken[a:b])
            self._publish(inst)

    def _grow(self, cloud: Cloud) -> None:
        """Rule 7: each frame segment mostly held by one instance grows it by its points in
        that instance's cells or next to them, within reach of what its detections took
        (``grow_margin``); an unconfirmed instance's points wait with it (rule 6)."""
        if not len(cloud.part) or not len(self.claimed):
            return
        cfg = self.cfg
        grown, take, rank, keys, cells = grow_pass(
            cloud.x, cloud.y, cloud.z, cloud.part, len(cloud.size), float(cfg.cell), float(cfg.voxel),
            self.claimed.arrays, self.cells.arrays, self._roots(), self.extent.rows, float(cfg.grow_margin),
            float(cfg.grow))
        if len(grown):  # the points of the few voxels taken only: most are held already
            self._claim(grown, keys, lambda new: np.stack([a[take[new]] for a in (cloud.x, cloud.y, cloud.z)], -1),
                        cells, rank, rank)

    def _roots(self) -> np.ndarray:
        """(I + 1,) each instance's last instance after merges; index -1 (no instance) maps to
        -1. Kept until an instance is added or merged (callers only read it)."""
        if self._root is None:
            root = np.array(self.parent, np.int64)
            while not np.array_equal(root, root[root]):
                root = root[root]
            self._root = np.r_[root, -1]
        return self._root

    def _frame_voxels(self, pose: np.ndarray, depth: np.ndarray, boxes: np.ndarray) -> list[Boxed]:
        """Each box's points in this frame (rules 1-3), kept with the
        frame's cloud while the frame repeats: a robot at rest sends the same pose, depth and
        boxes after every decision."""
        last = self._last
        self._repeat = last is not None and (np.array_equal(last.pose, pose) and np.array_equal(last.depth, depth)
                                             and np.array_equal(last.boxes, boxes))
        if not self._repeat:
            cloud = self._cloud(np.asarray(pose)[None], np.asarray(depth)[None], self.rays, self.cfg)
            self._last = last = _Seen(np.array(pose), np.array(depth), np.array(boxes), cloud,
                                      self._box_points(cloud, np.asarray(boxes, np.float64)))
        return last.voxels

    def _box_points(self, cloud: Cloud, boxes: np.ndarray) -> list[Boxed]:
        """Each box's points (boxes (D, 4)) in a one-frame cloud (rules 1-3)."""
        cfg, kind = self.cfg, cloud.depth.dtype.type  # margins in the depth's precision, as numpy adds them
        keys, points, key_at, cells, cell_at, core, core_at = boxes_pass(
            boxes, cloud.valid[0], cloud.depth, cloud.x, cloud.y, cloud.z, cloud.part, cloud.size, float(cfg.voxel),
            float(cfg.cell), float(cfg.inside), float(cfg.min_share), float(cfg.front_share), kind(cfg.behind),
            float(cfg.part_share), kind(cfg.part_behind))
        return [Boxed(keys[a:b], cells[c:d], points[a:b], core[e:f])
                for a, b, c, d, e, f in zip(key_at[:-1], key_at[1:], cell_at[:-1], cell_at[1:], core_at[:-1],
                                            core_at[1:])]

    def _cloud(self, pose: np.ndarray, depth: np.ndarray, rays: tuple, cfg: PerceivedConfig) -> Cloud:
        """F frames' depth pixels above the floor and off the walls (rule 10), in the world
        frame, cut into segments (each frame's own): pose (F, 3), depth (F, H, W); ``rays``
        the frames' (:func:`depth_rays`). Points higher than ``wall_above`` mark their cells
        as a wall's first, and the map's points in a new wall's cells leave it."""
        pose, depth = np.asarray(pose), np.ascontiguousarray(depth)
        kind = depth.dtype.type  # thresholds in the depth's precision, as numpy takes a Python number beside it
        valid, d, x, y, z, part, size, walls, hit = cloud_pass(  # rays in the camera frame, turned by yaw
            depth, *rays, np.cos(pose[:, 2]), np.sin(pose[:, 2]), np.ascontiguousarray(pose[:, 0]),
            np.ascontiguousarray(pose[:, 1]), float(self.config.mount_height), pose.dtype.type(self.config.mount_x),
            float(cfg.floor_z), self.walls.arrays, self.held.arrays, float(self.cfg.wall_cell),
            float(self.cfg.wall_above), kind(cfg.edge_abs), kind(cfg.edge_rel))
        self._found_walls(walls, hit)
        return Cloud(valid, d, x, y, z, part, size)

    def _off_walls(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Rule 10 on points x, y, z (k,) (as :meth:`_cloud` applies it): which of them lie
        off the walls, after the cells of those higher than ``wall_above`` join the walls."""
        if not np.isfinite(self.cfg.wall_above):
            return np.ones(len(x), bool)
        keep, walls, hit = off_walls(*(np.ascontiguousarray(a, np.float64) for a in (x, y, z)), self.walls.arrays,
                                     self.held.arrays, float(self.cfg.wall_cell), float(self.cfg.wall_above))
        self._found_walls(walls, hit)
        return keep

    def _found_walls(self, walls: tuple, hit: bool) -> None:
        """Rule 10: take back the walls table a pass filled (:attr:`HashTable.arrays`); if a
        new wall cell holds map points (``hit``), they leave the map."""
        self.walls.update(walls)
        if hit:
            self._drop_walled()

    def _plan_cells(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(k,) the plan-view cell keys (``wall_cell``) of points at x, y (k,) (rule 10)."""
        return cube_keys((x, y, np.zeros_like(x)), self.cfg.wall_cell)

    def _associate(self, cells: np.ndarray, label: int, taken: set[int]) -> int:
        """The instance a detection joins, from the instances seen in ``cells``, those of its
        object's segment (rule 4):
        of those holding ``overlap`` of them and not ``taken`` by another detection of the
        frame, the one holding most among those of the detection's label, else among all;
        the others of that label merge into it."""
        held = self._roots()[self.cells.get(cells)]
        counts = np.bincount(held + 1)[1:]  # each instance's cells (instance -1: none)
        ids = np.flatnonzero(counts)
        counts = counts[ids]
        same = np.array([self.label[i] == label for i in ids.tolist()], bool)
        share = counts / len(cells)
        free = np.array([i not in taken for i in ids.tolist()], bool)
        keep = ((share >= self.cfg.overlap) | same & (share >= self.cfg.same_overlap)) & free
        ids, counts, same = ids[keep], counts[keep], same[keep]
        if len(ids):
            pool = same if same.any() else np.ones(len(ids), bool)
            inst = int(ids[pool][np.argmax(counts[pool])])
            for j in ids[same].tolist():
                if j != inst:
                    self._merge(j, inst)
            return inst
        self.pending.append([])
        self.views.append(0)
        self.parent.append(len(self.parent))
        self._root = None
        self.label.append(-1)
        self.conf.append(np.float32(0.0))
        self.box.append(np.array([[np.inf, np.inf], [-np.inf, -np.inf]]))
        self.count.append(0)
        self.extent.append(np.array([[[np.inf] * 3, [-np.inf] * 3]]))
        return len(self.parent) - 1

    def _merge(self, j: int, into: int, relabel: bool = True) -> None:
        """Instance j becomes part of ``into``: its points, views and (if more confident, and
        ``relabel``) label."""
        self.parent[j] = into
        self._root = None
        self.views[into] += self.views[j]
        if relabel and self.conf[j] > self.conf[into]:
            self.label[into], self.conf[into] = self.label[j], self.conf[j]
        self.label[j], self.conf[j] = -1, np.float32(0.0)
        self.pending[into] += self.pending[j]
        self.pending[j] = []
        _cover(self.extent.rows[into], *self.extent.rows[j])
        self._extend(into, *self.box[j], self.count[j])
        self._publish(into)

    def _publish(self, inst: int) -> None:
        """A confirmed instance's pending points join the map's end (rule 6), but for those
        in a wall's cells (rule 10: the wall may have been found since they were seen)."""
        if self.pending[inst] and self._confirmed(inst):
            pts = np.concatenate(self.pending[inst])
            self.pending[inst] = []
            pts, held = publish_pass(pts, self.walls.arrays, self.held.arrays, float(self.cfg.wall_cell))
            self.held.update(held)
            if not len(pts):
                return
            self.points.append(pts)
            self.point_instance.append(np.full(len(pts), inst))
            self._extend(inst, pts[:, :2].min(0), pts[:, :2].max(0), len(pts))

    def _drop_walled(self) -> None:
        """Rule 10: the map's points in cells found to be a wall's leave it (the points after
        them move up), and each instance's plan-view box and count are those of what is left."""
        pts = self.points.rows
        keep = self.walls.get(self._plan_cells(pts[:, 0], pts[:, 1])) < 0
        pts, inst = pts[keep], self.point_instance.rows[keep]
        self.points, self.point_instance = Rows.of(pts), Rows.of(inst)
        roots = self._roots()
        root = roots[inst]
        count = np.bincount(root, minlength=len(self.parent))
        box = np.tile(np.array([[np.inf, np.inf], [-np.inf, -np.inf]]), (len(self.parent), 1, 1))
        np.minimum.at(box[:, 0], root, pts[:, :2])
        np.maximum.at(box[:, 1], root, pts[:, :2])
        for i in np.flatnonzero(roots[:-1] == np.arange(len(self.parent))).tolist():
            self.count[i], self.box[i] = int(count[i]), box[i]

    def _extend(self, inst: int, lo: np.ndarray, hi: np.ndarray, count: int) -> None:
        """Instance ``inst``'s points in the map now include ``count`` more, within the
        plan-view box from ``lo`` to ``hi`` (2,)."""
        if count:
            _cover(self.box[inst], lo, hi)
            self.count[inst] += count
            self._changed.add(inst)

    def _absorb(self) -> None:
        """Rule 9: each confirmed instance mostly over the widened plan-view box of a much
        larger one of its label, or a ``placed`` one over a ``bare`` one, merges into it (of
        several, the one it lies over most; the larger keeps its label), the smallest first;
        only pairs of which one changed since the last call are checked."""
        if not self._changed or self.cfg.absorb > 1:
            self._changed.clear()
            return
        changed, self._changed = self._changed, set()
        ids, own, count, pair = self._part_pairs(changed)
        box = _widened(own, self.cfg.absorb_margin)
        root = None  # each map point's instance, read once if a partial overlap needs the points
        order = np.argsort(count, kind="stable")
        for a in order[pair.any(1)[order]].tolist():
            best, most = -1, self.cfg.absorb
            for b in np.flatnonzero(pair[a]).tolist():
                if ((own[a, 0] >= box[b, 0]) & (own[a, 1] <= box[b, 1])).all():
                    share = 1.0  # its whole box lies inside
                else:
                    if root is None:
                        root = self._roots()[self.point_instance.rows]
                    pts = self.points.rows[root == ids[a], :2]
                    share = ((pts >= box[b, 0]) & (pts <= box[b, 1])).all(-1).mean()
                if share >= most and (best < 0 or share > most):
                    best, most = b, share
            if best >= 0:
                part, whole = int(ids[a]), int(ids[best])
                self._merge(part, whole, relabel=self.label[part] == self.label[whole])
                pair[:, a] = pair[a] = False  # a is gone; best's box has grown
                own[best] = self.box[ids[best]]
                box[best] = _widened(own[best], self.cfg.absorb_margin)
                if root is not None:
                    root[root == ids[a]] = ids[best]

    def _part_pairs(self, changed: set[int]) -> tuple:
        """Rule 9's candidates: ids (K,) the confirmed labelled instances; box (K, 2, 2)
        their plan-view boxes; count (K,) their points; pair (K, K) whether a may be a part
        of b: its box meets b's widened by ``absorb_margin``, same label (or a's ``placed``
        and b's ``bare``), under ``absorb_size`` of b's points, and one of the two among the
        ``changed`` instances."""
        cfg, touched = self.cfg, np.zeros(len(self.parent), bool)
        touched[list(changed)] = True
        count, label = np.array(self.count), np.array(self.label)
        ids = np.flatnonzero((self._roots()[:-1] == np.arange(len(self.parent))) & (count > 0) & (label >= 0))
        box = np.array(self.box).reshape(-1, 2, 2)[ids]
        count, label, touched = count[ids], label[ids], touched[ids]
        m = cfg.absorb_margin
        meet = ((box[:, None, 0] <= box[None, :, 1] + m) & (box[:, None, 1] >= box[None, :, 0] - m)).all(-1)
        on_seat = _member(self._placed, label)[:, None] & _member(self._bare, label)[None]
        kin = (label[:, None] == label[None]) | on_seat
        pair = (meet & kin & (count[:, None] < cfg.absorb_size * count[None])
                & (touched[:, None] | touched[None]))
        return ids, box, count, pair


def _ranks(rank: np.ndarray | int, n: int) -> np.ndarray:
    """(n,) int64 ranks: ``rank`` itself, or n copies of one."""
    return np.full(n, rank, np.int64) if np.isscalar(rank) else np.ascontiguousarray(rank, np.int64)


def _member(mask: np.ndarray, label: np.ndarray) -> np.ndarray:
    """(K,) whether each of ``label`` (K,) (category indices, >= 0) is one of those ``mask``
    (categories,) marks; a label beyond the categories is none of them."""
    out = label < len(mask)
    out[out] = mask[label[out]]
    return out


def _cover(box: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
    """Grow ``box`` (2, D) (lower corner, upper corner) in place to hold the box from ``lo``
    to ``hi`` (D,)."""
    np.minimum(box[0], lo, out=box[0])
    np.maximum(box[1], hi, out=box[1])


def _widened(box: np.ndarray, margin: float) -> np.ndarray:
    """Boxes (..., 2, D) (lower corner, upper corner) grown by ``margin`` on every side."""
    return box + np.array([[-margin], [margin]])
