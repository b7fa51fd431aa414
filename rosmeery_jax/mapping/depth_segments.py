"""A depth frame cut into the segments objects are made of, for the perceived mapper
(:mod:`rosmeery_jax.mapping.perceived`): the camera's rays scaled by depth, which box each
pixel lies most inside, and depth segments. Shapes: F
frames, H x W pixels, k valid pixels."""

from __future__ import annotations

import numpy as np

from rosmeery_jax.mapping.kernels import label_segments
from rosmeery_jax.raycast.sensors import camera_rays


def depth_rays(camera, w: int, h: int) -> tuple:
    """The camera's rays at w x h pixels scaled so that a point is ray * depth: x (forward),
    y, z (H, W) each, in the camera's level frame."""
    rays = camera_rays(camera, w, h)  # (H*W, 3) camera frame, unit
    axis = np.array([np.cos(camera.pitch), 0.0, -np.sin(camera.pitch)])
    rays = (rays / (rays @ axis)[:, None]).reshape(h, w, 3)
    return tuple(np.ascontiguousarray(rays[..., i]) for i in range(3))


def box_owner(boxes: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) index of the box each pixel lies most inside (rule 1), -1 outside every box.
    Each box is measured over its own rows and columns only."""
    h, w = shape
    owner = np.full(shape, -1, np.int64)
    best = np.full(shape, np.inf)
    for i, (x1, y1, x2, y2) in enumerate(np.asarray(boxes, np.float64)):
        rows = np.s_[int(np.clip(np.floor(y1), 0, h)):int(np.clip(np.ceil(y2) + 1, 0, h))]
        cols = np.s_[int(np.clip(np.floor(x1), 0, w)):int(np.clip(np.ceil(x2) + 1, 0, w))]
        v = np.arange(h)[rows, None] + 0.5  # pixel centres in the boxes' corner coordinates
        u = np.arange(w)[None, cols] + 0.5
        inside = np.maximum(np.abs(u - (x1 + x2) / 2) / max((x2 - x1) / 2, 1e-6),
                            np.abs(v - (y1 + y2) / 2) / max((y2 - y1) / 2, 1e-6))
        take = (inside <= 1) & (inside < best[rows, cols])
        owner[rows, cols][take], best[rows, cols][take] = i, inside[take]
    return owner


def segments(d: np.ndarray, valid: np.ndarray, edge_abs: float, edge_rel: float) -> tuple[int, np.ndarray]:
    """The ``valid`` depth pixels of frames ``d`` (F, h, w) cut at depth discontinuities
    (4-neighbours further apart than ``edge_abs + edge_rel * depth``): the segment count and
    each valid pixel's segment (k,), in row-major order, numbered in the order of their
    first pixel; no segment spans two frames.

    A compiled union-find over the pixels (:func:`~rosmeery_jax.mapping.kernels.label_segments`;
    it numbers segments as ``scipy.ndimage.label`` does on the image of pixels and links,
    which it replaced)."""
    d = np.ascontiguousarray(d)  # thresholds in the depth's precision, as numpy takes a Python number beside it
    return label_segments(d, np.ascontiguousarray(valid), d.dtype.type(edge_abs), d.dtype.type(edge_rel))
