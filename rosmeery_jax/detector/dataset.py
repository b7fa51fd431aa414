"""Detector training data rendered by the simulator, labels free from the segmentation.

``generate`` renders RGB frames (the session's detector resolution) from random reachable
viewpoints of the worlds, most of them turned towards an object, and writes YOLO-format
labels: one line ``class xc yc w h`` (normalised) per object whose visible area is at least
``min_pixels``, class = the object's taxonomy category index.

Variety: training frames get, with probability ``perturb``, a random colour per object
(each channel scaled by 0.6-1.4), a random floor tint and a global brightness change.
Validation frames are rendered as the session renders them.

Split: viewpoints are grouped into ``block`` x ``block`` metre squares of each world; a
square's frames all go to validation when a hash of (world, square) falls in the held-out
fifth, so validation viewpoints are places the training set never stood in.

No torch here: rendering is the JAX raycaster. Layout of ``OUT``::

    images/{train,val}/<world>_<k>.png   labels/{train,val}/<world>_<k>.txt   data.json
"""

from __future__ import annotations

import json
import shutil
import zlib
from dataclasses import asdict, dataclass
from functools import cache
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from rosmeery_jax.core import xla
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.raycast.kernel import SMALL_BITS, RayScene, padded_boxes, ray_scene
from rosmeery_jax.raycast.sensors import CameraConfig, rgb
from rosmeery_jax.world import load_world
from rosmeery_jax.world.taxonomy import load_taxonomy


@dataclass(frozen=True)
class DatasetConfig:
    worlds: tuple[str, ...] = ("kitchen", "laboratory", "small_office", "large_office")
    per_world: int = 1500  # viewpoints drawn per world (train + val)
    seed: int = 0
    min_pixels: int = 40  # visible pixels for an object to be labelled
    perturb: float = 0.7  # share of training frames with perturbed colours
    block: float = 1.5  # metres: side of the squares the split holds out
    val_share: float = 0.2
    aim: float = 0.75  # share of viewpoints turned towards an object (the rest random yaw)
    balance: bool = False  # aim at each category equally often, not each object (rare classes
    # get more views: a world's one dining table as many as its twelve chairs)
    near: float = 0.0  # share of aimed viewpoints standing NEAR metres from their object (close,
    # cut-off views, as in small rooms; 0: wherever the robot can stand, as before)
    far: float = 0.0  # share of the other aimed viewpoints standing FAR metres from their object
    # with a clear line to a corner of it (small, distant, partly hidden views, as through a doorway)
    more: tuple[tuple[str, float], ...] = ()  # (category, factor): with ``balance``, aim at these
    # categories ``factor`` times as often as at the others (more views of weak classes)


NEAR = (0.6, 2.0)  # metres from the aimed object's centre, for the ``near`` share
FAR = (4.0, 10.0)  # the same for the ``far`` share
FAR_TRIES = 256  # cells of the ring tried for a clear line, at random
FAR_STOP = 0.15  # metres short of a footprint corner where the line may end in the object's own cells


def visible_boxes(labels: np.ndarray, min_pixels: int) -> np.ndarray:
    """Per visible object in a label image (H, W): rows (object, x1, y1, x2, y2, pixels),
    corners in pixels (x2, y2 exclusive), objects with at least ``min_pixels`` pixels, by
    object index. One pass over the image: the object pixels sorted by object, then each
    object's extremes by ``reduceat`` (a mask per object took 0.18 against 0.10 ms for a
    160 x 128 frame)."""
    w = labels.shape[1]
    flat = labels.ravel()
    where = np.flatnonzero(flat >= 0)
    order = np.argsort(flat[where], kind="stable")
    ids, where = flat[where][order], where[order]
    if not len(ids):
        return np.zeros((0, 6), np.int64)
    start = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    ys, xs = np.divmod(where, w)
    count = np.diff(np.r_[start, len(ids)])
    rows = np.stack([ids[start], np.minimum.reduceat(xs, start), np.minimum.reduceat(ys, start),
                     np.maximum.reduceat(xs, start) + 1, np.maximum.reduceat(ys, start) + 1, count], -1)
    return rows[count >= min_pixels].astype(np.int64)


def _is_val(world: str, xy: np.ndarray, cfg: DatasetConfig) -> np.ndarray:
    cells = np.floor(xy / cfg.block).astype(np.int64)
    h = np.array([zlib.crc32(f"{world}:{i}:{j}".encode()) for i, j in cells], np.int64)
    return (h % 1000) < cfg.val_share * 1000


