"""Bring a map given in its own frame into the world frame: point-to-plane ICP against the
ground-truth surface samples (which carry normals), or a transform the user gives.

Point-to-plane ICP (Chen & Medioni): each iteration pairs every map point with its nearest
sample (scipy cKDTree), drops pairs farther than ``max_dist``, and solves the linearised
least squares  min sum (n_q . (R p + t - q))^2  for a small rotation and a translation.
Written here rather than taken from a library: trimesh's ICP is point-to-point only, and
open3d (which has point-to-plane) is a several-hundred-megabyte dependency for 30 lines.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from rosmeery_jax.core.errors import InputError


class Alignment(NamedTuple):
    """transform (4, 4): map frame -> world frame; rms: point-to-plane residual (m) of the
    inlier pairs; inliers: their share of the points used; iterations run."""

    transform: np.ndarray
    rms: float
    inliers: float
    iterations: int


def apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (P, 3) moved by a 4 x 4 rigid transform."""
    return points @ transform[:3, :3].T + transform[:3, 3]


def icp(points: np.ndarray, samples: np.ndarray, normals: np.ndarray, max_dist: float = 0.5,
        iterations: int = 50, max_points: int = 50_000, seed: int = 0) -> Alignment:
    """The rigid transform that lays map ``points`` (P, 3) onto ``samples`` (S, 3) with unit
    ``normals`` (S, 3). Uses at most ``max_points`` points (a fixed random subset)."""
    rng = np.random.default_rng(seed)
    src = points if len(points) <= max_points else points[rng.choice(len(points), max_points, replace=False)]
    tree = cKDTree(samples)
    T = np.eye(4)
    it = 0
    for it in range(1, iterations + 1):
        p = apply(T, src)
        dist, j = tree.query(p, distance_upper_bound=max_dist)
        ok = np.isfinite(dist)
        if ok.sum() < 6:
            raise InputError("map", "--align", f"only {int(ok.sum())} points lie within {max_dist} m of the "
                             "world's surfaces: too far apart to align (give --transform)")
        p, q, n = p[ok], samples[j[ok]], normals[j[ok]]
        r = np.einsum("ij,ij->i", p - q, n)
        A = np.concatenate([np.cross(p, n), n], 1)
        x, *_ = np.linalg.lstsq(A, -r, rcond=None)
        step = np.eye(4)
        step[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix()
        step[:3, 3] = x[3:]
        T = step @ T
        if np.linalg.norm(x[:3]) < 1e-7 and np.linalg.norm(x[3:]) < 1e-6:
            break
    p = apply(T, src)
    dist, j = tree.query(p, distance_upper_bound=max_dist)
    ok = np.isfinite(dist)
    rms = float(np.sqrt(np.mean(np.einsum("ij,ij->i", p[ok] - samples[j[ok]], normals[j[ok]]) ** 2)))
    return Alignment(T, rms, float(ok.mean()), it)


def read_transform(path: str | Path) -> np.ndarray:
    """A 4 x 4 rigid transform (map -> world) from JSON (``{"transform": [[...] x 4]}`` or a
    bare nested list) or whitespace-separated text; one InputError if it is not one."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
        data = json.loads(text) if text.lstrip().startswith(("{", "[")) else [line.split() for line in text.splitlines() if line.strip()]
        if isinstance(data, dict):
            data = data.get("transform")
        T = np.asarray(data, dtype=np.float64)
    except (OSError, ValueError, TypeError) as err:
        raise InputError(path, "transform", f"not a 4 x 4 matrix ({err})") from None
    except RecursionError:
        raise InputError(path, "transform", "nested too deeply to be a 4 x 4 matrix") from None
    if T.shape != (4, 4):
        raise InputError(path, "transform", f"must be a 4 x 4 matrix, got shape {T.shape}")
    if not np.isfinite(T).all():
        row, col = np.argwhere(~np.isfinite(T))[0]
        raise InputError(path, f"transform[{row}][{col}]", f"{T[row, col]} is not a finite number")
    R = T[:3, :3]
    # A rotation's entries lie in [-1, 1]; larger ones would overflow R @ R.T.
    if (np.abs(R).max() > 1.0 + 1e-4 or not np.allclose(R @ R.T, np.eye(3), atol=1e-4)
            or not np.isclose(np.linalg.det(R), 1.0, atol=1e-4) or not np.allclose(T[3], [0, 0, 0, 1])):
        raise InputError(path, "transform", "is not a rigid transform (rotation and translation, last row 0 0 0 1)")
    return T


def to_world(world, maps: list, transform: str | Path | None = None, align: bool = False) -> tuple[list, dict | None]:
    """``maps`` (SemanticMap) moved into ``world``'s frame by a given ``transform`` file or, with
    ``align``, by ICP on the run's last (fullest) map; also what was done (for summary.json)."""
    if transform is not None:
        frame = {"transform": read_transform(transform).tolist(), "source": str(transform)}
    elif align:
        samples = world.truth.samples
        fit = icp(maps[-1].points, np.asarray(samples.points, np.float64), np.asarray(samples.normals, np.float64))
        frame = {"transform": fit.transform.tolist(), "source": "icp", "rms_m": fit.rms,
                 "inliers": fit.inliers, "iterations": fit.iterations}
    else:
        return maps, None
    T = np.asarray(frame["transform"])
    return [m._replace(points=apply(T, m.points)) for m in maps], frame
