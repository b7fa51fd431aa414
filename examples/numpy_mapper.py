"""A mapper plugin in plain numpy: box pixels back-projected with the camera's intrinsics and
pose, 5 cm voxels, one instance per label and place.

    rosmeery run --worlds small_office --detector oracle --mapper oracle,examples/numpy_mapper.py:VoxelMapper

Each detection keeps the box's pixels within 0.3 m of their median depth (the object, not
the wall behind), joins the nearest instance of the same label whose centre lies within
0.6 m, or starts one; an instance keeps its most confident detection's confidence.
"""

import numpy as np

from rosmeery_jax import Mapper, MapState

VOXEL, BAND, NEAR = 0.05, 0.3, 0.6  # m


class VoxelMapper(Mapper):
    name = "voxel_numpy"

    def __init__(self, camera, categories):
        super().__init__(camera, categories)
        v, u = np.mgrid[0:camera.height, 0:camera.width]
        pixels = np.stack([u, v, np.ones_like(u)], -1).astype(np.float64)
        self.rays = pixels @ np.linalg.inv(camera.intrinsics).T  # (H, W, 3): a point is ray * depth
        self.voxels: list[dict] = []  # per instance: voxel key -> point
        self.label: list[int] = []
        self.conf: list[float] = []

    def add(self, frame):
        for box, label, conf in zip(frame.boxes, frame.labels, frame.confidences):
            if label < 0:
                continue
            x1, y1, x2, y2 = np.clip(np.round(box).astype(int), 0, [self.camera.width, self.camera.height] * 2)
            depth = frame.depth[y1:y2, x1:x2]
            keep = depth > 0
            if keep.sum() < 3:
                continue
            keep &= np.abs(depth - np.median(depth[keep])) <= BAND
            cam = self.rays[y1:y2, x1:x2][keep] * depth[keep][:, None]
            world = cam @ frame.camera_pose[:3, :3].T + frame.camera_pose[:3, 3]
            self._join(world, int(label), float(conf))

    def _join(self, points, label, conf):
        centre = points.mean(0)
        near = [i for i, lab in enumerate(self.label)
                if lab == label and np.linalg.norm(self._centre(i) - centre) < NEAR]
        if near:
            i = min(near, key=lambda i: np.linalg.norm(self._centre(i) - centre))
        else:
            i = len(self.label)
            self.voxels.append({})
            self.label.append(label)
            self.conf.append(0.0)
        self.conf[i] = max(self.conf[i], conf)
        for key, p in zip(map(tuple, np.floor(points / VOXEL).astype(int)), points):
            self.voxels[i].setdefault(key, p)

    def _centre(self, i):
        return np.mean(list(self.voxels[i].values()), 0)

    def semantic_map(self):
        points = [np.array(list(v.values())).reshape(-1, 3) for v in self.voxels]
        instance = [np.full(len(p), i) for i, p in enumerate(points)]
        return MapState(np.concatenate(points) if points else np.zeros((0, 3)),
                        np.concatenate(instance) if instance else np.zeros(0, np.int64),
                        np.array(self.label, np.int64), np.array(self.conf))
