"""The raycast scene: every solid in a world as a yaw-rotated box tagged with its owner.

The fast raycast kernel (docs/performance.md) handles boxes rotated about z, so a world is
stored as G boxes plus the implicit floor plane z = 0. Labels in segmentation images and
in ``object_id`` below: objects are 0..N-1, and these constants mark the rest.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

WALL = -1  # walls and any other static structure that is not an object
FLOOR = -2  # the plane z = 0
NOTHING = -3  # a ray that hits nothing within range


class Scene(NamedTuple):
    """G boxes (float32 / int32 numpy arrays; a pytree, so ``jnp.asarray`` maps over it).

    center: (G, 3) box centres, world frame.
    half:   (G, 3) half extents in the box frame.
    yaw:    (G,)   rotation about +z.
    object_id: (G,) owner: object index >= 0, or WALL.
    rgb:    (G, 3) diffuse colour in [0, 1].
    floor_rgb: (3,) colour of the floor plane.
    geom:   (G,) MuJoCo geom id of each box in the world model.
    """

    center: np.ndarray
    half: np.ndarray
    yaw: np.ndarray
    object_id: np.ndarray
    rgb: np.ndarray
    floor_rgb: np.ndarray
    geom: np.ndarray

    @property
    def num_boxes(self) -> int:
        return int(self.center.shape[0])

    def select(self, mask: np.ndarray) -> "Scene":
        """The boxes where ``mask`` (G,) is set."""
        return self._replace(center=self.center[mask], half=self.half[mask], yaw=self.yaw[mask],
                             object_id=self.object_id[mask], rgb=self.rgb[mask], geom=self.geom[mask])

    def footprint_corners(self) -> np.ndarray:
        """(G, 4, 2) plan corners of every box, counter-clockwise."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        hx, hy = self.half[:, 0], self.half[:, 1]
        local = np.stack(
            [np.stack([-hx, -hy], -1), np.stack([hx, -hy], -1),
             np.stack([hx, hy], -1), np.stack([-hx, hy], -1)], axis=1)
        x = local[..., 0] * c[:, None] - local[..., 1] * s[:, None]
        y = local[..., 0] * s[:, None] + local[..., 1] * c[:, None]
        return np.stack([x, y], -1) + self.center[:, None, :2]

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """Points (P, 3) in every box frame: (P, G, 3)."""
        d = points[:, None, :] - self.center[None]
        c, s = np.cos(self.yaw)[None], np.sin(self.yaw)[None]
        return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], d[..., 2]], -1)

    def inside_any(self, points: np.ndarray, margin: float = 0.0, skip: np.ndarray | None = None,
                   planar: bool = False) -> np.ndarray:
        """(P,) bool: point strictly inside some box shrunk by ``margin`` (``skip`` (P,): a box
        index per point to ignore, e.g. its own). ``planar``: test x and y only.

        Cost grows with points near each box, not points x boxes: a KD-tree over the points
        gives each box the candidates within its bounding circle or sphere."""
        dims = 2 if planar else 3
        out = np.zeros(points.shape[0], dtype=bool)
        if points.shape[0] == 0 or self.num_boxes == 0:
            return out
        tree = cKDTree(points[:, :dims])
        reach = np.linalg.norm(self.half[:, :dims], axis=1)
        for g, idx in enumerate(tree.query_ball_point(self.center[:, :dims], reach + 1e-6)):
            if not idx:
                continue
            idx = np.asarray(idx)
            if skip is not None:
                idx = idx[skip[idx] != g]
            d = points[idx] - self.center[g]
            c, s = np.cos(self.yaw[g]), np.sin(self.yaw[g])
            local = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], -1)[:, :dims]
            hit = np.all(np.abs(local) < self.half[g, :dims] - margin, axis=-1)
            out[idx[hit]] = True
        return out

    def inside(self, points: np.ndarray, margin: float = 0.0, chunk: int = 8192) -> np.ndarray:
        """(P, G) bool: point strictly inside box shrunk by ``margin`` on every side."""
        out = np.empty((points.shape[0], self.num_boxes), dtype=bool)
        for i in range(0, points.shape[0], chunk):
            local = self.to_local(points[i:i + chunk])
            out[i:i + chunk] = np.all(np.abs(local) < self.half[None] - margin, axis=-1)
        return out
