"""The perceived mapper: a semantic map built only from what the robot perceives.

The built-in knowledge (:mod:`rosmeery_jax.sim.knowledge`) ties every detection to an object
through the ground-truth segmentation, so a real mapper's errors never show. This mapper
uses none of that: per detector frame, the depth pixels inside each detection box are
back-projected with the robot's pose, and the points join an instance by overlap. The map
is scored by the same evaluator as a user's map (:mod:`rosmeery_jax.scoring.evaluate`), so boxes
that spill onto the wall or a neighbour, objects merged or split, and labels on the wrong
instance all lower the scores.

Per detection (box, label, confidence) in a frame:

1. **Points**: the box's pixels with a depth return, back-projected to the world; pixels
   more than ``depth_band`` from the box's median depth (background behind the object or
   a nearer occluder) and points below ``floor_z`` (the floor, whose height the robot
   knows) are dropped.
2. **Voxels**: points are binned into ``voxel`` cubes; a voxel belongs to the first
   instance that claimed it and keeps its first point (a point on the surface, so it ties
   to a sample like any mapper's point).
3. **Association**: the instance owning the most of the detection's voxels takes it if it
   owns at least ``overlap`` of them; otherwise the detection starts a new instance. The
   detection's unclaimed voxels join that instance.
4. **Label**: an instance holds the label of its most confident detection so far, the
   built-in knowledge's rule.

Policies still decide on the built-in knowledge: this mapper only scores what a mapper fed
the same frames would hold. Shapes: H x W the detector frame, D detections, V voxels, I
instances, F frames, N objects.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import repeat

import numpy as np

from rosmeery_jax.scoring.mapper import Camera, Frame, Mapper, MapState
from rosmeery_jax.sim.sensors import camera_rays


@dataclass(frozen=True)
class PerceivedConfig:
    voxel: float = 0.05  # m: the surface samples' spacing, so a voxel holds about one sample
    depth_band: float = 0.5  # m: a box keeps pixels within this of its median depth
    floor_z: float = 0.03  # m: points lower than this are floor
    overlap: float = 0.2  # share of a detection's voxels an instance must own to take it
    min_voxels: int = 3  # detections with fewer voxels are dropped (a few stray pixels)


class PerceivedMapper(Mapper):
    """One env's perceived map, fed frame by frame (host side, numpy), through the mapper
    protocol (:mod:`rosmeery_jax.scoring.mapper`)."""

    name = "perceived"

    def __init__(self, camera: Camera, categories: tuple[str, ...] = (), cfg: PerceivedConfig = PerceivedConfig()):
        super().__init__(camera, categories)
        self.cfg = cfg
        camera = self.config = camera.config  # the benchmark's camera settings: mount and rays
        w, h = camera.rgb_width, camera.rgb_height
        rays = camera_rays(camera, w, h)  # (H*W, 3) camera frame, unit
        axis = np.array([np.cos(camera.pitch), 0.0, -np.sin(camera.pitch)])
        rays = (rays / (rays @ axis)[:, None]).reshape(h, w, 3)  # a point is ray * depth
        self.rays = tuple(np.ascontiguousarray(rays[..., i]) for i in range(3))  # (H, W) each: x, y, z
        self.owner: dict[int, int] = {}  # voxel key -> instance
        self.points: list[np.ndarray] = []  # per claimed voxel batch: (k, 3)
        self.point_instance: list[np.ndarray] = []
        self.label: list[int] = []  # per instance: the held label (-1 none) and its confidence (step 4)
        self.conf: list[float] = []
        self.instances = 0
        self._last: tuple | None = None  # (pose, depth, {box bytes: voxels}) of the latest frame

    def add(self, frame: Frame) -> None:
        self.fold(frame.pose, frame.depth, frame.boxes, frame.labels, frame.confidences)

    def semantic_map(self) -> MapState:
        """The map of every frame folded so far."""
        if self.points:
            points, instance = np.concatenate(self.points), np.concatenate(self.point_instance)
        else:
            points, instance = np.zeros((0, 3)), np.zeros(0, np.int64)
        return MapState(points, instance, np.array(self.label, np.int32), np.array(self.conf, np.float32))

    def fold(self, pose: np.ndarray, depth: np.ndarray, boxes: np.ndarray, label: np.ndarray,
             conf: np.ndarray) -> None:
        """Fold one frame: pose (3,) x, y, yaw; depth (H, W) (0 = no return); boxes (D, 4)
        pixel corners x1, y1, x2, y2; label (D,) category index (-1 = padding); conf (D,)."""
        memo = self._frame_memo(pose, depth)
        for box, k, c in zip(boxes, label, conf):
            if k < 0:
                continue
            if (key := box.tobytes()) not in memo:
                memo[key] = self._voxels(pose, depth, box)
            keys, pts = memo[key]
            if len(keys) < max(self.cfg.min_voxels, 1):
                continue
            owners = np.fromiter(map(self.owner.get, keys.tolist(), repeat(-1)), np.int64, len(keys))
            inst = self._associate(owners)
            new = owners < 0
            self.owner.update(dict.fromkeys(keys[new].tolist(), inst))
            if new.any():
                self.points.append(pts[new])
                self.point_instance.append(np.full(int(new.sum()), inst, np.int64))
            if np.float32(c) > self.conf[inst]:  # the most confident so far; ties keep the older
                self.label[inst], self.conf[inst] = int(k), np.float32(c)

    def _frame_memo(self, pose: np.ndarray, depth: np.ndarray) -> dict:
        """The voxels of each box already seen in this frame, kept while the frame repeats: a
        robot at rest sends the same pose and depth after every decision, and a box's voxels
        depend on pose, depth and box alone."""
        last = self._last
        if last is None or not (np.array_equal(last[0], pose) and np.array_equal(last[1], depth)):
            self._last = last = (np.array(pose), np.array(depth), {})
        return last[2]

    def _voxels(self, pose: np.ndarray, depth: np.ndarray, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The detection's distinct voxel keys (V,) ascending and the first of its points in
        each, (V, 3) in the world frame (steps 1-2). Per column and only for the points kept,
        which is where the time goes; each value is computed as for a whole (P, 3) cloud."""
        h, w = depth.shape
        x1, y1 = int(np.clip(np.floor(box[0]), 0, w)), int(np.clip(np.floor(box[1]), 0, h))
        x2, y2 = int(np.clip(np.ceil(box[2]), 0, w)), int(np.clip(np.ceil(box[3]), 0, h))
        d = depth[y1:y2, x1:x2]
        valid = d > 0
        if not valid.any():
            return np.zeros(0, np.int64), np.zeros((0, 3))
        valid &= np.abs(d - _median(d[valid])) <= self.cfg.depth_band
        d = d[valid]
        rx, ry, rz = (r[y1:y2, x1:x2][valid] for r in self.rays)
        z = self.config.mount_height + rz * d
        up = z >= self.cfg.floor_z  # the floor's points are dropped before the rest is computed
        d, rx, ry, z = d[up], rx[up], ry[up], z[up]
        px, py = rx * d, ry * d  # camera frame, x forward
        c, s = np.cos(pose[2]), np.sin(pose[2])
        x = pose[0] + self.config.mount_x * c + c * px - s * py
        y = pose[1] + self.config.mount_x * s + s * px + c * py
        cell = [np.floor(a / self.cfg.voxel).astype(np.int64) + (1 << 20) for a in (x, y, z)]
        keys = (cell[0] << 42) | (cell[1] << 21) | cell[2]  # 21 bits per axis: a 100 km cube at 5 cm
        keys, first = np.unique(keys, return_index=True)
        return keys, np.stack([x[first], y[first], z[first]], -1)

    def _associate(self, owners: np.ndarray) -> int:
        """The instance a detection joins, from the owner of each of its voxels (-1 none)
        (step 3)."""
        held = owners[owners >= 0]
        if len(held):
            ids, counts = np.unique(held, return_counts=True)
            best = int(np.argmax(counts))
            if counts[best] >= self.cfg.overlap * len(owners):
                return int(ids[best])
        self.instances += 1
        self.label.append(-1)
        self.conf.append(np.float32(0.0))
        return self.instances - 1


def _median(v: np.ndarray):
    """np.median of a non-empty 1-D array, bitwise (the middle two averaged in v's dtype),
    without its general-purpose overhead."""
    n = len(v)
    part = np.partition(v, [(n - 1) // 2, n // 2])
    return (part[(n - 1) // 2] + part[n // 2]) / 2
