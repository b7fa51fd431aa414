"""A depth frame cut into the segments objects are made of, for the perceived mapper
(:mod:`rosmeery_jax.mapping.perceived`): the camera's rays scaled by depth, which box each
pixel lies most inside, depth segments, and the instance each segment grows. Shapes: F
frames, H x W pixels, k valid pixels, Q (segment, cell) pairs."""

from __future__ import annotations

import numpy as np

from scipy import ndimage

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

    The pixels and the links between them are one image of (2h - 1, 2w - 1) cells a frame
    (pixels at even places, a link between two pixels on the cell between them), so the
    segments are the image's 4-connected components (``scipy.ndimage.label``: 2.7x faster
    on the depth camera's frames than scipy's connected components of a graph of the links)."""
    f, h, w = d.shape
    grid = np.zeros((f, 2 * h - 1, 2 * w - 1), bool)
    grid[:, ::2, ::2] = valid
    for a, b, link in ((np.s_[..., :-1], np.s_[..., 1:], np.s_[:, ::2, 1::2]),
                       (np.s_[:, :-1, :], np.s_[:, 1:, :], np.s_[:, 1::2, ::2])):
        da, db = d[a], d[b]  # right and down neighbours
        grid[link] = valid[a] & valid[b] & (np.abs(da - db) <= edge_abs + edge_rel * np.minimum(da, db))
    label, count = ndimage.label(grid, _WITHIN_FRAME)
    return count, label[:, ::2, ::2][valid] - 1


_WITHIN_FRAME = np.zeros((3, 3, 3), bool)  # 4-neighbours within a frame, none across
_WITHIN_FRAME[1] = ndimage.generate_binary_structure(2, 1)


def segment_owners(seg: np.ndarray, held: np.ndarray, count: int, share: float) -> tuple[np.ndarray, np.ndarray]:
    """Rule 7's segments, ascending, and the instance each grows: from each of a frame's
    distinct (segment, cell) pairs, seg (Q,) its segment and held (Q,) the instance holding
    the cell (-1 none), the segments of which one instance holds at least ``share`` of the cells."""
    cells = np.bincount(seg, minlength=count)
    on = held >= 0
    if not on.any():
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    width = int(held.max()) + 1
    pair, n = np.unique(seg[on] * width + held[on], return_counts=True)
    s, inst = pair // width, pair % width
    order = np.lexsort((-n, s))  # per segment, the instance holding most first
    s, inst, n = s[order], inst[order], n[order]
    first = np.r_[True, s[1:] != s[:-1]]
    keep = first & (n >= share * cells[s])
    return s[keep], inst[keep]
