"""Build a semantic map from a recorded TUM RGB-D sequence, the way an external mapper would.

A minimal mapper written against the recorded files only (no rosmeery import): every depth
pixel of an object in the instance image is back-projected with the pinhole intrinsics of
camera.json and the camera pose of groundtruth.txt, and the points are thinned to one per
2 cm voxel per instance. The result is a map ``rosmeery evaluate`` reads (PLY + JSON).

    python examples/tum_to_map.py REC/seed0 --out map.ply [--until SECONDS]
    rosmeery evaluate --world WORLD --map map.ply --out scores/

It reads the ground-truth instance images (seg/) for the segmentation, so it scores the
geometry of the round trip (intrinsics, depth scale, poses, frames), not a detector.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation


def read_list(path: Path) -> dict[str, str]:
    """'timestamp value...' lines -> {timestamp: rest of the line}."""
    out = {}
    for line in path.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            stamp, rest = line.split(maxsplit=1)
            out[stamp] = rest
    return out


def backproject(depth_m: np.ndarray, cam: dict) -> np.ndarray:
    """(H, W, 3) points in the optical frame (x right, y down, z forward)."""
    h, w = depth_m.shape
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    x = (u - cam["cx"]) * depth_m / cam["fx"]
    y = (v - cam["cy"]) * depth_m / cam["fy"]
    return np.stack([x, y, depth_m], -1)


def write_ply(path: Path, points: np.ndarray, instance: np.ndarray) -> None:
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(points)}\n"
              "property float x\nproperty float y\nproperty float z\nproperty int object_id\nend_header\n")
    rows = np.zeros(len(points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("object_id", "<i4")])
    rows["x"], rows["y"], rows["z"], rows["object_id"] = points[:, 0], points[:, 1], points[:, 2], instance
    path.write_bytes(header.encode() + rows.tobytes())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequence", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--until", type=float, default=float("inf"), help="use frames up to this time (s)")
    ap.add_argument("--voxel", type=float, default=0.02)
    args = ap.parse_args()
    seq = args.sequence
    cam = json.loads((seq / "camera.json").read_text())
    info = json.loads((seq / "info.json").read_text())
    objects = json.loads((seq / "objects.json").read_text())["objects"]
    depth, seg, poses = (read_list(seq / f) for f in ("depth.txt", "seg.txt", "groundtruth.txt"))
    stamps = sorted((s for s in depth if float(s) <= args.until), key=float)
    points, instance = [], []
    for s in stamps:
        d = cv2.imread(str(seq / depth[s]), cv2.IMREAD_UNCHANGED).astype(np.float64) / cam["depth_scale"]
        ids = cv2.imread(str(seq / seg[s]), cv2.IMREAD_UNCHANGED).astype(np.int64) - 1
        keep = (d > 0) & (ids >= 0)
        pose = np.array(poses[s].split(), float)  # tx ty tz qx qy qz qw
        p = backproject(d, cam)[keep] @ Rotation.from_quat(pose[3:]).as_matrix().T + pose[:3]
        points.append(p)
        instance.append(ids[keep])
    points, instance = np.concatenate(points), np.concatenate(instance)
    voxel = np.floor(points / args.voxel).astype(np.int64)
    _, first = np.unique(np.c_[voxel, instance], axis=0, return_index=True)
    points, instance = points[first], instance[first]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_ply(args.out, points, instance)
    meta = {"frame": {"world": info["world"], "time_s": float(stamps[-1])},
            "objects": [{"id": o["id"], "label": o["category"], "confidence": 1.0}
                        for o in objects if o["id"] in set(instance.tolist())]}
    args.out.with_suffix(".json").write_text(json.dumps(meta, indent=1))
    print(f"{len(points)} points of {len(meta['objects'])} objects from {len(stamps)} frames -> {args.out}")


if __name__ == "__main__":
    main()