def aim_shares(categories: np.ndarray, more: dict[int, float] | None = None) -> np.ndarray:
    """(N,) probability of aiming at each object so that every category present is aimed at
    equally often (objects of one category share its turn), or ``more[c]`` times as often
    for the categories ``c`` it names."""
    weight = 1.0 / np.bincount(categories)[categories]
    weight = weight * np.array([(more or {}).get(int(c), 1.0) for c in categories])
    return weight / weight.sum()


def viewpoints(world, cfg: DatasetConfig, rng: np.random.Generator) -> np.ndarray:
    """(per_world, 3) camera poses at reachable cells, mostly looking at an object."""
    fs = world.free_space
    ii, jj = np.nonzero(fs.reachable)
    k = rng.integers(len(ii), size=cfg.per_world)
    xy = np.stack([fs.origin[0] + (jj[k] + rng.random(cfg.per_world)) * fs.resolution,
                   fs.origin[1] + (ii[k] + rng.random(cfg.per_world)) * fs.resolution], -1)
    centres = world.truth.bbox_center[:, :2]
    if cfg.balance:
        names = list(load_taxonomy().names)
        share = aim_shares(np.asarray(world.truth.category_index), {names.index(n): x for n, x in cfg.more})
        aim_at = rng.choice(len(centres), size=cfg.per_world, p=share)
    else:  # uniform over objects (drawn as before ``balance`` existed: same datasets)
        aim_at = rng.integers(len(centres), size=cfg.per_world)
    pick = centres[aim_at]
    noise = rng.normal(0, 0.35, cfg.per_world)
    aimed = rng.random(cfg.per_world) < cfg.aim
    yaw = rng.uniform(-np.pi, np.pi, cfg.per_world)
    near = np.zeros(cfg.per_world, bool)
    if cfg.near > 0:  # drawn after the rest: datasets without it are unchanged
        near = aimed & (rng.random(cfg.per_world) < cfg.near)
        xy = _near(xy, pick, near, fs, ii, jj, rng)
    if cfg.far > 0:  # drawn after ``near``, for the same reason
        far = aimed & ~near & (rng.random(cfg.per_world) < cfg.far)
        xy = _far(xy, pick, far, footprint_corners(world.truth, aim_at), fs, ii, jj, rng)
    towards = np.arctan2(pick[:, 1] - xy[:, 1], pick[:, 0] - xy[:, 0]) + noise
    return np.concatenate([xy, np.where(aimed, towards, yaw)[:, None]], -1).astype(np.float32)


def _near(xy: np.ndarray, pick: np.ndarray, which: np.ndarray, fs, ii: np.ndarray, jj: np.ndarray,
          rng: np.random.Generator) -> np.ndarray:
    """xy (P, 2) with the viewpoints ``which`` (P,) moved to a random reachable cell within
    :data:`NEAR` of their object's centre ``pick`` (P, 2) (left where they are if none is)."""
    return _stand_in_ring(xy, pick, which, NEAR, fs, ii, jj, rng)


def _stand_in_ring(xy: np.ndarray, pick: np.ndarray, which: np.ndarray, ring: tuple[float, float], fs,
                   ii: np.ndarray, jj: np.ndarray, rng: np.random.Generator, keep=None) -> np.ndarray:
    """xy (P, 2) with the viewpoints ``which`` (P,) moved to a random reachable cell (``ii``,
    ``jj``) ``ring`` metres from their object's centre ``pick`` (P, 2), among those that
    ``keep(p, cells (K, 2)) -> (K,) bool`` keeps (all without it); left where they are if none is."""
    cells = np.stack([fs.origin[0] + (jj + 0.5) * fs.resolution, fs.origin[1] + (ii + 0.5) * fs.resolution], -1)
    out = xy.copy()
    for p in np.flatnonzero(which).tolist():
        d = np.linalg.norm(cells - pick[p], axis=-1)
        ok = np.flatnonzero((d >= ring[0]) & (d <= ring[1]))
        if keep is not None:
            ok = rng.permutation(ok)[:FAR_TRIES]  # a sample of the ring: ``keep`` may be costly
            ok = ok[keep(p, cells[ok])]
        if len(ok):
            out[p] = cells[ok[rng.integers(len(ok))]] + (rng.random(2) - 0.5) * fs.resolution
    return out


