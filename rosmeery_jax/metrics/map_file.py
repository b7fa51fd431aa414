"""Semantic map export: SM = <R, M, P> of one env at one time.

- M, the segmented point cloud: ``<stem>.ply`` (binary, written with trimesh). One vertex per
  ground-truth surface sample the robot's depth camera has observed, at its position in the
  map frame (float x, y, z) with ``object_id`` (int, index into the JSON's objects), ``label``
  (int, category index in the taxonomy, -1 when the robot holds no label) and ``confidence``
  (float, of the held label).
- R and P: ``<stem>.json`` (schema: ``rosmeery_jax/metrics/semantic_map.schema.json``):
  ``frame`` (id, world, units, axes, time_s), ``objects`` (per object with at least one
  observed point: id, name, label, confidence, observed_points and the axis-aligned bounding
  box of its observed points in the map frame: what the robot perceived, not the ground
  truth box) and ``predicates`` (the triples the robot declares from its labels).

The map frame is the world frame (z up, metres): the robot is told its pose. The perceived
mapper's maps (:mod:`rosmeery_jax.mapping.perceived`) use the same format through :func:`build_map`:
one vertex per claimed voxel, ``object_id`` an instance id named ``instance_<id>``.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import numpy as np
import trimesh

from rosmeery_jax.core.files import write_atomic

SCHEMA_PATH = resources.files("rosmeery_jax.metrics") / "semantic_map.schema.json"


def semantic_map(world, knowledge, time_s: float) -> tuple[trimesh.Trimesh, dict]:
    """(point cloud with vertex attributes, R + P as a JSON-ready dict) from one env's
    :class:`Knowledge` (numpy or jax arrays, no batch axis)."""
    points, obj = knowledge_points(world, knowledge.seen)
    return build_map(world, points, obj, list(world.truth.names), np.asarray(knowledge.label),
                     np.asarray(knowledge.confidence, np.float32), time_s)


def knowledge_points(world, seen) -> tuple[np.ndarray, np.ndarray]:
    """The built-in knowledge's map points: the ground-truth samples observed (``seen`` (S,)
    coverage > 0.5), (P, 3), and their object ids (P,)."""
    keep = np.asarray(seen) > 0.5
    return np.asarray(world.truth.samples.points)[keep], np.asarray(world.truth.samples.object)[keep]


def build_map(world, points: np.ndarray, instance: np.ndarray, names: list[str], label: np.ndarray,
              confidence: np.ndarray, time_s: float) -> tuple[trimesh.Trimesh, dict]:
    """The map of points (P, 3) with instance ids (P,) indexing names, label (category index,
    -1 none) and confidence (one entry per id): the PLY cloud and the JSON's dict."""
    label = np.asarray(label)
    conf = np.asarray(confidence, np.float32)
    cloud = trimesh.Trimesh(vertices=points, faces=np.zeros((0, 3), np.int64), process=False)
    cloud.vertex_attributes["object_id"] = instance.astype(np.int32)
    cloud.vertex_attributes["label"] = label[instance].astype(np.int32)
    cloud.vertex_attributes["confidence"] = conf[instance]
    categories = world.taxonomy.names
    objects, predicates = [], []
    for n in np.unique(instance):
        p = points[instance == n].astype(np.float64)
        lo, hi = p.min(0), p.max(0)
        k = int(label[n])
        objects.append({
            "id": int(n), "name": names[n], "label": categories[k] if k >= 0 else None,
            "confidence": round(float(conf[n]), 6), "observed_points": int(len(p)),
            "bbox": {"center": ((lo + hi) / 2).round(4).tolist(), "size": (hi - lo).round(4).tolist(), "yaw": 0.0},
        })
        if k >= 0:
            predicates += [list(t) for t in world.taxonomy.predicates(names[n], categories[k])]
    meta = {
        "frame": {"id": "map", "world": world.name, "units": "m", "axes": "x forward, y left, z up (world)",
                  "time_s": float(time_s)},
        "objects": objects,
        "predicates": predicates,
    }
    return cloud, meta


def write_map(directory: str | Path, stem: str, cloud: trimesh.Trimesh, meta: dict) -> tuple[Path, Path]:
    """Write ``<stem>.ply`` and ``<stem>.json`` into directory (atomically)."""
    d = Path(directory)
    ply = write_atomic(d / f"{stem}.ply", trimesh.exchange.ply.export_ply(cloud, encoding="binary", include_attributes=True))
    js = write_atomic(d / f"{stem}.json", json.dumps(meta, indent=1))
    return ply, js


def write_semantic_map(directory: str | Path, stem: str, world, knowledge, time_s: float) -> tuple[Path, Path]:
    """Write ``<stem>.ply`` and ``<stem>.json`` into directory (atomically)."""
    return write_map(directory, stem, *semantic_map(world, knowledge, time_s))


def load_schema() -> dict:
    return json.loads(SCHEMA_PATH.read_text())
