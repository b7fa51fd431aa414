"""Detector evaluation: mAP@0.5 and per-class AP on a labelled split.

AP follows the common YOLO / COCO practice: detections at confidence >= 0.001 after NMS
(IoU 0.6), matched greedily by decreasing confidence to an unmatched ground-truth box of the
same class with IoU >= 0.5; precision at recall r taken as the best precision at any
recall >= r, averaged over the 101 recall points 0, 0.01, ..., 1 (COCO's interpolation).
mAP is the mean over classes that have ground truth in the split.
"""

from __future__ import annotations

import numpy as np

from rosmeery_jax.detector.boxes import box_iou


def rows_to_xyxy(rows: np.ndarray, h: int, w: int) -> np.ndarray:
    """YOLO rows (k, 5) -> (k, 4) pixel corners."""
    xc, yc, bw, bh = rows[:, 1] * w, rows[:, 2] * h, rows[:, 3] * w, rows[:, 4] * h
    return np.stack([xc - bw / 2, yc - bh / 2, xc + bw / 2, yc + bh / 2], -1)


def average_precision(tp: np.ndarray, conf: np.ndarray, n_gt: int) -> float:
    """AP of one class from per-detection true-positive flags and confidences."""
    if n_gt == 0 or len(tp) == 0:
        return 0.0
    order = np.argsort(-conf, kind="stable")
    tp = tp[order].astype(np.float64)
    ctp, cfp = np.cumsum(tp), np.cumsum(1 - tp)
    recall = ctp / n_gt
    precision = ctp / (ctp + cfp)
    envelope = np.flip(np.maximum.accumulate(np.flip(precision)))  # best precision at recall >= r
    at = np.searchsorted(recall, np.linspace(0, 1, 101), side="left")
    return float(np.mean(np.where(at < len(recall), envelope[np.minimum(at, len(recall) - 1)], 0.0)))


def mean_ap(dets: list[np.ndarray], gts: list[np.ndarray], nc: int, iou_thr: float = 0.5) -> dict:
    """dets: per image (D, 6) x1 y1 x2 y2 conf class; gts: per image (G, 5) class x1 y1 x2 y2.
    Returns {"map50", "ap" {class: AP}, "n_gt" {class: count}, "precision", "recall"}."""
    tp, conf, cls = [], [], []
    n_gt = np.zeros(nc, np.int64)
    for d, g in zip(dets, gts):
        g_cls = g[:, 0].astype(int)
        np.add.at(n_gt, g_cls, 1)
        if not len(d):
            continue
        d = d[np.argsort(-d[:, 4], kind="stable")]
        used = np.zeros(len(g), bool)
        iou = box_iou(d[:, :4], g[:, 1:5]) if len(g) else np.zeros((len(d), 0))
        for i, row in enumerate(d):
            c = int(row[5])
            ok = (~used) & (g_cls == c) & (iou[i] >= iou_thr) if len(g) else np.zeros(0, bool)
            hit = bool(ok.any())
            if hit:
                j = int(np.argmax(np.where(ok, iou[i], -1)))
                used[j] = True
            tp.append(hit)
            conf.append(row[4])
            cls.append(c)
    tp, conf, cls = np.array(tp, bool), np.array(conf, np.float64), np.array(cls, np.int64)
    ap = {c: average_precision(tp[cls == c], conf[cls == c], int(n_gt[c])) for c in range(nc) if n_gt[c] > 0}
    sel = conf >= 0.25  # operating point for precision / recall
    return {"map50": float(np.mean(list(ap.values()))) if ap else 0.0, "ap": ap,
            "n_gt": {c: int(n_gt[c]) for c in ap},
            "precision": float(tp[sel].mean()) if sel.any() else 0.0,
            "recall": float(tp[sel].sum() / max(1, n_gt.sum()))}


# NMS for scoring: every detection down to confidence 0.001 (module docstring)
SCORING_NMS = {"conf": 0.001, "iou": 0.6, "max_det": 300}


def model_detections(model, images: np.ndarray, batch: int = 64) -> list[np.ndarray]:
    """A torch YOLOv5's detections (D, 6) per image at :data:`SCORING_NMS`, in torch eager
    (what training scores each epoch)."""
    import torch  # the detector extra: imported only when a model is scored

    dets = []
    model.eval()
    with torch.inference_mode():
        for i in range(0, len(images), batch):
            x = torch.from_numpy(images[i:i + batch]).permute(0, 3, 1, 2).float() / 255
            dets += model.detect(x, **SCORING_NMS)
    return dets


def evaluate(dets: list[np.ndarray], images: np.ndarray, rows: list[np.ndarray], nc: int) -> dict:
    """mAP of detections ``dets`` (per image (D, 6), at :data:`SCORING_NMS`) on images
    (I, H, W, 3) uint8 with YOLO rows per image."""
    h, w = images.shape[1:3]
    gts = [np.concatenate([r[:, :1], rows_to_xyxy(r, h, w)], 1) for r in rows]
    return mean_ap(dets, gts, nc)