def footprint_corners(t, k: np.ndarray, inset: float = 0.8) -> np.ndarray:
    """(P, 4, 2) corners of the floor footprint of objects ``k`` (P,) of the ground truth
    ``t``, drawn in towards the centre to ``inset`` of the half-size (inside the object)."""
    c, s = np.cos(t.bbox_yaw[k]), np.sin(t.bbox_yaw[k])
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (P, 2, 2)
    signs = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], float)
    half = signs[None] * (t.bbox_size[k, None, :2] / 2 * inset)  # (P, 4, 2)
    return t.bbox_center[k, None, :2] + np.einsum("pij,pcj->pci", rot, half)


def clear_line(fs, start: np.ndarray, end: np.ndarray, stop: float, step: float = 0.05) -> np.ndarray:
    """(K,) whether the segments from ``start`` (K, 2) towards ``end`` (K, 2), up to ``stop``
    metres short of ``end``, cross no occupied cell of the free-space grid ``fs``."""
    gap = end - start
    length = np.linalg.norm(gap, axis=-1)
    t = np.arange(0.0, 1.0, step / max(float(length.max(initial=0.0)), step))
    pts = start[:, None] + t[None, :, None] * gap[:, None]  # (K, S, 2)
    shape = np.array(fs.occupied.shape)
    cell = np.floor((pts - fs.origin) / fs.resolution).astype(np.int64)[..., ::-1]  # (row, col)
    inside = ((cell >= 0) & (cell < shape)).all(-1)
    cell = np.clip(cell, 0, shape - 1)
    blocked = fs.occupied[cell[..., 0], cell[..., 1]] | ~inside
    counts = t[None] * length[:, None] <= (length - stop)[:, None]
    return ~(blocked & counts).any(1)


