"""Training YOLO-v5 from scratch on a rendered dataset, on the CPU, readable top to bottom.

Recipe (chosen for short CPU schedules, where AdamW converges faster than the official SGD):
AdamW, lr 1e-3 with one warm-up epoch then cosine decay to 1e-5, weight decay 5e-4 on
convolution weights only; an exponential moving average of the weights (decay 0.999,
ramped) is what gets evaluated and saved; augmentation: optionally a 2 x 2 mosaic of four
frames at half size (``mosaic``), horizontal flip, random zoom-crop (scale 0.7-1) and
brightness / contrast / per-channel gain jitter. The loss is the official one
(:mod:`.loss`). Every epoch logs the mean losses and the validation mAP@0.5 to ``log.csv``;
the weights with the best validation mAP are saved (fp16 state dict).
"""

from __future__ import annotations

import copy
import csv
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from rosmeery_jax.detector import checkpoint
from rosmeery_jax.detector.dataset import read
from rosmeery_jax.detector.loss import YoloLoss
from rosmeery_jax.detector.mean_ap import evaluate, model_detections, rows_to_xyxy
from rosmeery_jax.detector.yolo import YOLOv5


@dataclass(frozen=True)
class DetectorTrainConfig:
    size: str = "n"
    epochs: int = 40
    batch: int = 32
    lr: float = 1e-3
    weight_decay: float = 5e-4
    ema_decay: float = 0.999
    seed: int = 0
    threads: int = 2
    max_images: int = 0  # 0 = the whole training split (a cap for quick tests)
    mosaic: float = 0.0  # share of training images made a 2 x 2 mosaic at half size (far views)
    p2: bool = False  # a fourth head level at stride 4 (yolov5-p2), for objects a few pixels across


class EMA:
    def __init__(self, model, decay: float):
        self.model, self.decay, self.updates = copy.deepcopy(model).eval(), decay, 0
        for p in self.model.parameters():
            p.requires_grad_(False)

    @torch.no_grad()
    def update(self, model) -> None:
        self.updates += 1
        d = self.decay * (1 - math.exp(-self.updates / 2000))  # ramp: early steps follow closely
        msd = model.state_dict()
        for k, v in self.model.state_dict().items():
            if v.dtype.is_floating_point:
                v.mul_(d).add_(msd[k].detach(), alpha=1 - d)
            else:
                v.copy_(msd[k])


def _to_rows(cls: np.ndarray, b: np.ndarray, w: int, h: int) -> np.ndarray:
    """Classes (k,) and pixel corners (k, 4) -> YOLO rows (k, 5)."""
    return np.stack([cls, (b[:, 0] + b[:, 2]) / 2 / w, (b[:, 1] + b[:, 3]) / 2 / h,
                     (b[:, 2] - b[:, 0]) / w, (b[:, 3] - b[:, 1]) / h], -1).astype(np.float32)


