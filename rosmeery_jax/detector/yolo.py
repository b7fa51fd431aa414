"""YOLO-v5 (release 6/7 architecture) in plain torch: backbone, neck, head, decode and NMS.

Module and parameter names follow the official ``models/yolo.py`` / ``models/common.py``
layer for layer (``model.0.conv.weight`` ... ``model.24.m.2.bias``, ``model.24.anchors``),
so official checkpoints load with ``strict=True`` (see :mod:`.checkpoint`). Sizes: ``n``
and ``s`` (and ``m``, ``l``, ``x``) from depth / width multiples, any number of classes.
``p2=True`` is the official ``yolov5-p2`` graph: a fourth head level at stride 4 for objects
a few pixels across (its anchors are ours: the P3 ones halved, as official ``yolov5-p2``
leaves them to its auto-anchor step).

Shapes: I images, C classes, A anchors per level (3), D detections.
NMS is :func:`rosmeery_jax.detector.boxes.nms` (numpy).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from rosmeery_jax.detector.boxes import nms

SIZES = {"n": (0.33, 0.25), "s": (0.33, 0.50), "m": (0.67, 0.75), "l": (1.0, 1.0), "x": (1.33, 1.25)}
ANCHORS = ((10, 13, 16, 30, 33, 23), (30, 61, 62, 45, 59, 119), (116, 90, 156, 198, 373, 326))  # pixels
STRIDES = (8, 16, 32)
P2_ANCHORS, P2_STRIDE = (5, 6, 8, 15, 16, 11), 4


class Conv(nn.Module):
    """Conv2d (no bias) + BatchNorm + SiLU, 'same' padding."""

    def __init__(self, c1: int, c2: int, k: int = 1, s: int = 1, p: int | None = None):
        super().__init__()
        self.conv = nn.Conv2d(c1, c2, k, s, k // 2 if p is None else p, bias=False)
        self.bn = nn.BatchNorm2d(c2, eps=1e-3, momentum=0.03)  # the official hyper-parameters
        self.act = nn.SiLU()

    def forward(self, x):
        return self.act(self.bn(self.conv(x)))


class Bottleneck(nn.Module):
    def __init__(self, c1: int, c2: int, shortcut: bool = True):
        super().__init__()
        self.cv1 = Conv(c1, c2, 1, 1)
        self.cv2 = Conv(c2, c2, 3, 1)
        self.add = shortcut and c1 == c2

    def forward(self, x):
        y = self.cv2(self.cv1(x))
        return x + y if self.add else y


class C3(nn.Module):
    """CSP bottleneck with three convolutions."""

    def __init__(self, c1: int, c2: int, n: int = 1, shortcut: bool = True):
        super().__init__()
        c_ = c2 // 2
        self.cv1 = Conv(c1, c_, 1, 1)
        self.cv2 = Conv(c1, c_, 1, 1)
        self.cv3 = Conv(2 * c_, c2, 1)
        self.m = nn.Sequential(*(Bottleneck(c_, c_, shortcut) for _ in range(n)))

    def forward(self, x):
        return self.cv3(torch.cat((self.m(self.cv1(x)), self.cv2(x)), 1))


class SPPF(nn.Module):
    """Spatial pyramid pooling, fast: three chained 5x5 max pools."""

    def __init__(self, c1: int, c2: int, k: int = 5):
        super().__init__()
        c_ = c1 // 2
        self.cv1 = Conv(c1, c_, 1, 1)
        self.cv2 = Conv(c_ * 4, c2, 1, 1)
        self.m = nn.MaxPool2d(k, 1, k // 2)

    def forward(self, x):
        x = self.cv1(x)
        y1 = self.m(x)
        y2 = self.m(y1)
        return self.cv2(torch.cat((x, y1, y2, self.m(y2)), 1))


class Concat(nn.Module):
    def forward(self, xs):
        return torch.cat(xs, 1)


class Detect(nn.Module):
    """One 1x1 conv per level; ``anchors`` (L, A, 2) in grid units of each level's stride
    (L levels: 3, or 4 with P2)."""

    def __init__(self, nc: int, ch: tuple[int, ...]):
        super().__init__()
        self.nc, self.no, self.nl, self.na = nc, nc + 5, len(ch), len(ANCHORS[0]) // 2
        anchors, strides = ((P2_ANCHORS, *ANCHORS)[-self.nl:], (P2_STRIDE, *STRIDES)[-self.nl:])  # the coarsest nl
        self.register_buffer("anchors", torch.tensor(anchors, dtype=torch.float32).view(self.nl, -1, 2)
                             / torch.tensor(strides, dtype=torch.float32).view(-1, 1, 1))
        self.m = nn.ModuleList(nn.Conv2d(c, self.no * self.na, 1) for c in ch)
        self.stride = strides

    def forward(self, xs):
        """Raw maps: per level (I, A, h, w, 5 + C) logits."""
        out = []
        for i, x in enumerate(xs):
            y = self.m[i](x)
            n, _, h, w = y.shape
            out.append(y.view(n, self.na, self.no, h, w).permute(0, 1, 3, 4, 2).contiguous())
        return out

    def decode(self, raw):
        """(I, sum A*h*w, 5 + C): box centre x, y, width, height in input pixels, objectness
        and class probabilities."""
        out = []
        for i, y in enumerate(raw):
            n, a, h, w, _ = y.shape
            s = self.stride[i]
            gy, gx = torch.meshgrid(torch.arange(h, dtype=y.dtype), torch.arange(w, dtype=y.dtype), indexing="ij")
            grid = torch.stack((gx, gy), -1).view(1, 1, h, w, 2) - 0.5
            anchor = (self.anchors[i] * s).view(1, a, 1, 1, 2).to(y.dtype)
            p = y.sigmoid()
            xy = (p[..., :2] * 2 + grid) * s
            wh = (p[..., 2:4] * 2) ** 2 * anchor
            out.append(torch.cat((xy, wh, p[..., 4:]), -1).view(n, -1, self.no))
        return torch.cat(out, 1)


def _ch(c: float, width: float) -> int:
    return int(math.ceil(c * width / 8) * 8)


def _n(n: int, depth: float) -> int:
    return max(round(n * depth), 1)


class YOLOv5(nn.Module):
    """The official YOLO-v5 graph; ``model`` is the ``nn.Sequential`` of the official
    checkpoints (layer i's parameters are ``model.i.*``): 25 layers, or 32 with ``p2``."""

    def __init__(self, nc: int = 80, size: str = "n", names: list[str] | None = None, p2: bool = False):
        super().__init__()
        if size not in SIZES:
            raise ValueError(f"unknown YOLO-v5 size {size!r} (sizes: {', '.join(SIZES)})")
        d, w = SIZES[size]
        c = lambda x: _ch(x, w)  # noqa: E731
        n = lambda x: _n(x, d)  # noqa: E731
        layers = [
            Conv(3, c(64), 6, 2, 2), Conv(c(64), c(128), 3, 2), C3(c(128), c(128), n(3)),
            Conv(c(128), c(256), 3, 2), C3(c(256), c(256), n(6)),
            Conv(c(256), c(512), 3, 2), C3(c(512), c(512), n(9)),
            Conv(c(512), c(1024), 3, 2), C3(c(1024), c(1024), n(3)), SPPF(c(1024), c(1024), 5),
            # head: up to stride 8 (or 4), then back down
            Conv(c(1024), c(512), 1, 1), nn.Upsample(None, 2, "nearest"), Concat(),
            C3(c(1024), c(512), n(3), False),
            Conv(c(512), c(256), 1, 1), nn.Upsample(None, 2, "nearest"), Concat(),
            C3(c(512), c(256), n(3), False),
        ]
        if p2:
            layers += [Conv(c(256), c(128), 1, 1), nn.Upsample(None, 2, "nearest"), Concat(),
                       C3(c(256), c(128), n(1), False),
                       Conv(c(128), c(128), 3, 2), Concat(), C3(c(256), c(256), n(3), False)]
        layers += [
            Conv(c(256), c(256), 3, 2), Concat(), C3(c(512), c(512), n(3), False),
            Conv(c(512), c(512), 3, 2), Concat(), C3(c(1024), c(1024), n(3), False),
            Detect(nc, ((c(128),) if p2 else ()) + (c(256), c(512), c(1024))),
        ]
        self.model = nn.Sequential(*layers)
        self.nc, self.size, self.p2 = nc, size, p2
        self.names = list(names) if names is not None else [str(i) for i in range(nc)]
        # Which earlier outputs each Concat joins with the previous layer's, and which
        # layers feed the head (the official "from").
        if p2:
            self._concat, self._levels = {12: 6, 16: 4, 20: 2, 23: 18, 26: 14, 29: 10}, (21, 24, 27)
        else:
            self._concat, self._levels = {12: 6, 16: 4, 19: 14, 22: 10}, (17, 20)
        self._init_biases()

    @property
    def head(self) -> Detect:
        return self.model[-1]

    def forward(self, x: torch.Tensor):
        """x (I, 3, H, W) float in [0, 1], H and W multiples of 32 -> raw maps per level."""
        saved = {}
        for i, layer in enumerate(self.model):
            if i in self._concat:
                x = layer((x, saved[self._concat[i]]))
            elif layer is self.head:
                return layer(tuple(saved[j] for j in self._levels) + (x,))
            else:
                x = layer(x)
            saved[i] = x
        raise AssertionError("unreachable")

    def _init_biases(self) -> None:
        """The official prior: objectness for ~8 objects per 640^2 image, classes ~ 0.6 / C."""
        det = self.head
        for conv, s in zip(det.m, det.stride):
            b = conv.bias.detach().view(det.na, -1)
            b[:, 4] += math.log(8 / (640 / s) ** 2)
            b[:, 5:] += math.log(0.6 / (det.nc - 0.99999))
            conv.bias = nn.Parameter(b.view(-1), requires_grad=True)
        for m in self.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.eps, m.momentum = 1e-3, 0.03

    @torch.no_grad()
    def decoded(self, images: torch.Tensor) -> torch.Tensor:
        """images (I, 3, H, W) in [0, 1] -> the decoded head (I, A, 5 + C): what every runtime
        computes (rosmeery_jax.detector.runtime)."""
        return self.head.decode(self(images))

    def detect(self, images: torch.Tensor, conf: float = 0.25, iou: float = 0.45, max_det: int = 100):
        """images (I, 3, H, W) in [0, 1] -> list of I arrays (D, 6): x1, y1, x2, y2 (pixels),
        confidence (objectness x class probability), class index."""
        with torch.inference_mode():
            return nms(self.decoded(images).numpy(), conf, iou, max_det)