def _far(xy: np.ndarray, pick: np.ndarray, which: np.ndarray, corners: np.ndarray, fs, ii: np.ndarray,
         jj: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """xy (P, 2) with the viewpoints ``which`` (P,) moved to a random reachable cell within
    :data:`FAR` of their object's centre ``pick`` (P, 2) with a clear line to at least one of
    its footprint's ``corners`` (P, 4, 2): the object whole or partly hidden, as through a
    doorway (left where they are if no cell is)."""
    def sees(p: int, cells: np.ndarray) -> np.ndarray:
        return np.any([clear_line(fs, cells, np.broadcast_to(c, cells.shape), FAR_STOP) for c in corners[p]], 0)

    return _stand_in_ring(xy, pick, which, FAR, fs, ii, jj, rng, keep=sees)


SCENE_BUCKET = 128  # scenes are padded to a multiple of this many boxes: one compile per bucket


def _render(rs: RayScene, cam: CameraConfig, pose: jax.Array, scale: jax.Array):
    """RGB (B, H, W, 3) and labels (B, H, W) at poses (B, 3) with colour scales (B, G + 1, 3)."""
    g = rs.num_boxes

    def one(p, s):
        scene = rs._replace(rgb=jnp.clip(rs.rgb * s[:g], 0, 1), floor_rgb=jnp.clip(rs.floor_rgb * s[g], 0, 1))
        return rgb(scene, cam, p)
    return jax.vmap(one)(pose, scale)


@cache
def renderer():
    """The compiled :func:`_render`, one for the process (made on first use: compiling options
    depend on JAX's backend, which importing this module must not start)."""
    return xla.jit(_render, static_argnames="cam")


def render_world(world, poses: np.ndarray, rgb_scale: np.ndarray | None = None, batch: int = 64,
                 camera=None):
    """RGB (P, H, W, 3) uint8 and labels (P, H, W) at robot poses (P, 3); ``rgb_scale``
    (P, G + 1, 3) multiplies each box's colour (last row: the floor) per frame.

    The scene travels as an argument padded to a bucket of boxes (kept below the packed
    key's small-scene size, so images are bitwise those of the unpadded scene): a dataset of
    hundreds of worlds compiles a handful of times, not once per world."""
    cam = camera or CameraConfig()
    g = padded_boxes(world.scene.num_boxes)  # the colour scales' G
    bucket = -(-g // SCENE_BUCKET) * SCENE_BUCKET
    small = 2 ** SMALL_BITS
    rs = ray_scene(world.scene, g if g < small <= bucket else bucket)
    if rgb_scale is None:
        rgb_scale = np.ones((len(poses), g + 1, 3), np.float32)
    # padding boxes keep scale 1; the floor's row moves to the end
    rgb_scale = np.concatenate([rgb_scale[:, :g], np.ones((len(poses), rs.num_boxes - g, 3), np.float32),
                                rgb_scale[:, g:]], 1)
    imgs, labs = [], []
    for i in range(0, len(poses), batch):
        p, s = poses[i:i + batch], rgb_scale[i:i + batch]
        pad = batch - len(p)  # one compiled shape
        out = renderer()(rs, cam, jnp.asarray(np.concatenate([p, np.repeat(p[-1:], pad, 0)])),
                           jnp.asarray(np.concatenate([s, np.repeat(s[-1:], pad, 0)])))
        imgs.append(np.asarray(out[0])[:len(p)])
        labs.append(np.asarray(out[1])[:len(p)])
    return np.concatenate(imgs), np.concatenate(labs)


def _perturbations(world, n: int, share: float, rng: np.random.Generator, num_boxes: int) -> np.ndarray:
    """(n, G + 1, 3) colour scales: per object (all its boxes alike), walls, floor; identity for
    the frames left unperturbed."""
    owner = np.asarray(world.scene.object_id)
    nobj = world.truth.num_objects
    out = np.ones((n, num_boxes + 1, 3), np.float32)
    for f in np.nonzero(rng.random(n) < share)[0]:
        per_obj = rng.uniform(0.6, 1.4, (nobj + 1, 3)).astype(np.float32)  # last row: walls
        scale = per_obj[np.where(owner >= 0, owner, nobj)]
        out[f, :len(owner)] = scale * rng.uniform(0.8, 1.2)
        out[f, num_boxes] = rng.uniform(0.8, 1.2, 3)
    return out


def yolo_rows(labels: np.ndarray, categories: np.ndarray, min_pixels: int) -> np.ndarray:
    """YOLO label rows (k, 5): class, xc, yc, w, h normalised, for one label image (H, W)."""
    h, w = labels.shape
    b = visible_boxes(labels, min_pixels)
    if not len(b):
        return np.zeros((0, 5), np.float32)
    x1, y1, x2, y2 = b[:, 1], b[:, 2], b[:, 3], b[:, 4]
    return np.stack([categories[b[:, 0]], (x1 + x2) / 2 / w, (y1 + y2) / 2 / h, (x2 - x1) / w, (y2 - y1) / h],
                    -1).astype(np.float32)


def generate(cfg: DatasetConfig, splits: tuple[str, ...] = ("train", "val"), progress: bool = True):
    """Yield (split, world name, index, rgb (H, W, 3) uint8, rows (k, 5)) frame by frame."""
    for w_i, name in enumerate(cfg.worlds):
        world = load_world(name)
        rng = np.random.default_rng([cfg.seed, w_i])
        poses = viewpoints(world, cfg, rng)
        val = _is_val(world.name, poses[:, :2], cfg)
        scales = _perturbations(world, len(poses), cfg.perturb, rng, padded_boxes(world.scene.num_boxes))
        scales[val] = 1.0
        keep = np.array([("val" if v else "train") in splits for v in val])
        idx = np.nonzero(keep)[0]
        if not len(idx):
            continue
        imgs, labs = render_world(world, poses[idx], scales[idx])
        cats = np.asarray(world.truth.category_index)
        for k, img, lab in tqdm(zip(idx, imgs, labs), total=len(idx), disable=not progress, desc=world.name):
            yield ("val" if val[k] else "train"), world.name, int(k), img, yolo_rows(lab, cats, cfg.min_pixels)


FRAME_BYTES = 20_000  # a rendered frame's PNG and label file, generously (about 15 kB at 160 x 128)


def check(cfg: DatasetConfig, out: Path, source: str = "command line") -> None:
    """The worlds named once each (a world twice wrote its frames over each other) and the
    frames within the disk space free where ``out`` goes; one InputError otherwise."""
    if not cfg.worlds:
        raise InputError(source, "--worlds", "name at least one world")
    names = load_taxonomy().names
    for n, x in cfg.more:
        if n not in names or not (np.isfinite(x) and x > 0):
            raise InputError(source, "--more", f"{n}={x}: name a category of the taxonomy and a factor above 0")
    if cfg.more and not cfg.balance:
        raise InputError(source, "--more", "weights the balanced aim: give --balance too")
    twice = next((w for w in cfg.worlds if cfg.worlds.count(w) > 1), None)
    if twice is not None:
        raise InputError(source, "--worlds", f"{twice!r} appears twice")
    need = float(cfg.per_world) * len(cfg.worlds) * FRAME_BYTES
    free = shutil.disk_usage(next(p for p in (out, *out.parents) if p.exists())).free
    if need > free:
        raise InputError(source, "--per-world", f"{cfg.per_world} viewpoints x {len(cfg.worlds)} worlds need about "
                         f"{need / 1e9:,.1f} GB on disk, more than the {free / 1e9:,.1f} GB free at {out}")


def write(cfg: DatasetConfig, out: str | Path, progress: bool = True) -> dict:
    """Render the dataset into ``out`` (see the module docstring) after :func:`check`;
    returns its summary."""
    out = Path(out).absolute()
    check(cfg, out)
    counts = {"train": 0, "val": 0}
    boxes = {"train": 0, "val": 0}
    for split, world, k, img, rows in generate(cfg, progress=progress):
        stem = f"{world}_{k:05d}"
        (out / "images" / split).mkdir(parents=True, exist_ok=True)
        (out / "labels" / split).mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out / "images" / split / f"{stem}.png"), img[..., ::-1])
        (out / "labels" / split / f"{stem}.txt").write_text(
            "".join(f"{int(r[0])} {r[1]:.6f} {r[2]:.6f} {r[3]:.6f} {r[4]:.6f}\n" for r in rows))
        counts[split] += 1
        boxes[split] += len(rows)
    cam = CameraConfig()
    summary = {"config": asdict(cfg), "names": list(load_taxonomy().names), "imgsz": [cam.rgb_height, cam.rgb_width],
               "images": counts, "boxes": boxes}
    (out / "data.json").write_text(json.dumps(summary, indent=2))
    return summary


