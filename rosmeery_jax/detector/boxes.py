"""Boxes in numpy: IoU, centre-size to corners, and YOLO's class-aware non-maximum suppression.

Written here rather than taken from torchvision (which has no build for the CPU torch used
here), and in numpy so that inference on ONNX Runtime needs no torch. Shapes: I images, P
predictions, C classes, D detections.
"""

from __future__ import annotations

import numpy as np


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(P, 4) x (Q, 4) corner boxes -> (P, Q) IoU."""
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.clip(rb - lt, 0, None).prod(-1)
    area = lambda x: (x[:, 2:] - x[:, :2]).prod(-1)  # noqa: E731
    return inter / (area(a)[:, None] + area(b)[None] - inter + 1e-9)


def xywh2xyxy(x: np.ndarray) -> np.ndarray:
    """(..., 4) centre x, y, width, height -> corners x1, y1, x2, y2."""
    return np.concatenate((x[..., :2] - x[..., 2:] / 2, x[..., :2] + x[..., 2:] / 2), -1)


def nms_indices(boxes: np.ndarray, scores: np.ndarray, iou: float) -> np.ndarray:
    """Greedy non-maximum suppression: indices kept, by decreasing score (ties: first first)."""
    order = np.argsort(-scores, kind="stable")
    overlap = box_iou(boxes[order], boxes[order]) > iou
    keep = np.ones(len(order), bool)
    for i in range(len(order)):  # D is small after the confidence filter
        if keep[i]:
            keep[i + 1:] &= ~overlap[i, i + 1:]
    return order[keep]


def nms(pred: np.ndarray, conf: float = 0.25, iou: float = 0.45, max_det: int = 100) -> list[np.ndarray]:
    """Decoded predictions (I, P, 5 + C) -> per image (D, 6) float32: x1, y1, x2, y2 (pixels),
    confidence (objectness x class probability), class index; class-aware NMS."""
    out = []
    for p in np.asarray(pred, np.float32):
        p = p[p[:, 4] > conf]
        scores = p[:, 5:] * p[:, 4:5]
        cls = scores.argmax(1)
        score = scores[np.arange(len(p)), cls]
        keep = score > conf
        boxes, score, cls = xywh2xyxy(p[keep, :4]), score[keep], cls[keep].astype(np.float32)
        if len(score) > 3000:
            top = np.argsort(-score, kind="stable")[:3000]
            boxes, score, cls = boxes[top], score[top], cls[top]
        # Class-aware: shift each class's boxes apart so one pass serves all classes.
        k = nms_indices(boxes + cls[:, None] * np.float32(4096.0), score, iou)[:max_det]
        out.append(np.concatenate((boxes[k], score[k, None], cls[k, None]), 1))
    return out
