"""The YOLO-v5 training loss: CIoU box loss, objectness and class BCE, with the official
target assignment (each box to the anchors within a 4x shape ratio, in its own grid cell and
the two nearest neighbouring cells) and the official gains.

targets (T, 6): image index, class, x, y, w, h with x, y, w, h normalised to the image.
"""

from __future__ import annotations

import math

import torch
from torch import nn

HYP = {"box": 0.05, "obj": 1.0, "cls": 0.5, "anchor_t": 4.0}
# Objectness weight of each level, finest first: P3, P4, P5, or P2 to P5 (the official ones).
BALANCE = {3: (4.0, 1.0, 0.4), 4: (4.0, 1.0, 0.25, 0.06)}
_OFFSETS = torch.tensor([[0, 0], [1, 0], [0, 1], [-1, 0], [0, -1]], dtype=torch.float32) * 0.5


def ciou(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-7) -> torch.Tensor:
    """Complete IoU of centre-size boxes a, b (P, 4) -> (P,)."""
    (x1, y1, w1, h1), (x2, y2, w2, h2) = a.unbind(-1), b.unbind(-1)
    ax1, ax2, ay1, ay2 = x1 - w1 / 2, x1 + w1 / 2, y1 - h1 / 2, y1 + h1 / 2
    bx1, bx2, by1, by2 = x2 - w2 / 2, x2 + w2 / 2, y2 - h2 / 2, y2 + h2 / 2
    inter = (torch.minimum(ax2, bx2) - torch.maximum(ax1, bx1)).clamp(0) * \
            (torch.minimum(ay2, by2) - torch.maximum(ay1, by1)).clamp(0)
    union = w1 * h1 + w2 * h2 - inter + eps
    iou = inter / union
    cw = torch.maximum(ax2, bx2) - torch.minimum(ax1, bx1)
    ch = torch.maximum(ay2, by2) - torch.minimum(ay1, by1)
    c2 = cw ** 2 + ch ** 2 + eps
    rho2 = (x2 - x1) ** 2 + (y2 - y1) ** 2
    v = (4 / math.pi ** 2) * (torch.atan(w2 / (h2 + eps)) - torch.atan(w1 / (h1 + eps))) ** 2
    with torch.no_grad():
        alpha = v / (v - iou + (1 + eps))
    return iou - (rho2 / c2 + v * alpha)


class YoloLoss:
    def __init__(self, model, imgsz: int):
        det = model.head
        self.balance = BALANCE[det.nl]
        self.anchors, self.nc, self.nl, self.na = det.anchors, det.nc, det.nl, det.na
        scale = 3 / self.nl
        self.gain = {"box": HYP["box"] * scale, "cls": HYP["cls"] * self.nc / 80 * scale,
                     "obj": HYP["obj"] * (imgsz / 640) ** 2 * scale}
        self.bce = nn.BCEWithLogitsLoss()

    def __call__(self, raw: list[torch.Tensor], targets: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """raw maps (per level (I, A, h, w, 5 + C)) -> (total loss x batch size, (box, obj, cls))."""
        lbox = lobj = lcls = torch.zeros((), dtype=raw[0].dtype)
        for i, (p, (b, a, gj, gi, tbox, anchor, tcls)) in enumerate(zip(raw, self._assign(raw, targets))):
            tobj = torch.zeros(p.shape[:4], dtype=p.dtype)
            if len(b):
                pxy, pwh, _, pcls = p[b, a, gj, gi].split((2, 2, 1, self.nc), 1)
                box = torch.cat((pxy.sigmoid() * 2 - 0.5, (pwh.sigmoid() * 2) ** 2 * anchor), 1)
                iou = ciou(box, tbox)
                lbox = lbox + (1.0 - iou).mean()
                tobj[b, a, gj, gi] = iou.detach().clamp(0).to(p.dtype)
                t = torch.zeros_like(pcls)
                t[torch.arange(len(b)), tcls] = 1.0
                lcls = lcls + self.bce(pcls, t)
            lobj = lobj + self.bce(p[..., 4], tobj) * self.balance[i]
        parts = torch.stack((lbox * self.gain["box"], lobj * self.gain["obj"], lcls * self.gain["cls"]))
        return parts.sum() * raw[0].shape[0], parts.detach()

    def _assign(self, raw, targets):
        nt = targets.shape[0]
        ai = torch.arange(self.na, dtype=torch.float32).view(self.na, 1).repeat(1, nt)
        tg = torch.cat((targets.float().repeat(self.na, 1, 1), ai[..., None]), 2)  # (A, T, 7)
        for i, p in enumerate(raw):
            h, w = p.shape[2], p.shape[3]
            gain = torch.tensor([1, 1, w, h, w, h, 1], dtype=torch.float32)
            anchors = self.anchors[i].float()
            t = tg * gain
            if nt:
                r = t[..., 4:6] / anchors[:, None]
                t = t[torch.max(r, 1 / r).max(2)[0] < HYP["anchor_t"]]
                gxy = t[:, 2:4]
                gxi = gain[[2, 3]] - gxy
                j, k = ((gxy % 1 < 0.5) & (gxy > 1)).T
                l, m = ((gxi % 1 < 0.5) & (gxi > 1)).T
                sel = torch.stack((torch.ones_like(j), j, k, l, m))
                t = t.repeat((5, 1, 1))[sel]
                offsets = (torch.zeros_like(gxy)[None] + _OFFSETS[:, None])[sel]
            else:
                t, offsets = tg[0], torch.zeros((0, 2))
            b, c = t[:, 0].long(), t[:, 1].long()
            gxy, gwh, a = t[:, 2:4], t[:, 4:6], t[:, 6].long()
            gij = (gxy - offsets).long()
            gi, gj = gij[:, 0].clamp(0, w - 1), gij[:, 1].clamp(0, h - 1)
            tbox = torch.cat((gxy - torch.stack((gi, gj), 1), gwh), 1)
            yield b, a, gj, gi, tbox, anchors[a], c
