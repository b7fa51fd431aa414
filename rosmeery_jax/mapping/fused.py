"""The fused mapper (``--mapper fused``): a semantic map that fuses evidence over frames,
so that noisy depth and a drifting pose estimate blur it rather than break it. Specified
in docs/mapping.md; its settings are :class:`FusedConfig`.

Geometry: a sparse voxel map (``voxel`` m) with a hit and a miss weight per voxel, updated
projectively as a truncated signed distance volume is (Curless and Levoy 1996; Voxblox):
each frame's plausible depth pixels inside a detection create voxels, and every voxel
held that projects into the frame onto a plausible pixel is seen again: a hit when the
pixel's depth lies within ``truncation`` of the voxel's, a miss when the camera sees
through it (the pixel lies more than ``truncation`` beyond it). A measurement weighs
``min(1, sigma(1 m) / sigma(z))`` for the axial noise of a Kinect-class camera, sigma(z) =
0.0012 + 0.0019 (z - 0.4)^2 m: far returns count less. Plausible pixels: a return inside
the range, not an edge (no 4-neighbour further away in depth than ``edge_rel`` of it:
mixed pixels), above ``floor_z``.

Semantics: each detection votes its label, with its confidence, into the voxels of its
segment (its box's plausible pixels on its nearest surface: within ``segment`` m of the
box's ``near_quantile`` depth): a log posterior over the categories per voxel, updated the
Bayesian way (the detector names the true category with probability ``confidence``, any
other alike).

Instances: the connected components (26-neighbourhood) of the occupied voxels (hits at
least ``min_weight`` and more than misses) that share their posterior's mode; voxels a
few centimetres apart (pose error) touch and stay one instance. An instance's label and
confidence are the mode and mass of its voxels' distributions summed by hit weight; it
needs ``min_voxels`` voxels and votes from ``min_views`` frames. The map exported and
scored is the instances' voxel centres.

Pose: each frame's pose is the robot's estimate (what the session hands every mapper).
Shapes: H x W the frame, D detections, V voxels, C categories, P points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from rosmeery_jax.mapping.protocol import Camera, Frame, Mapper, MapState

_BIAS = 1 << 20  # voxel indices are offset by this before packing (21 bits each: +-5 km at 5 mm)
_NEIGHBOURS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                        if (i, j, k) > (0, 0, 0)], np.int64)  # half of the 26: each pair once


@dataclass(frozen=True)
class FusedConfig:
    voxel: float = 0.05  # m: the voxels' edge
    truncation: float = 0.1  # m: a pixel this close to a voxel's depth sees it (>= voxel)
    edge_rel: float = 0.05  # a pixel with a 4-neighbour further than this share of its depth away is mixed
    floor_z: float = 0.03  # m: points lower than this are floor
    segment: float = 0.3  # m: a detection's segment lies within this of its box's near depth
    near_quantile: float = 0.1  # the box's near depth: this quantile of its plausible pixels' depths
    min_weight: float = 0.3  # hit weight an occupied voxel needs (one return at 1 m weighs 1)
    min_voxels: int = 3  # voxels an instance needs
    min_views: int = 2  # frames whose detections voted into an instance

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)):
                raise ValueError(f"fused mapper: {f.name} must be a finite number, not {v!r}")
        if self.voxel <= 0 or self.truncation < self.voxel:
            raise ValueError(f"fused mapper: voxel must be > 0 m and truncation at least the voxel "
                             f"(voxel {self.voxel!r}, truncation {self.truncation!r})")
        if not (0 < self.near_quantile < 1 and self.edge_rel > 0 and self.segment > 0):
            raise ValueError("fused mapper: near_quantile must lie in (0, 1), edge_rel and segment be > 0")


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
        self.views = np.zeros(0, np.int64)  # frames that voted into each voxel
        self._voted = np.zeros(0, np.int64)  # the last frame that voted (counted once per frame)
        self.frames = 0

    # -- feeding -----------------------------------------------------------------------
    def add(self, frame: Frame) -> None:
        cfg = self.cfg
        depth = np.asarray(frame.depth, np.float64)
        pose = np.asarray(frame.camera_pose, np.float64)
        if depth.ndim != 2 or pose.shape != (4, 4) or not np.isfinite(pose).all():
            return  # nothing defined to fuse
        k = np.asarray(self.camera.intrinsics, np.float64)
        ok = plausible(depth, self.camera.config.max_range, cfg.edge_rel)
        world = self._backproject(depth, pose, k)  # (H, W, 3)
        ok &= world[..., 2] > cfg.floor_z
        self.frames += 1
        self._see(depth, ok, pose, k)
        for box, label, conf in zip(np.asarray(frame.boxes, np.float64).reshape(-1, 4),
                                    np.asarray(frame.labels, np.int64).reshape(-1),
                                    np.asarray(frame.confidences, np.float64).reshape(-1)):
            if 0 <= label < self.c and np.isfinite(conf) and np.isfinite(box).all():
                seg = self._segment(depth, ok, box)
                if seg.any():
                    self._vote(world[seg], depth[seg], int(label), float(np.clip(conf, 1e-3, 1 - 1e-3)))

    def _backproject(self, depth: np.ndarray, pose: np.ndarray, k: np.ndarray) -> np.ndarray:
        h, w = depth.shape
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        cam = np.stack([(u - k[0, 2]) / k[0, 0] * depth, (v - k[1, 2]) / k[1, 1] * depth, depth], -1)
        return cam @ pose[:3, :3].T + pose[:3, 3]

    def _segment(self, depth: np.ndarray, ok: np.ndarray, box: np.ndarray) -> np.ndarray:
        """(H, W) bool: the box's plausible pixels on its nearest surface."""
        h, w = depth.shape
        x1, y1 = max(0, int(np.floor(box[0]))), max(0, int(np.floor(box[1])))
        x2, y2 = min(w, int(np.ceil(box[2])) + 1), min(h, int(np.ceil(box[3])) + 1)
        seg = np.zeros_like(ok)
        inside = ok[y1:y2, x1:x2]
        if not inside.any():
            return seg
        d = depth[y1:y2, x1:x2]
        near = np.quantile(d[inside], self.cfg.near_quantile)
        seg[y1:y2, x1:x2] = inside & (d <= near + self.cfg.segment)
        return seg

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
        uniq, first = np.unique(keys, return_index=True)
        at = self._lookup(uniq)
        new = at < 0
        if new.any():
            self._grow(uniq[new], weight(depth[first[new]]))
            at = self._lookup(uniq)
        like = np.full(self.c, math.log((1 - conf) / max(1, self.c - 1)))
        like[label] = math.log(conf)
        self.logp[at] += like
        fresh = self._voted[at] != self.frames
        self.views[at[fresh]] += 1
        self._voted[at] = self.frames

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
        if not len(self.keys):
            return np.full(len(keys), -1, np.int64)
        pos = np.minimum(np.searchsorted(self.keys, keys, sorter=self._order), len(self.keys) - 1)
        at = self._order[pos]
        return np.where(self.keys[at] == keys, at, -1)

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
        new_id = np.cumsum(keep) - 1
        chosen = keep[comp]
        mass = mass[keep]
        label = np.argmax(mass, 1)
        conf = mass[np.arange(len(mass)), label] / np.maximum(mass.sum(1), 1e-300)
        return MapState(self.centres()[occupied[chosen]], new_id[comp[chosen]].astype(np.int64),
                        label.astype(np.int64), conf.astype(np.float32))

    def _components(self, voxels: np.ndarray, mode: np.ndarray) -> np.ndarray:
        """(K,) component of each of ``voxels`` (K,): 26-neighbours with the same ``mode``."""
        ijk = self._ijk(self.keys[voxels])
        keys = self.keys[voxels]
        order = np.argsort(keys)
        rows, cols = [], []
        for off in _NEIGHBOURS:
            nb = _pack(ijk + off)
            pos = np.minimum(np.searchsorted(keys, nb, sorter=order), len(keys) - 1)
            j = order[pos]
            link = (keys[j] == nb) & (mode[j] == mode)
            rows.append(np.flatnonzero(link))
            cols.append(j[link])
        r, c = np.concatenate(rows), np.concatenate(cols)
        graph = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(len(keys), len(keys)))
        return connected_components(graph, directed=False)[1]


def _pack(ijk: np.ndarray) -> np.ndarray:
    """(P,) int64 keys of voxel indices (P, 3)."""
    ijk = np.clip(ijk + _BIAS, 0, (1 << 21) - 1)
    return (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]


def _empty() -> MapState:
    return MapState(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32))
