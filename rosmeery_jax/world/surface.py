"""Ground-truth surface samples: each object's observable surface at a fixed areal density.

Every face of every box of an object is covered by a regular grid of samples whose count is
the face area times the density (at least one per face; the grid is laid along the face's
short side first, so thin faces such as chair legs get a line of samples rather than an
inflated grid). A sample is then dropped when no camera can ever see it (docs/metrics.md):

- the face rests on the floor or on/against another solid: a point up to ``contact_gap``
  in front of the sample is inside another box or below the floor (a face in a slot
  narrower than that cannot be looked into);
- the sample lies inside another solid (another part of the same object included);
- with a fixed camera height h: an up-facing face above h, or a down-facing face below h,
  is seen edge-on at best from every camera pose (``camera_height=None`` turns this off).

ps_G(n) is the number of samples left on object n.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rosmeery_jax.world.scene import Scene

# faces as (axis, sign); the two in-face axes follow.
_FACES = [(0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1)]


class SurfaceSamples(NamedTuple):
    """S samples. points/normals: (S, 3) float32 world frame; object/box: (S,) int32."""

    points: np.ndarray
    normals: np.ndarray
    object: np.ndarray
    box: np.ndarray


def face_grid(half_u: float, half_v: float, density: float) -> np.ndarray:
    """Sample positions (K, 2) on a face of half extents (half_u, half_v) at ``density``/m^2."""
    lu, lv = 2 * half_u, 2 * half_v
    short, long_ = (lu, lv) if lu <= lv else (lv, lu)
    n_short = max(1, int(round(short * np.sqrt(density))))
    n_long = max(1, int(round(short * long_ * density / n_short)))
    nu, nv = (n_short, n_long) if lu <= lv else (n_long, n_short)
    u = (np.arange(nu) + 0.5) / nu * lu - half_u
    v = (np.arange(nv) + 0.5) / nv * lv - half_v
    uu, vv = np.meshgrid(u, v, indexing="ij")
    return np.stack([uu.ravel(), vv.ravel()], -1)


def sample_boxes(scene: Scene, boxes: np.ndarray, density: float) -> SurfaceSamples:
    """All face samples of the given boxes, before any exclusion."""
    pts, nrm, obj, box = [], [], [], []
    for g in boxes:
        c, h, yaw = scene.center[g], scene.half[g], float(scene.yaw[g])
        rot = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0, 0, 1]])
        for axis, sign in _FACES:
            u_ax, v_ax = [a for a in range(3) if a != axis]
            grid = face_grid(h[u_ax], h[v_ax], density)
            local = np.zeros((grid.shape[0], 3))
            local[:, axis] = sign * h[axis]
            local[:, u_ax], local[:, v_ax] = grid[:, 0], grid[:, 1]
            n_local = np.zeros(3)
            n_local[axis] = sign
            pts.append(local @ rot.T + c)
            nrm.append(np.broadcast_to(rot @ n_local, local.shape))
            obj.append(np.full(grid.shape[0], scene.object_id[g]))
            box.append(np.full(grid.shape[0], g))
    return SurfaceSamples(
        np.concatenate(pts).astype(np.float32), np.concatenate(nrm).astype(np.float32),
        np.concatenate(obj).astype(np.int32), np.concatenate(box).astype(np.int32))


def observable_mask(scene: Scene, s: SurfaceSamples, contact_gap: float,
                    camera_height: float | None) -> np.ndarray:
    """(S,) bool: which samples some camera pose could see (see module docstring)."""
    p = s.points.astype(np.float64)
    covered = np.zeros(p.shape[0], dtype=bool)
    # Several probes along the normal so a thin solid in front (a screen's glass) still counts.
    for gap in np.linspace(0.002, contact_gap, 4):
        q = p + gap * s.normals
        covered |= scene.inside_any(q, skip=s.box) | (q[:, 2] < 0.0)
    buried = scene.inside_any(p, margin=1e-4, skip=s.box)
    keep = ~covered & ~buried
    if camera_height is not None:
        nz = s.normals[:, 2]
        edge_on = ((nz > 0.99) & (p[:, 2] >= camera_height)) | ((nz < -0.99) & (p[:, 2] <= camera_height))
        keep &= ~edge_on
    return keep


def observable_samples(scene: Scene, density: float, contact_gap: float = 0.02,
                       camera_height: float | None = 0.5) -> SurfaceSamples:
    """Samples on every object box that some camera could observe, object-ordered."""
    boxes = np.flatnonzero(scene.object_id >= 0)
    s = sample_boxes(scene, boxes, density)
    keep = observable_mask(scene, s, contact_gap, camera_height)
    order = np.argsort(s.object[keep], kind="stable")
    return SurfaceSamples(*(a[keep][order] for a in s))
