#!/usr/bin/env bash
# Reproduce the held-out detector weights from nothing: render the procedural dataset (240
# worlds, each category aimed at equally often), train YOLO-v5n from scratch, evaluate on the
# four paper worlds (never seen in training). Run from the repository root after
# `bash scripts/setup.sh`. On 2 CPU cores: training 30 min, rendering about 15 CPU-minutes.
set -euo pipefail
R=.venv/bin/rosmeery
W=""
for kind in apartment office kitchen lab; do
    W="$W,procedural:$kind:1000-1039,procedural:$kind:1100-1119:clutter=0.4"
done
$R detector dataset --worlds "${W#,}" --per-world 50 --seed 0 --balance --out data/detector_procedural
$R detector train --data data/detector_procedural --epochs 20 --batch 32 --seed 0 --out out/detector/yolov5n_procedural.pt
$R detector eval --weights out/detector/yolov5n_procedural.pt --runtime torch --json > out/detector/eval_paper_worlds.json
cat out/detector/eval_paper_worlds.json