def read(root: str | Path, split: str) -> tuple[np.ndarray, list[np.ndarray], dict]:
    """Load a written split: images (I, H, W, 3) uint8 RGB, label rows per image, data.json."""
    root = Path(root)
    meta_path = root / "data.json"
    if not meta_path.is_file():
        raise InputError(str(meta_path), "file", "not found: make the dataset with `rosmeery detector dataset`")
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
        raise InputError(str(meta_path), "file", f"not valid JSON ({type(err).__name__})") from None
    files = sorted((root / "images" / split).glob("*.png"))
    if not files:
        raise InputError(str(root / "images" / split), "images", "no images in this split")
    imgs, rows, classes = [], [], len(load_taxonomy().names)
    for f in files:
        img = cv2.imread(str(f))
        if img is None:
            raise InputError(str(f), "image", "unreadable")
        if imgs and img.shape != imgs[0].shape:
            raise InputError(str(f), "image", f"{img.shape[1]}x{img.shape[0]} pixels, not {imgs[0].shape[1]}x"
                             f"{imgs[0].shape[0]} like {files[0].name}: a split's images share one size")
        imgs.append(img[..., ::-1])
        rows.append(_label_rows(root / "labels" / split / f"{f.stem}.txt", classes))
    return np.stack(imgs), rows, meta


def _label_rows(path: Path, classes: int) -> np.ndarray:
    """A YOLO label file as rows (B, 5) float32: class (a whole number below ``classes``),
    then the box's centre x, y and width, height as shares of the image, in [0, 1]."""
    try:
        lines = path.read_text().splitlines()
        r = np.array([line.split() for line in lines if line.strip()], np.float32).reshape(-1, 5)
    except (OSError, ValueError) as err:
        raise InputError(str(path), "rows", f"not YOLO label rows ({err})") from None
    ok = (r[:, 0] == np.round(r[:, 0])) & (r[:, 0] >= 0) & (r[:, 0] < classes)
    ok &= ((r[:, 1:] >= 0) & (r[:, 1:] <= 1)).all(1) & (r[:, 3:] > 0).all(1)  # NaN fails too
    if not ok.all():
        row = int(np.argmin(ok))
        raise InputError(str(path), f"row {row + 1}", f"{' '.join(f'{v:g}' for v in r[row])}: a row is a class "
                         f"(0-{classes - 1}), then x, y, w, h as shares of the image (0-1, w and h above 0)")
    return r
