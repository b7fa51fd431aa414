"""The fused mapper (``--mapper fused``): a semantic map that fuses evidence over frames,
so that noisy depth and a drifting pose estimate blur it rather than break it. Specified
in docs/mapping.md; its settings are :class:`FusedConfig`.

Depth: a pixel is plausible with a finite return inside the range, above ``floor_z``, and
no 4-neighbour further than ``edge_rel`` of its depth away (mixed pixels at edges).

Geometry: a sparse voxel map (``voxel`` m) with a hit and a miss weight per voxel, updated
projectively as a truncated signed distance volume is (Curless and Levoy 1996; Voxblox):
every voxel held that projects onto a plausible pixel of a new frame is a hit when the
pixel's depth lies within ``truncation`` of the voxel's, a miss when the camera sees
through it. A return weighs ``min(1, sigma(1 m) / sigma(z))`` for the axial noise of a
Kinect-class camera, sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2 m: far returns count less.

Semantics: each detection's object points (the perceived mapper's depth segments, rules
1-3 and 10 of docs/mapping.md, on the plausible pixels) vote its label, with its
confidence, into their voxels (made where new): a log posterior over the categories per
voxel, updated the Bayesian way (the detector names the true category with probability
``confidence``, any other alike). The map keeps the first point of each half-voxel.

Instances: the connected components of the occupied voxels (hits above ``min_weight`` and
above misses) that share their posterior's mode, voxels within ``reach`` voxels along each
axis joined (a pose error of a few centimetres keeps an object one instance). An
instance's label and confidence are the mode and mass of its voxels' distributions summed
by hit weight; it needs ``min_voxels`` voxels and votes from ``min_views`` frames. The map
exported and scored is its voxels' points.

Pose: each frame's pose is the robot's estimate (what the session hands every mapper).
Shapes: H x W the frame, V voxels, C categories, P points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from rosmeery_jax.mapping.config import PerceivedConfig
from rosmeery_jax.mapping.perceived import PerceivedMapper
from rosmeery_jax.mapping.protocol import Camera, Frame, Mapper, MapState

_BIAS = 1 << 20  # voxel indices are offset by this before packing (21 bits each: +-5 km at 5 mm)


_NEIGHBOURS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                        if (i, j, k) > (0, 0, 0)], np.int64)  # half of the 26 (each pair once)


@dataclass(frozen=True)
class FusedConfig:
    voxel: float = 0.05  # m: the voxels' edge
    truncation: float = 0.1  # m: a pixel this close to a voxel's depth sees it (>= voxel)
    edge_rel: float = 0.2  # a pixel with a 4-neighbour further than this share of its depth away is mixed
    floor_z: float = 0.03  # m: points lower than this are floor
    min_weight: float = 0.0  # hit weight an occupied voxel needs, besides more hits than misses (a return at 1 m weighs 1)
    min_voxels: int = 3  # voxels an instance needs
    min_views: int = 2  # frames whose detections voted into an instance
    reach: int = 3  # voxels: occupied voxels this close along each axis join one instance

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)):
                raise ValueError(f"fused mapper: {f.name} must be a finite number, not {v!r}")
        if self.voxel <= 0 or self.truncation < self.voxel:
            raise ValueError(f"fused mapper: voxel must be > 0 m and truncation at least the voxel "
                             f"(voxel {self.voxel!r}, truncation {self.truncation!r})")
        if self.edge_rel <= 0 or self.reach < 1:
            raise ValueError(f"fused mapper: edge_rel must be > 0 and reach at least 1 (edge_rel {self.edge_rel!r}, "
                             f"reach {self.reach!r})")


def weight(z: np.ndarray) -> np.ndarray:
    """A return's weight at depth ``z`` (m): sigma(1 m) / sigma(z), at most 1."""
    sigma = lambda d: 0.0012 + 0.0019 * (d - 0.4) ** 2  # noqa: E731  (Nguyen et al. 2012)
    return np.minimum(1.0, sigma(1.0) / sigma(np.asarray(z, np.float64)))


