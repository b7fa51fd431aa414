"""Time the detector's runtimes side by side at a session's batch and resolution, and score
each on the held-out paper-world frames.

    .venv/bin/python scripts/detector_runtimes.py [--repeats 9] [--map] [--weights NAME|FILE.pt]

Each runtime runs in a process of its own (thread pools of two runtimes in one process
slow each other), on the same 32 frames of the Kitchen at 160 x 128 (the session's
detector batch and resolution), with the threads a session gives it (one per core). A
detection call is timed as a chain whose parts add up: preprocessing (uint8 frames to the
padded float batch), the network, NMS. Medians of ``--repeats`` calls after one warm-up.
``torch.compile`` (inductor) is timed on the network alone. ``--map`` also scores each
runtime with ``rosmeery detector eval`` (1,419 held-out frames; minutes each).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = r"""
import json, sys, time
import numpy as np
from rosmeery_jax.detector import dataset
from rosmeery_jax.detector.boxes import nms
from rosmeery_jax.detector.detections import YoloDetector

runtime, repeats, weights = sys.argv[1], int(sys.argv[2]), sys.argv[3] or None
cfg = dataset.DatasetConfig(worlds=("kitchen",), per_world=200)
frames = np.stack([f[3] for f, _ in zip(dataset.generate(cfg, splits=("val", "train"), progress=False), range(32))])
det = YoloDetector((), weights, runtime="torch" if runtime == "torch.compile" else runtime)
det.forward(frames)  # builds the network (and its exported graph) for this shape
net = det._nets[(128, 160)]
if runtime == "torch.compile":
    import torch
    compiled = torch.compile(det.model)
    def net(x):
        with torch.inference_mode():
            return det.model.head.decode(compiled(torch.from_numpy(x))).numpy()
parts = {"pre_ms": [], "network_ms": [], "nms_ms": []}
for i in range(repeats + 1):
    t0 = time.perf_counter()
    x = np.full((32, 3, 128, 160), np.float32(114 / 255))
    x[:, :, :128, :160] = frames.transpose(0, 3, 1, 2) / np.float32(255)
    t1 = time.perf_counter()
    pred = net(x)
    t2 = time.perf_counter()
    nms(pred, det.conf)
    t3 = time.perf_counter()
    if i:  # the first call warms up (and compiles)
        for k, v in zip(parts, (t1 - t0, t2 - t1, t3 - t2)):
            parts[k].append(1e3 * v)
out = {k: round(float(np.median(v)), 2) for k, v in parts.items()}
out["images_per_s"] = round(32e3 / sum(out.values()), 1)
print(json.dumps(out))
"""

RUNTIMES = ("torch", "torch.compile", "onnxruntime", "onnxruntime-int8")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--map", action="store_true", help="also mAP@0.5 on the held-out paper-world frames")
    ap.add_argument("--weights", default="", help="weights name or file (default: the default weights)")
    args = ap.parse_args()
    rows = {}
    for rt in RUNTIMES:
        run = subprocess.run([sys.executable, "-c", CHILD, rt, str(args.repeats), args.weights], capture_output=True, text=True,
                             env=os.environ)
        if run.returncode:
            print(f"{rt}: failed\n{run.stderr[-2000:]}", file=sys.stderr)
            continue
        rows[rt] = json.loads(run.stdout.strip().splitlines()[-1])
        print(f"{rt:<18}{rows[rt]['pre_ms']:>8.1f}{rows[rt]['network_ms']:>10.1f}{rows[rt]['nms_ms']:>8.1f} ms"
              f"{rows[rt]['images_per_s']:>9.0f} images/s", flush=True)
    if "torch" in rows:
        base = rows["torch"]["images_per_s"]
        print("ratio to torch eager: " + ", ".join(f"{k} {v['images_per_s'] / base:.2f}x" for k, v in rows.items()))
    if args.map:
        for rt in RUNTIMES:
            if rt == "torch.compile":
                continue
            run = subprocess.run([sys.executable, "-m", "rosmeery_jax", "detector", "eval", "--runtime", rt, "--json",
                                  *(["--weights", args.weights] if args.weights else [])],
                                 capture_output=True, text=True, check=True)
            r = json.loads(run.stdout)
            print(f"{rt:<18} mAP@0.5 {r['map50']:.4f}; lowest class {min(r['ap50'].values()):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
