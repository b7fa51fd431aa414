"""Detectors the session runs between chunks, and how detections attach to objects.

A detector takes a batch of RGB frames (I, H, W, 3) uint8 with their segmentation images
(I, H, W) (object index per pixel, negative for walls / floor / nothing) and returns, per
frame, arrays ``obj`` (D,), ``label`` (D,) taxonomy category index, ``conf`` (D,).

- ``yolo``: the torch YOLO-v5 (by default the shipped weights trained on generated worlds
  only, ``procedural``; ``procedural_2x`` the same fine-tuned on frames scaled up twice;
  ``paper_worlds`` those trained on the four paper worlds; or any
  YOLO-v5 weights path; class names are matched to taxonomy categories by name, others dropped).
  Weights trained on frames scaled up a whole number of times (their ``imgsz`` that many
  times the frame's size) see the session's frames scaled up alike (``runtime.upscale``),
  and their boxes are brought back to the frame's pixels.
  A detection attaches to the object with the most pixels inside its box in the
  segmentation image, if that object covers at least ``MIN_SHARE`` of the box.
- ``oracle``: simulated from ground truth, no torch, for fast sweeps. Confidence model: for
  an object with p visible pixels in a frame, size s = min(1, p / 600) (600 px is 3 % of a
  160 x 128 frame); it is detected with probability 0.3 + 0.7 s, with confidence
  0.35 + 0.6 sqrt(s) + N(0, 0.05) clipped to [0.05, 0.99]; with probability 0.15 (1 - s) the
  label is a wrong one: a sibling category of the same macro-category when there is one,
  otherwise any other category. Objects below 40 visible pixels are never detected.
Both drop detections below the session's confidence threshold.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from pathlib import Path

import numpy as np

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.detector import runtime as runtimes
from rosmeery_jax.detector.boxes import nms
from rosmeery_jax.detector.dataset import visible_boxes

MIN_SHARE = 0.1  # share of a detection's box an object must cover to take the detection
DETECTORS = ("yolo", "oracle", "off")  # a session's choices: YOLO-v5n, simulated from ground truth, none
_FOLDER = Path(__file__).parent / "weights"
WEIGHTS = {"procedural": _FOLDER / "yolov5n_procedural.pt",  # the default: trained on generated worlds only
           "procedural_2x": _FOLDER / "yolov5n_procedural_2x.pt",  # the same fine-tuned on frames scaled up twice
           "paper_worlds": _FOLDER / "yolov5n_paper_worlds.pt"}  # trained on the four paper worlds it is scored in
DEFAULT_WEIGHTS = WEIGHTS["procedural"]


def weights_file(weights: str | Path | None) -> Path:
    """The weights file named by ``weights``: a name of :data:`WEIGHTS`, a path, or
    None / "" for the default."""
    if not weights:
        return DEFAULT_WEIGHTS
    return WEIGHTS.get(str(weights), Path(weights))


def associate(boxes: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """boxes (D, 4) pixel corners -> (D,) object index covering most of each box, or -1."""
    h, w = seg.shape
    out = np.full(len(boxes), -1, np.int32)
    for i, (x1, y1, x2, y2) in enumerate(boxes):
        xa, ya = int(np.clip(np.floor(x1), 0, w)), int(np.clip(np.floor(y1), 0, h))
        xb, yb = int(np.clip(np.ceil(x2), 0, w)), int(np.clip(np.ceil(y2), 0, h))
        patch = seg[ya:yb, xa:xb].ravel()
        patch = patch[patch >= 0]
        if not len(patch):
            continue
        ids, counts = np.unique(patch, return_counts=True)
        k = int(np.argmax(counts))
        if counts[k] >= MIN_SHARE * max(1, (xb - xa) * (yb - ya)):
            out[i] = ids[k]
    return out


class YoloDetector:
    """The torch YOLO-v5 on a world's frames. A call is the network pass (:meth:`raw`), then
    per frame the world's class mapping and the association (:meth:`finish`). Detectors with
    the same ``network`` (weights, threshold, batch) give the same raw detections, so a session
    runs one pass over every world's frames (fewer padded batches) and finishes per world.

    A frame's raw detections depend on its pixels alone (not on its batch-mates: tested), so
    :meth:`raw` runs the network once per distinct image and remembers the last ``memory``
    images' results by content: a robot that stands still sends the same frame again and
    again (a third of the default session's frames, mostly frontier robots done exploring)."""

    name = "yolo"

    def __init__(self, categories: tuple[str, ...], weights: str | Path | None = None, conf: float = 0.25,
                 batch: int = 32, threads: int | None = None, memory: int = 50_000, runtime: str = runtimes.DEFAULT):
        import torch  # the detector extra: imported only when YOLO runs

        from rosmeery_jax.detector import checkpoint  # imports torch

        if threads:
            torch.set_num_threads(threads)
        self.path = weights_file(weights)
        self.model = checkpoint.load(self.path)
        index = {c: i for i, c in enumerate(categories)}
        self.class_map = np.array([index.get(n, -1) for n in self.model.names], np.int32)
        runtimes.check(runtime)
        self.conf, self.batch, self.runtime, self.threads = conf, batch, runtime, threads
        self._nets: dict[tuple[int, int], object] = {}  # padded (H, W) -> the network at that input shape
        self.network = (str(self.path.resolve()), conf, batch, runtime)
        self.memory, self._known = memory, OrderedDict()  # image digest -> raw detections

    def __call__(self, images: np.ndarray, seg: np.ndarray, frame_ids=None) -> list[tuple]:
        return self.finish(self.raw(images), seg)

    def raw(self, images: np.ndarray) -> list[np.ndarray]:
        """The network's detections per frame (k, 6): x1, y1, x2, y2, confidence, class
        (read-only: repeated images share them); the network sees each new image once."""
        keys = [_digest(im) for im in images]
        new: dict[bytes, int] = {}  # each unknown image's first frame
        for i, k in enumerate(keys):
            if k not in self._known:
                new.setdefault(k, i)
        for k, d in zip(new, self.forward(images[list(new.values())]) if new else []):
            d.setflags(write=False)
            self._known[k] = d
        out = [self._known[k] for k in keys]
        for k in keys:  # most recently used last; the oldest are forgotten
            self._known.move_to_end(k)
        while len(self._known) > self.memory:
            self._known.popitem(last=False)
        return out

    def forward(self, images: np.ndarray, conf: float | None = None, iou: float = 0.45,
                max_det: int = 100) -> list[np.ndarray]:
        """:meth:`raw` without the memory: the network on every frame, then NMS at ``conf``
        (default: the detector's threshold)."""
        return nms(self.head(images), self.conf if conf is None else conf, iou, max_det)

    def prepare(self, h: int, w: int) -> tuple[int, int]:
        """Build the network for frames of h x w (scaled up as ``runtime.upscale_factor``
        says, padded to whole strides), exporting its graph on first use; a session calls it
        while it compiles. Returns the network's padded (H, W)."""
        return self._built(h, w)[1]

    def _built(self, h: int, w: int) -> tuple[int, tuple[int, int]]:
        """For frames of h x w: how many times they are scaled up and the network's padded
        (H, W), its network built if it is not yet."""
        k = runtimes.upscale_factor(self.model.imgsz, h, w)
        padded = runtimes.padded(k * h, k * w)
        if padded not in self._nets:
            calibration = runtimes.Calibration.of(k, self.model.int8_percentile)
            self._nets[padded] = runtimes.network(self.runtime, self.model, self.path, self.batch, *padded,
                                                  self.threads, calibration)
        return k, padded

    def head(self, images: np.ndarray) -> np.ndarray:
        """images (I, H, W, 3) uint8 -> the network's decoded head (I, A, 5 + C) on the
        runtime, boxes in the frames' pixels."""
        k, padded = self._built(*images.shape[1:3])
        images = runtimes.upscale(images, k)
        h, w = images.shape[1:3]
        out = []
        for i in range(0, len(images), self.batch):
            part = images[i:i + self.batch]
            # Always a full batch (zero frames pad the last one): the runtimes' numerics depend
            # on the batch size; with it fixed, a frame's detections do not depend on its
            # batch-mates or its place in the batch (tests/test_detector.py).
            x = np.full((self.batch, 3, *padded), np.float32(114 / 255))  # the official grey pad
            x[:, :, :h, :w] = 0
            x[:len(part), :, :h, :w] = part.transpose(0, 3, 1, 2) / np.float32(255)
            out.append(self._nets[padded](x)[:len(part)])
        if not out:
            return np.zeros((0, 0, 5 + len(self.model.names)), np.float32)
        out = np.concatenate(out)
        if k > 1:
            out[..., :4] /= k  # box centres and sizes back to the frames' pixels
        return out

    def finish(self, raw: list[np.ndarray], seg: np.ndarray) -> list[tuple]:
        """This world's (obj, label, conf, box) per frame from :meth:`raw`'s detections."""
        out = []
        for d, s in zip(raw, seg):
            label = self.class_map[d[:, 5].astype(int)]
            keep = label >= 0
            d, label = d[keep], label[keep]
            out.append((associate(d[:, :4], s), label, d[:, 4].astype(np.float32), d[:, :4].astype(np.float32)))
        return out


class OracleDetector:
    name = "oracle"

    def __init__(self, categories: np.ndarray, taxonomy, conf: float = 0.25, min_pixels: int = 40):
        self.categories = np.asarray(categories)
        self.conf, self.min_pixels = conf, min_pixels
        names = list(taxonomy.names)
        macro = [taxonomy.chain(n)[1] for n in names]
        self.siblings = [[j for j in range(len(names)) if macro[j] == macro[i] and j != i]
                         or [j for j in range(len(names)) if j != i] for i in range(len(names))]

    def __call__(self, images: np.ndarray, seg: np.ndarray, frame_ids) -> list[tuple]:
        """frame_ids (I, 2): (env seed, frame number) per frame: the random stream of a frame,
        so results do not depend on how frames are batched."""
        out = []
        for s, fid in zip(seg, frame_ids):
            rng = np.random.default_rng([int(fid[0]), int(fid[1]), 7])
            b = visible_boxes(s, self.min_pixels)
            size = np.minimum(1.0, b[:, 5] / 600.0)
            hit = rng.random(len(b)) < 0.3 + 0.7 * size
            conf = np.clip(0.35 + 0.6 * np.sqrt(size) + rng.normal(0, 0.05, len(b)), 0.05, 0.99)
            label = self.categories[b[:, 0]].copy()
            wrong = rng.random(len(b)) < 0.15 * (1 - size)
            for k in np.nonzero(wrong)[0]:
                sib = self.siblings[label[k]]
                label[k] = sib[rng.integers(len(sib))]
            keep = hit & (conf >= self.conf)
            out.append((b[keep, 0].astype(np.int32), label[keep].astype(np.int32), conf[keep].astype(np.float32),
                        b[keep, 1:5].astype(np.float32)))
        return out


def pad(per_frame: list[tuple], frames: int, max_det: int) -> tuple[np.ndarray, ...]:
    """Detections of ``frames`` frames -> obj, label (frames, max_det) int32 (-1 = none),
    conf (frames, max_det) and box (frames, max_det, 4), keeping each frame's most confident
    ``max_det``."""
    obj = np.full((frames, max_det), -1, np.int32)
    label = np.full((frames, max_det), -1, np.int32)
    conf = np.zeros((frames, max_det), np.float32)
    box = np.zeros((frames, max_det, 4), np.float32)
    for f, (o, lab, c, b) in enumerate(per_frame):
        k = np.argsort(-c, kind="stable")[:max_det]
        obj[f, :len(k)], label[f, :len(k)], conf[f, :len(k)], box[f, :len(k)] = o[k], lab[k], c[k], b[k]
    return obj, label, conf, box


def _digest(image: np.ndarray) -> bytes:
    """128 bits of BLAKE2b over an image's shape and pixels: its identity for YOLO's memory."""
    h = hashlib.blake2b(str(image.shape).encode(), digest_size=16)
    h.update(np.ascontiguousarray(image).data)
    return h.digest()


def make_detector(name: str, world, conf: float, weights: str | None = None, runtime: str = runtimes.DEFAULT):
    if name == "yolo":
        return YoloDetector(world.taxonomy.names, weights, conf, runtime=runtime)
    if name == "oracle":
        return OracleDetector(world.truth.category_index, world.taxonomy, conf)
    raise ValueError(f"unknown detector {name!r}")


def check_choice(detector: str, weights: str, runtime: str, source: str) -> None:
    """A session's weights and runtime for its ``detector`` (one of :data:`DETECTORS`; the
    runtime's packages found, not imported)."""
    if weights and detector != "yolo":
        raise InputError(source, "weights", f"{weights!r} is for --detector yolo, not {detector!r}")
    if weights and not weights_file(weights).is_file():
        raise InputError(source, "weights", f"{weights!r}: no such file (or a name: {', '.join(WEIGHTS)})")
    if detector == "yolo":
        runtimes.check(runtime, source, "detector", "'yolo'", " (or use --detector oracle / off)")
