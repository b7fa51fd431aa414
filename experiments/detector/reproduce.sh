#!/usr/bin/env bash
# Reproduce the shipped detector weights from nothing: render the procedural dataset, train
# YOLO-v5n from scratch, evaluate on the four paper worlds (never seen in training).
# Run from the repository root after `bash scripts/setup.sh`. About 45 min on 2 CPU cores.
set -euo pipefail
R=.venv/bin/rosmeery
WORLDS=procedural:apartment:1000-1009,procedural:office:1000-1009,procedural:kitchen:1000-1009,procedural:lab:1000-1009
$R detector dataset --worlds "$WORLDS" --per-world 150 --seed 0 --out data/detector_procedural
$R detector train --data data/detector_procedural --epochs 40 --batch 32 --seed 0 --out out/detector/yolov5n_procedural.pt
$R detector eval --weights out/detector/yolov5n_procedural.pt --json > out/detector/eval_paper_worlds.json
cat out/detector/eval_paper_worlds.json