def plausible(depth: np.ndarray, max_range: float, edge_rel: float) -> np.ndarray:
    """(H, W) bool: a finite return inside (0, max_range) whose 4-neighbours with a return
    lie within ``edge_rel`` of its depth (mixed and edge pixels fail)."""
    d = np.where(np.isfinite(depth), depth, 0.0).astype(np.float64)
    ok = (d > 0) & (d < max_range)
    p = np.pad(d, 1, mode="edge")
    for nb in (p[:-2, 1:-1], p[2:, 1:-1], p[1:-1, :-2], p[1:-1, 2:]):
        ok &= ~((nb > 0) & (np.abs(nb - d) > edge_rel * d))
    return ok


class FusedMapper(Mapper):
    """One robot's fused map (module docstring), fed frame by frame on the host."""

    name = "fused"

    def __init__(self, camera: Camera, categories: tuple[str, ...] = (), cfg: FusedConfig = FusedConfig()):
        super().__init__(camera, categories)
        self.cfg = cfg
        self.c = max(1, len(categories))
        self.keys = np.zeros(0, np.int64)  # (V,) packed voxel indices, in order of creation
        self._order = np.zeros(0, np.int64)  # keys' argsort, for lookups
        self.hit = np.zeros(0, np.float64)
        self.miss = np.zeros(0, np.float64)
        self.logp = np.zeros((0, self.c), np.float64)  # log posterior up to a constant
        # the map's points: the first point voted into each half-voxel, with its voxel
        self.point_keys = np.zeros(0, np.int64)
        self._point_order = np.zeros(0, np.int64)
        self.points = np.zeros((0, 3), np.float64)
        self.point_voxel = np.zeros(0, np.int64)
        self.views = np.zeros(0, np.int64)  # frames that voted into each voxel
        self._voted = np.zeros(0, np.int64)  # the last frame that voted (counted once per frame)
        self.frames = 0
        # each detection's object points: the perceived mapper's depth segments and rules
        # 1-3 and 10 (docs/mapping.md), its association and instances unused
        self._segmenter = PerceivedMapper(camera, categories, PerceivedConfig(voxel=cfg.voxel / 2))

    # -- feeding -----------------------------------------------------------------------
    def add(self, frame: Frame) -> None:
        cfg = self.cfg
        depth = np.asarray(frame.depth, np.float64)
        pose = np.asarray(frame.camera_pose, np.float64)
        if depth.ndim != 2 or pose.shape != (4, 4) or not np.isfinite(pose).all():
            return  # nothing defined to fuse
        k = np.asarray(self.camera.intrinsics, np.float64)
        ok = plausible(depth, self.camera.config.max_range, cfg.edge_rel)
        ok &= self._height(depth, pose, k) > cfg.floor_z
        self.frames += 1
        self._see(depth, ok, pose, k)
        plain = np.where(ok, depth, 0.0).astype(np.float32)  # implausible pixels read as no return
        keep = np.asarray(frame.labels) >= 0
        boxes = np.asarray(frame.boxes, np.float64).reshape(-1, 4)[keep]
        for boxed, label, conf in zip(self._segmenter._frame_voxels(np.asarray(frame.pose), plain, boxes),
                                      np.asarray(frame.labels, np.int64)[keep],
                                      np.asarray(frame.confidences, np.float64)[keep]):
            if label < self.c and np.isfinite(conf) and len(boxed.points):
                self._vote(boxed.points, self._depth_of(boxed.points, pose), int(label),
                           float(np.clip(conf, 1e-3, 1 - 1e-3)))

    @staticmethod
    def _depth_of(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """(P,) the points' depth along the optical axis of the camera at ``pose`` (4, 4)."""
        return (points - pose[:3, 3]) @ pose[:3, 2]

    @staticmethod
    def _height(depth: np.ndarray, pose: np.ndarray, k: np.ndarray) -> np.ndarray:
        """(H, W) each pixel's world z (its back-projected point's height)."""
        h, w = depth.shape
        u, v = np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)[:, None]
        r = pose[2, :3]  # the world z row of the camera's rotation
        return depth * (r[0] * (u - k[0, 2]) / k[0, 0] + r[1] * (v - k[1, 2]) / k[1, 1] + r[2]) + pose[2, 3]

    def _see(self, depth: np.ndarray, ok: np.ndarray, pose: np.ndarray, k: np.ndarray) -> None:
        """Every voxel held that projects onto a plausible pixel: a hit or a miss."""
        if not len(self.keys):
            return
        cam = (self.centres() - pose[:3, 3]) @ pose[:3, :3]  # camera frame (V, 3)
        z = cam[:, 2]
        front = z > 1e-6
        u = np.full(len(z), -1, np.int64)
        v = np.full(len(z), -1, np.int64)
        u[front] = np.round(k[0, 0] * cam[front, 0] / z[front] + k[0, 2]).astype(np.int64)
        v[front] = np.round(k[1, 1] * cam[front, 1] / z[front] + k[1, 2]).astype(np.int64)
        h, w = depth.shape
        inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        idx = np.flatnonzero(inside)
        idx = idx[ok[v[idx], u[idx]]]
        d = depth[v[idx], u[idx]]
        wt = weight(d)
        t = self.cfg.truncation
        hit, miss = np.abs(d - z[idx]) <= t, d > z[idx] + t
        self.hit[idx[hit]] += wt[hit]
        self.miss[idx[miss]] += wt[miss]

    def _vote(self, points: np.ndarray, depth: np.ndarray, label: int, conf: float) -> None:
        """One detection's segment (P, 3) with depths (P,): its voxels (made where new, with
        the return's hit weight) take the label's likelihood once each."""
        keys = self._keys(points)
        uniq, first, back = np.unique(keys, return_index=True, return_inverse=True)
        at = self._lookup(uniq)
        new = at < 0
        if new.any():
            self._grow(uniq[new], weight(depth[first[new]]))
            at = self._lookup(uniq)
        like = np.full(self.c, math.log((1 - conf) / max(1, self.c - 1)))
        like[label] = math.log(conf)
        self.logp[at] += like
        self._keep_points(points, at[back])
        fresh = self._voted[at] != self.frames
        self.views[at[fresh]] += 1
        self._voted[at] = self.frames

    def _keep_points(self, points: np.ndarray, voxel: np.ndarray) -> None:
        """The first of ``points`` (P, 3) in each half-voxel the map has no point in yet,
        kept with its voxel (P,)."""
        keys = _pack(np.floor(points / (self.cfg.voxel / 2)).astype(np.int64))
        keys, first = np.unique(keys, return_index=True)
        new = _find(self.point_keys, self._point_order, keys) < 0
        if new.any():
            self.point_keys = np.concatenate([self.point_keys, keys[new]])
            self._point_order = np.argsort(self.point_keys, kind="stable")
            self.points = np.concatenate([self.points, points[first[new]]])
            self.point_voxel = np.concatenate([self.point_voxel, voxel[first[new]]])

    # -- voxels ---------------------------------------------------------------------------
    def _keys(self, points: np.ndarray) -> np.ndarray:
        return _pack(np.floor(np.asarray(points, np.float64) / self.cfg.voxel).astype(np.int64))

    @staticmethod
    def _ijk(keys: np.ndarray) -> np.ndarray:
        mask = (1 << 21) - 1
        return np.stack([keys >> 42, (keys >> 21) & mask, keys & mask], -1) - _BIAS

    def centres(self) -> np.ndarray:
        """(V, 3) the voxels' centres."""
        return (self._ijk(self.keys) + 0.5) * self.cfg.voxel

    def _lookup(self, keys: np.ndarray) -> np.ndarray:
        """Each key's voxel index (-1: not held)."""
        return _find(self.keys, self._order, keys)

    def _grow(self, keys: np.ndarray, hit: np.ndarray) -> None:
        n = len(keys)
        self.keys = np.concatenate([self.keys, keys])
        self._order = np.argsort(self.keys, kind="stable")
        self.hit = np.concatenate([self.hit, hit])
        self.miss = np.concatenate([self.miss, np.zeros(n)])
        self.logp = np.concatenate([self.logp, np.zeros((n, self.c))])
        self.views = np.concatenate([self.views, np.zeros(n, np.int64)])
        self._voted = np.concatenate([self._voted, np.full(n, -1, np.int64)])

    # -- the map --------------------------------------------------------------------------
    def semantic_map(self) -> MapState:
        cfg = self.cfg
        occupied = np.flatnonzero((self.hit >= cfg.min_weight) & (self.hit > self.miss) & (self.views > 0))
        if not len(occupied):
            return _empty()
        mode = np.argmax(self.logp[occupied], 1)
        comp = self._components(occupied, mode)
        p = np.exp(self.logp[occupied] - self.logp[occupied].max(1, keepdims=True))
        p /= p.sum(1, keepdims=True)
        n = comp.max() + 1
        mass = np.zeros((n, self.c))
        np.add.at(mass, comp, p * self.hit[occupied, None])
        size = np.bincount(comp, minlength=n)
        views = np.zeros(n, np.int64)
        np.maximum.at(views, comp, self.views[occupied])
        keep = (size >= cfg.min_voxels) & (views >= cfg.min_views)
        mass = mass[keep]
        label = np.argmax(mass, 1)
        conf = mass[np.arange(len(mass)), label] / np.maximum(mass.sum(1), 1e-300)
        instance = np.full(len(self.keys), -1, np.int64)  # per voxel: its instance in the map (-1 none)
        instance[occupied] = np.where(keep[comp], (np.cumsum(keep) - 1)[comp], -1)
        point_instance = instance[self.point_voxel]
        chosen = point_instance >= 0
        return MapState(self.points[chosen], point_instance[chosen], label.astype(np.int64), conf.astype(np.float32))

    def _components(self, voxels: np.ndarray, mode: np.ndarray) -> np.ndarray:
        """(K,) component of each of ``voxels`` (K,): voxels of one ``mode`` in the same or
        neighbouring (26) cells of ``reach`` voxels join."""
        coarse = np.floor_divide(self._ijk(self.keys[voxels]), self.cfg.reach)
        comp, base = np.zeros(len(voxels), np.int64), 0
        for label in np.unique(mode):  # a few labels: the cells of each apart
            mine = np.flatnonzero(mode == label)
            cells, back = np.unique(_pack(coarse[mine]), return_inverse=True)
            ijk = self._ijk(cells)
            rows, cols = [np.arange(len(cells))], [np.arange(len(cells))]
            for off in _NEIGHBOURS:
                j = _find(cells, np.arange(len(cells)), _pack(ijk + off))  # cells are sorted
                rows.append(np.flatnonzero(j >= 0))
                cols.append(j[j >= 0])
            r, c = np.concatenate(rows), np.concatenate(cols)
            n, labels = connected_components(coo_matrix((np.ones(len(r), np.int8), (r, c)),
                                                        shape=(len(cells), len(cells))), directed=False)
            comp[mine] = base + labels[back]
            base += n
        return comp


def _find(keys: np.ndarray, order: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """Each of ``wanted``'s index in ``keys`` (sorted by ``order``), -1 where absent."""
    if not len(keys):
        return np.full(len(wanted), -1, np.int64)
    pos = np.minimum(np.searchsorted(keys, wanted, sorter=order), len(keys) - 1)
    at = order[pos]
    return np.where(keys[at] == wanted, at, -1)


def _pack(ijk: np.ndarray) -> np.ndarray:
    """(P,) int64 keys of voxel indices (P, 3)."""
    ijk = np.clip(ijk + _BIAS, 0, (1 << 21) - 1)
    return (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]


def _empty() -> MapState:
    return MapState(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32))
