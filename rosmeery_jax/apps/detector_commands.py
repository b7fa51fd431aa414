"""The ``rosmeery detector`` sub-commands: render the dataset, train YOLO-v5, evaluate it and
export it for ONNX Runtime. Torch (the detector extra) is imported by train, eval and
export only."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from rosmeery_jax.apps.arguments import WEIGHTS_HELP, positive
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import output_folder, require_new
from rosmeery_jax.core.specs import expand_ranges
from rosmeery_jax.core.xla import MEMORY_SHARE, memory_bytes
from rosmeery_jax.detector import dataset, mean_ap
from rosmeery_jax.detector import runtime as runtimes
from rosmeery_jax.detector.detections import weights_file
from rosmeery_jax.env.config import MAX_PIXELS
from rosmeery_jax.world import load_world


def add_detector(sub) -> None:
    """The ``detector`` command: ``dataset``, ``train``, ``eval`` and ``export``."""
    p = sub.add_parser("detector", help="the YOLO-v5 detector: make its dataset, train, evaluate")
    dsub = p.add_subparsers(dest="detector_command", required=True)
    s = dsub.add_parser("dataset", help="render a YOLO-format dataset from the simulator")
    s.add_argument("--worlds", default="kitchen,laboratory,small_office,large_office", metavar="A,B")
    s.add_argument("--out", default="data/detector", metavar="DIR")
    s.add_argument("--per-world", type=int, default=1500, metavar="N", help="viewpoints per world (train + val)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--balance", action="store_true",
                   help="aim at each object category equally often (more views of rare classes)")
    s.add_argument("--near", type=float, default=0.0, metavar="X",
                   help=f"share of the aimed viewpoints standing {dataset.NEAR[0]:g}-{dataset.NEAR[1]:g} m from their "
                        "object (close, cut-off views; default 0)")
    s.add_argument("--far", type=float, default=0.0, metavar="X",
                   help=f"share of the other aimed viewpoints standing {dataset.FAR[0]:g}-{dataset.FAR[1]:g} m from "
                        "their object with a clear line to a corner of it (small, distant views; default 0)")
    s.add_argument("--more", default="", metavar="CAT=X,...",
                   help="with --balance, aim at these categories X times as often (e.g. toilet=4)")
    s.add_argument("--quiet", action="store_true")
    s.set_defaults(func=_cmd_detector_dataset)
    s = dsub.add_parser("train", help="train YOLO-v5 from scratch on a dataset folder (CPU)")
    s.add_argument("--data", default="data/detector", metavar="DIR")
    s.add_argument("--out", default="out/detector/yolov5n.pt", metavar="FILE.pt")
    s.add_argument("--size", default="n", choices=("n", "s"))
    s.add_argument("--epochs", type=int, default=40)
    s.add_argument("--batch", type=int, default=32)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--max-images", type=int, metavar="N", help="use only the first N training images (default: all)")
    s.add_argument("--mosaic", type=float, default=0.0, metavar="P", help="share of training images made a 2 x 2 "
                   "mosaic of four frames at half size, objects as from twice as far (default 0)")
    s.add_argument("--p2", action="store_true", help="a fourth head level at stride 4 (the official yolov5-p2 "
                   "graph), for objects a few pixels across")
    s.add_argument("--quiet", action="store_true")
    s.set_defaults(func=_cmd_detector_train)
    s = dsub.add_parser("eval", help="mAP@0.5 and per-class AP on held-out viewpoints")
    s.add_argument("--weights", metavar="FILE.pt", help=WEIGHTS_HELP)
    s.add_argument("--data", metavar="DIR", help="a dataset folder (default: render the default held-out split)")
    s.add_argument("--runtime", default=runtimes.DEFAULT, choices=runtimes.RUNTIMES, help="where the network "
                   f"runs (default {runtimes.DEFAULT})")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=_cmd_detector_eval)
    s = dsub.add_parser("export", help="write the network as an ONNX graph (for ONNX Runtime)")
    s.add_argument("--weights", metavar="FILE.pt", help=WEIGHTS_HELP)
    s.add_argument("--out", required=True, metavar="FILE.onnx")
    s.add_argument("--batch", type=int, default=32, help="frames per call (default 32, a session's)")
    s.add_argument("--size", default="160x128", metavar="WxH", help="frame size, scaled up for weights trained "
                   "on frames scaled up, padded to whole strides of 32 (default 160x128, a session's)")
    s.set_defaults(func=_cmd_detector_export)



def _cmd_detector_dataset(args) -> int:
    positive(args, "per_world", "seed")
    out = require_new(args.out)  # an existing dataset is never mixed with a new one
    worlds = tuple(expand_ranges(w.strip() for w in args.worlds.split(",") if w.strip()))
    for w in worlds:
        load_world(w)  # a bad name fails here, in one line
    for name in ("near", "far"):
        if not 0 <= getattr(args, name) <= 1:
            raise InputError("command line", f"--{name}", f"{getattr(args, name)} must be a share between 0 and 1")
    cfg = dataset.DatasetConfig(worlds=worlds, per_world=args.per_world, seed=args.seed, balance=args.balance,
                                near=args.near, far=args.far, more=_more(args.more))
    with output_folder(out):
        summary = dataset.write(cfg, out, progress=not args.quiet)
    print(f"wrote {args.out}: {summary['images']['train']} train / {summary['images']['val']} val images, "
          f"{summary['boxes']['train']} / {summary['boxes']['val']} boxes")
    return 0


def _more(text: str) -> tuple[tuple[str, float], ...]:
    """``--more`` as (category, factor) pairs; the values are checked by ``dataset.check``."""
    pairs = []
    for item in filter(None, (t.strip() for t in text.split(","))):
        name, _, x = item.partition("=")
        try:
            pairs.append((name.strip(), float(x)))
        except ValueError:
            raise InputError("command line", "--more", f"{item!r} is not CATEGORY=FACTOR") from None
    return tuple(pairs)


def _cmd_detector_train(args) -> int:
    runtimes.require("command line", "detector train")
    from rosmeery_jax.detector.train import (  # torch (the detector extra): only here
        DetectorTrainConfig,
        log_file,
        train,
    )

    positive(args, "epochs", "batch", "max_images", "seed")
    out = require_new(args.out, kind="file")  # earlier weights are never replaced, nor their log
    require_new(log_file(out), kind="file")
    for name in ("images/train", "images/val"):
        if not Path(args.data, name).is_dir():
            raise InputError(str(Path(args.data, name)), "--data", "not found: make the dataset with "
                             "`rosmeery detector dataset`")
    if not 0 <= args.mosaic <= 1:
        raise InputError("command line", "--mosaic", f"{args.mosaic} is not a share between 0 and 1")
    cfg = DetectorTrainConfig(size=args.size, epochs=args.epochs, batch=args.batch, seed=args.seed,
                      max_images=args.max_images or 0, mosaic=args.mosaic, p2=args.p2)
    with output_folder(out.parent):
        best = train(args.data, out, cfg, progress=not args.quiet)
    print(f"best validation mAP@0.5 {best['map50']:.3f} at epoch {best['epoch']}; wrote {args.out}")
    return 0


def _cmd_detector_export(args) -> int:
    runtimes.require("command line", "detector export", ("onnx", "onnxscript"))
    from rosmeery_jax.detector import checkpoint  # torch (the detector extra): only here

    positive(args, "batch")
    out = require_new(args.out, kind="file")
    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
        if not (1 <= w <= MAX_PIXELS and 1 <= h <= MAX_PIXELS):
            raise ValueError
    except ValueError:
        raise InputError("command line", "--size", f"{args.size!r} is not WxH in whole pixels up to {MAX_PIXELS}, "
                         "e.g. 160x128") from None
    model = checkpoint.load(weights_file(args.weights))
    k = runtimes.upscale_factor(model.imgsz, h, w)  # weights trained on frames scaled up see them so
    size = runtimes.padded(k * h, k * w)
    need, have = 4.0 * args.batch * 3 * size[0] * size[1], memory_bytes() * MEMORY_SHARE  # the traced input
    if need > have:
        raise InputError("command line", "--batch", f"{args.batch} frames of {size[1]}x{size[0]} need {need / 1e9:,.1f} "
                         f"GB, more than this machine's {have / 1e9:,.1f} GB allows")
    runtimes.export(model, out, args.batch, *size)
    scaled = f" (frames scaled up {k} times, as these weights were trained)" if k > 1 else ""
    print(f"wrote {out}: YOLO-v5{model.size}, {len(model.names)} classes, "
          f"input {args.batch}x3x{size[0]}x{size[1]}{scaled}")
    return 0


def _cmd_detector_eval(args) -> int:
    runtimes.check(args.runtime, "command line", "detector eval", "")
    from rosmeery_jax.detector.detections import YoloDetector  # torch (the detector extra): only here

    weights = weights_file(args.weights)
    detector = YoloDetector((), weights, runtime=args.runtime)
    model = detector.model
    if args.data:
        images, rows, _ = dataset.read(args.data, "val")
        source = f"{args.data} (val)"
    else:  # the held-out viewpoints of the default dataset, rendered now (deterministic)
        frames = list(dataset.generate(dataset.DatasetConfig(), splits=("val",), progress=False))
        images = np.stack([f[3] for f in frames])
        rows = [f[4] for f in frames]
        source = "default dataset, held-out viewpoints (rendered now)"
    r = mean_ap.evaluate(detector.forward(images, **mean_ap.SCORING_NMS), images, rows, model.nc)
    names = model.names
    if args.json:
        print(json.dumps({"weights": str(weights), "runtime": args.runtime, "data": source, "images": len(images),
                          "map50": r["map50"],
                          "precision": r["precision"], "recall": r["recall"],
                          "ap50": {names[c]: v for c, v in r["ap"].items()},
                          "instances": {names[c]: v for c, v in r["n_gt"].items()}}, indent=2))
        return 0
    print(f"weights {weights} ({args.runtime})\ndata {source}: {len(images)} images")
    print(f"{'class':<16}{'instances':>10}{'AP@0.5':>8}")
    for c, v in sorted(r["ap"].items(), key=lambda kv: names[kv[0]]):
        print(f"{names[c]:<16}{r['n_gt'][c]:>10}{v:>8.3f}")
    print(f"{'all':<16}{sum(r['n_gt'].values()):>10}{r['map50']:>8.3f}   (mAP@0.5; precision {r['precision']:.3f}, "
          f"recall {r['recall']:.3f} at conf 0.25)")
    return 0