def mosaic(tiles: torch.Tensor, rows: list[np.ndarray]) -> tuple[torch.Tensor, np.ndarray]:
    """Four images (4, 3, H, W) at half size in a 2 x 2 grid (YOLOv5's mosaic, without its
    random centre): one image (3, H, W) whose objects look as from twice as far, and the
    four images' rows moved into their quadrants (boxes under 2 pixels a side dropped)."""
    _, _, h, w = tiles.shape
    small = F.interpolate(tiles, size=(h // 2, w // 2), mode="area")
    img = torch.cat([torch.cat([small[0], small[1]], -1), torch.cat([small[2], small[3]], -1)], -2)
    img = F.pad(img, (0, w - 2 * (w // 2), 0, h - 2 * (h // 2)), mode="replicate")
    out = []
    for q, r in enumerate(rows):
        b = rows_to_xyxy(r, h, w) / 2 + np.array([q % 2 * (w // 2), q // 2 * (h // 2)] * 2)
        keep = (b[:, 2] - b[:, 0] >= 2) & (b[:, 3] - b[:, 1] >= 2)
        out.append(_to_rows(r[keep, 0], b[keep], w, h))
    return img, np.concatenate(out) if out else np.zeros((0, 5), np.float32)


def augment(x: torch.Tensor, rows: list[np.ndarray], rng: np.random.Generator, mosaic_share: float = 0.0):
    """x (I, 3, H, W) in [0, 1], YOLO rows per image -> augmented batch and targets (T, 6).
    With probability ``mosaic_share`` an image becomes a :func:`mosaic` of itself and three
    others of the batch; then zoom-crop, flip and colour jitter."""
    n, _, h, w = x.shape
    out, targets = torch.empty_like(x), []
    for i in range(n):
        img, r = x[i], rows[i].copy()
        if mosaic_share > 0 and rng.random() < mosaic_share:  # no draw without it: same runs as before
            pick = np.r_[i, rng.choice(np.delete(np.arange(n), i), 3, replace=n < 4)] if n > 1 else np.zeros(4, int)
            img, r = mosaic(x[pick], [rows[j] for j in pick])
        s = rng.uniform(0.7, 1.0) if rng.random() < 0.5 else 1.0
        if s < 1.0:  # zoom: crop a window of scale s, resize back; boxes follow and are clipped
            cw, ch = s * w, s * h
            x0, y0 = rng.uniform(0, w - cw), rng.uniform(0, h - ch)
            y0i, x0i = int(y0), int(x0)
            img = F.interpolate(img[None, :, y0i:y0i + int(ch), x0i:x0i + int(cw)], size=(h, w),
                                mode="bilinear", align_corners=False)[0]
            if len(r):
                sx, sy = w / int(cw), h / int(ch)
                b = rows_to_xyxy(r, h, w)
                nb = np.stack([(b[:, 0] - x0i) * sx, (b[:, 1] - y0i) * sy, (b[:, 2] - x0i) * sx,
                               (b[:, 3] - y0i) * sy], -1)
                area0 = (nb[:, 2] - nb[:, 0]) * (nb[:, 3] - nb[:, 1])
                nb = np.clip(nb, 0, [w, h, w, h])
                area = (nb[:, 2] - nb[:, 0]) * (nb[:, 3] - nb[:, 1])
                keep = (area > 0.4 * area0) & (nb[:, 2] - nb[:, 0] > 3) & (nb[:, 3] - nb[:, 1] > 3)
                r = _to_rows(r[keep, 0], nb[keep], w, h)
        if rng.random() < 0.5:
            img = img.flip(-1)
            r[:, 1] = 1 - r[:, 1]
        gain = torch.from_numpy(rng.uniform(0.85, 1.15, 3).astype(np.float32)).view(3, 1, 1)
        contrast, bright = rng.uniform(0.75, 1.25), rng.uniform(-0.1, 0.1)
        img = ((img - 0.5) * contrast + 0.5 + bright) * gain
        out[i] = img.clamp(0, 1)
        targets.append(np.concatenate([np.full((len(r), 1), i, np.float32), r], 1))
    return out, torch.from_numpy(np.concatenate(targets) if targets else np.zeros((0, 6), np.float32))


def cosine(lr: float, t: float) -> float:
    """The learning rate at share ``t`` in [0, 1] of a cosine decay from ``lr`` to 1e-5."""
    return 1e-5 + 0.5 * (lr - 1e-5) * (1 + math.cos(math.pi * t))


def optimizer(model, lr: float, weight_decay: float) -> torch.optim.AdamW:
    """AdamW over ``model``'s parameters, weight decay on convolution weights only."""
    decay, other = [], []
    for mod in model.modules():
        for name, p in mod.named_parameters(recurse=False):
            (decay if name == "weight" and isinstance(mod, torch.nn.Conv2d) else other).append(p)
    return torch.optim.AdamW([{"params": decay, "weight_decay": weight_decay},
                              {"params": other, "weight_decay": 0.0}], lr=lr)


def fit_batch(model, ema: EMA, opt, compute_loss, x: torch.Tensor, targets: torch.Tensor, lr: float) -> torch.Tensor:
    """One optimisation step on batch x (I, 3, H, W) with targets (T, 6) at learning rate
    ``lr`` (gradients clipped to norm 10), the EMA updated; the loss's parts (3,)."""
    for g in opt.param_groups:
        g["lr"] = lr
    loss, parts = compute_loss(model(x), targets)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
    opt.step()
    ema.update(model)
    return parts


def log_file(out: str | Path) -> Path:
    """The per-epoch log written beside weights ``out``: ``<stem>.log.csv``."""
    return Path(out).with_name(Path(out).stem + ".log.csv")


def train(data: str | Path, out: str | Path, cfg: DetectorTrainConfig = DetectorTrainConfig(), progress: bool = True) -> dict:
    """Train on ``data`` (a dataset folder), write ``out`` (weights) and ``out``'s log.csv
    beside it; returns the best validation result."""
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed)
    images, rows, meta = read(data, "train")
    if cfg.max_images:
        images, rows = images[:cfg.max_images], rows[:cfg.max_images]
    val_images, val_rows, _ = read(data, "val")
    names = meta["names"]
    h, w = images.shape[1:3]
    model = YOLOv5(len(names), cfg.size, names, cfg.p2)
    compute_loss = YoloLoss(model, max(h, w))
    opt = optimizer(model, cfg.lr, cfg.weight_decay)
    ema = EMA(model, cfg.ema_decay)
    steps_per_epoch = math.ceil(len(images) / cfg.batch)
    total, warm = cfg.epochs * steps_per_epoch, steps_per_epoch

    def lr_at(step: int) -> float:
        if step < warm:
            return cfg.lr * (step + 1) / warm
        return cosine(cfg.lr, (step - warm) / max(1, total - warm))

    out = Path(out)
    log_path = log_file(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    best = {"map50": -1.0}
    step = 0
    started = time.time()
    with open(log_path, "w", newline="") as fh:
        log = csv.writer(fh)
        log.writerow(["epoch", "box", "obj", "cls", "val_map50", "val_precision", "val_recall", "lr", "wall_s"])
        for epoch in range(cfg.epochs):
            model.train()
            order = rng.permutation(len(images))
            parts_sum = torch.zeros(3)
            bar = tqdm(range(steps_per_epoch), disable=not progress, desc=f"epoch {epoch + 1}/{cfg.epochs}")
            for b in bar:
                idx = order[b * cfg.batch:(b + 1) * cfg.batch]
                x = torch.from_numpy(images[idx]).permute(0, 3, 1, 2).float() / 255
                x, targets = augment(x, [rows[i] for i in idx], rng, cfg.mosaic)
                parts = fit_batch(model, ema, opt, compute_loss, x, targets, lr_at(step))
                parts_sum += parts
                step += 1
                bar.set_postfix(loss=f"{float(parts.sum()):.3f}")
            result = evaluate(model_detections(ema.model, val_images), val_images, val_rows, model.nc)
            mean = (parts_sum / steps_per_epoch).tolist()
            log.writerow([epoch + 1, *[f"{v:.5f}" for v in mean], f"{result['map50']:.4f}",
                          f"{result['precision']:.4f}", f"{result['recall']:.4f}", f"{lr_at(step - 1):.2e}",
                          f"{time.time() - started:.0f}"])
            fh.flush()
            if progress:
                tqdm.write(f"epoch {epoch + 1}: loss box {mean[0]:.4f} obj {mean[1]:.4f} cls {mean[2]:.4f}  "
                           f"val mAP@0.5 {result['map50']:.3f}")
            if result["map50"] > best["map50"]:
                best = {**result, "epoch": epoch + 1}
                checkpoint.save(ema.model, out, (h, w), meta={
                    "train": asdict(cfg), "dataset": meta.get("config"), "epoch": epoch + 1,
                    "val_map50": result["map50"], "train_images": len(images), "val_images": len(val_images)})
    return best
