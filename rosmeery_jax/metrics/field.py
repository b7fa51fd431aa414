"""The field's map metrics beside ORI, cORI and OPI (docs/metrics.md, "The field's map
metrics"): BenchBot's OMQ, ScanNet's instance AP, object precision / recall / F1 (at an
IoU and by centroid containment), geometric accuracy / completeness / F-score / Chamfer,
and the semantic segmentation of the map (mIoU, mean accuracy, F-mIoU).

Every metric reads a :class:`Tally` of one map at one time: what each instance shares with
each object (the surface samples its points lie on), each instance's size, box and
centroid, and the nearest neighbours between map points and ground-truth samples within
20 cm. :class:`FieldScorer` keeps the tally of a map that grows (new points are looked up
once), as a session's mappers' maps and the built-in knowledge's map do; a map read from
disk is one growth from nothing. Shapes: P points, S samples, I instances, N objects,
C classes.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from rosmeery_jax.metrics import field_kernels as fk

TAUS = (0.05, 0.20)  # m: geometry's thresholds
REACH = max(TAUS)  # m: neighbours looked up within this
SEGMENT_RADIUS = 0.05  # m: a sample takes the label of the nearest map point within this
VOXEL = 0.05  # m: points on no object count once per cube of this side in an instance's size
MIN_BOX_POINTS = 4  # an instance of fewer points has no cuboid (spatial quality 0)
AP_THRESHOLDS = (0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8, 0.85, 0.9)  # ScanNet's AP averages these
PR_THRESHOLDS = (0.25, 0.5)

OMQ = ("omq", "omq_pairwise", "omq_label", "omq_spatial", "omq_fp_quality")
AP = ("ap", "ap50", "ap25")
OBJECTS = tuple(n for t in ("25", "50") for n in (f"precision{t}", f"recall{t}", f"f1_{t}")) + \
    tuple(f"{m}_{t}" for t in ("weak", "strict") for m in ("precision", "recall", "f1"))
GEOMETRY = tuple(f"{m}_{round(100 * t)}cm" for t in TAUS for m in ("accuracy", "completeness", "fscore", "chamfer"))
SEGMENTATION = ("miou", "macc", "fmiou")
FIELD_METRICS = OMQ + AP + OBJECTS + GEOMETRY + SEGMENTATION
FIELD_SET = "field"  # the name that selects them all


class FieldTruth(NamedTuple):
    """A world's ground truth as the field metrics read it: samples (S, 3) float64,
    sample_object (S,), sample_category (S,); per object category (N,), ps_G (N,), its
    box center (N, 3), size (N, 3), yaw (N,); classes (C,) the categories holding samples
    and sample_class (S,) each sample's index among them;
    the samples' grid (origin (3,), cell, dims (3,), start, order) for :func:`fk.near`."""

    samples: np.ndarray
    sample_object: np.ndarray
    sample_category: np.ndarray
    category: np.ndarray
    ps_G: np.ndarray
    center: np.ndarray
    size: np.ndarray
    yaw: np.ndarray
    classes: np.ndarray
    sample_class: np.ndarray
    origin: np.ndarray
    cell: float
    dims: np.ndarray
    start: np.ndarray
    order: np.ndarray

    @staticmethod
    def of(world) -> "FieldTruth":
        t = world.truth
        return FieldTruth.build(t.samples.points, t.samples.object, t.category_index, t.bbox_center, t.bbox_size,
                                t.bbox_yaw)

    @staticmethod
    def build(samples, sample_object, category, center, size, yaw) -> "FieldTruth":
        """From samples (S, 3) of objects sample_object (S,); per object its category (N,)
        and box center (N, 3), size (N, 3), yaw (N,)."""
        samples = np.asarray(samples, np.float64)
        obj = np.asarray(sample_object, np.int64)
        category = np.asarray(category, np.int64)
        origin = samples.min(0) - REACH
        dims = np.floor((samples.max(0) + REACH - origin) / REACH).astype(np.int64) + 1
        cells = np.floor((samples - origin) / REACH).astype(np.int64)
        key = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
        order = np.argsort(key, kind="stable")
        classes = np.unique(category[obj])
        start = np.searchsorted(key[order], np.arange(int(np.prod(dims)) + 1))
        return FieldTruth(samples, obj, category[obj], category, np.bincount(obj, minlength=len(category)),
                          np.asarray(center, np.float64), np.asarray(size, np.float64), np.asarray(yaw, np.float64),
                          classes, np.searchsorted(classes, category[obj]), origin, REACH, dims, start, order)


class Tally(NamedTuple):
    """One map at one time, as every field metric reads it. Per instance (I, the ids that
    hold points): shared (I, N) samples of each object it covers; size (I,) the samples it
    covers plus the cubes of its points on no object; count (I,) points; lo, hi (I, 3) its
    points' box; centroid (I, 3); label (I,) category (-1 none) and confidence (I,).
    Geometry, per tau of TAUS (2,): points_in and points_sum, the points within tau of a
    sample and the sum of their distances, of ``points``; samples_in and samples_sum, the
    same of the ``samples`` towards the map. confusion (C, C + 1): samples of each class
    by the class of their nearest map point's label within SEGMENT_RADIUS (last column:
    none, or a category holding no samples)."""

    shared: np.ndarray
    size: np.ndarray
    count: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    centroid: np.ndarray
    label: np.ndarray
    confidence: np.ndarray
    points: int
    points_in: np.ndarray
    points_sum: np.ndarray
    samples: int
    samples_in: np.ndarray
    samples_sum: np.ndarray
    confusion: np.ndarray


def wanted(names) -> tuple[str, ...]:
    """The field metrics among ``names``, in the order of FIELD_METRICS."""
    return tuple(n for n in FIELD_METRICS if n in names)


class FieldScorer:
    """The tally of one robot's map as it grows (module docstring): :meth:`tally` takes the
    map now (points, instance ids, per-id label and confidence) with each point's tied
    sample (-1 none; :func:`rosmeery_jax.metrics.map_score.tie`) and the object of each id
    it shares samples with (``shared`` per id, from the caller's counting). Points that only
    grow are looked up once; old points given other ids are re-aggregated; any other change
    starts again. The result is the same either way."""

    def __init__(self, truth: FieldTruth):
        self.truth = truth
        self.class_count = np.bincount(truth.sample_class, minlength=len(truth.classes))
        self._clear()

    def _clear(self) -> None:
        s = len(self.truth.samples)
        self.points = np.zeros((0, 3))
        self.instance = np.zeros(0, np.int64)
        self.points_in, self.points_sum = np.zeros(len(TAUS), np.int64), np.zeros(len(TAUS))
        self.samples_in, self.samples_sum = np.zeros(len(TAUS), np.int64), np.zeros(len(TAUS))
        self.sample_d2 = np.full(s, np.inf)
        self.sample_point = np.full(s, -1, np.int64)
        self.near_class = np.zeros((0, len(self.truth.classes)), np.int64)  # per id: samples nearest it, by class
        self.agg = _Aggregates.empty()

    def tally(self, points, instance, label, confidence, sample, shared_by_id) -> Tally:
        old = len(self.points)
        if not (len(points) >= old and np.array_equal(points[:old], self.points)):
            self._clear()
            old = 0
        instance = np.asarray(instance, np.int64)
        merged = not np.array_equal(instance[:old], self.instance)
        if merged:  # instances merged or renumbered: aggregate every point again
            self.agg = _Aggregates.empty()
            self.near_class[:] = 0
        top = int(instance.max()) + 1 if len(instance) else 0
        if top > len(self.near_class):
            self.near_class = np.r_[self.near_class, np.zeros((top - len(self.near_class),
                                                               len(self.truth.classes)), np.int64)]
        if merged:
            near = (self.sample_point >= 0) & (self.sample_d2 <= SEGMENT_RADIUS ** 2)
            np.add.at(self.near_class, (instance[self.sample_point[near]], self.truth.sample_class[near]), 1)
        self.agg = self.agg.add(points, instance, sample) if merged else \
            self.agg.add(points[old:], instance[old:], sample[old:])
        self._near(np.ascontiguousarray(points[old:], np.float64), old, instance)
        self.points, self.instance = np.asarray(points), instance
        return self._tally(label, confidence, shared_by_id)

    def _near(self, new: np.ndarray, base: int, instance: np.ndarray) -> None:
        """Look the new points up (numbered from ``base``): their distances to the samples,
        and the samples' nearest points, with the counts built on them."""
        t = self.truth
        d2 = np.full(len(new), np.inf)
        taus2 = np.asarray(TAUS) ** 2
        fk.near(new, base, instance, t.origin, t.cell, t.dims, t.start, t.order, t.samples, t.sample_class,
                REACH ** 2, SEGMENT_RADIUS ** 2, taus2, d2, self.sample_d2, self.sample_point, self.samples_in,
                self.samples_sum, self.near_class)
        for k, tau2 in enumerate(taus2):
            inlier = d2 <= tau2
            self.points_in[k] += int(inlier.sum())
            self.points_sum[k] += float(np.sqrt(d2[inlier]).sum())

    def _tally(self, label, confidence, shared_by_id) -> Tally:
        a, t = self.agg, self.truth
        ids = np.flatnonzero(a.count > 0)
        label = np.asarray(label, np.int64)
        shared = shared_by_id[ids] if len(ids) else np.zeros((0, len(t.ps_G)), np.int64)
        size = shared.sum(1) + a.untied[ids]
        count = a.count[ids]
        c = len(t.classes)
        table = np.full(max(int(t.classes.max()) + 2, int(label.max(initial=-1)) + 2), c)
        table[t.classes] = np.arange(c)  # the last entry (index -1): no label
        confusion = np.zeros((c + 1, c), np.int64)  # rows: the predicted class
        np.add.at(confusion, table[label[ids]], self.near_class[ids])
        confusion[c] += self.class_count - confusion.sum(0)  # samples with no map point near: no label
        return Tally(shared, size, count, a.lo[ids], a.hi[ids], a.total[ids] / np.maximum(count, 1)[:, None],
                     label[ids], np.asarray(confidence, np.float64)[ids], len(self.points), self.points_in.copy(),
                     self.points_sum.copy(), len(t.samples), self.samples_in.copy(), self.samples_sum.copy(),
                     confusion.T.copy())


class _Aggregates(NamedTuple):
    """Per instance id: count, lo, hi, total (sum of points), untied (cubes of points on no
    object), and the (id, cube) pairs seen."""

    count: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    total: np.ndarray
    untied: np.ndarray
    cubes: set  # grown in place: the aggregates belong to one scorer

    @staticmethod
    def empty() -> "_Aggregates":
        return _Aggregates(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)),
                           np.zeros(0, np.int64), set())

    def add(self, points, instance, sample) -> "_Aggregates":
        if not len(points):
            return self
        top = max(int(instance.max()) + 1, len(self.count))
        grow = top - len(self.count)
        count = np.r_[self.count, np.zeros(grow, np.int64)]
        lo = np.r_[self.lo, np.full((grow, 3), np.inf)]
        hi = np.r_[self.hi, np.full((grow, 3), -np.inf)]
        total = np.r_[self.total, np.zeros((grow, 3))]
        untied = np.r_[self.untied, np.zeros(grow, np.int64)]
        np.add.at(count, instance, 1)
        np.minimum.at(lo, instance, points)
        np.maximum.at(hi, instance, points)
        np.add.at(total, instance, points)
        off = sample < 0
        cubes = self.cubes
        if off.any():
            q = np.clip(np.floor(points[off] / VOXEL).astype(np.int64) + (1 << 15), 0, (1 << 16) - 1)  # +-1.6 km
            cube = (q[:, 0] << 32) | (q[:, 1] << 16) | q[:, 2]
            fresh = set(zip(instance[off].tolist(), cube.tolist())) - cubes
            if fresh:
                np.add.at(untied, np.fromiter((i for i, _ in fresh), np.int64, len(fresh)), 1)
                cubes |= fresh
        return _Aggregates(count, lo, hi, total, untied, cubes)


def tally_of(truth: FieldTruth, points, instance, label, confidence, tolerance: float = 0.05,
             sample: np.ndarray | None = None) -> Tally:
    """The tally of one map from nothing: points (P, 3), instance (P,) any integer ids,
    label and confidence per id as dicts or arrays indexed by id; ``sample`` (P,): the
    points' tied samples when known (else the nearest within ``tolerance``)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    ids, inst = np.unique(np.asarray(instance, np.int64), return_inverse=True)
    if sample is None:
        _, sample = cKDTree(truth.samples).query(points, distance_upper_bound=tolerance)
        sample = np.where(sample < len(truth.samples), sample, -1)
    on = sample >= 0
    pairs = np.unique(inst[on] * len(truth.samples) + sample[on])
    shared = np.zeros((len(ids), len(truth.ps_G)), np.int64)
    np.add.at(shared, (pairs // len(truth.samples), truth.sample_object[pairs % len(truth.samples)]), 1)
    lab = np.array([label[i] for i in ids.tolist()], np.int64)
    conf = np.array([confidence[i] for i in ids.tolist()], np.float64)
    return FieldScorer(truth).tally(points, inst, lab, conf, sample, shared)


def values(tally: Tally, truth: FieldTruth, names) -> dict[str, float]:
    """{name: value} of the field metrics ``names`` (each group computed once)."""
    names = set(names)
    out: dict[str, float] = {}
    for group, fn in _GROUPS:
        if names & set(group):
            out.update(fn(tally, truth))
    return {n: out[n] for n in FIELD_METRICS if n in names}


def iou(tally: Tally, truth: FieldTruth) -> np.ndarray:
    """(I, N) surface IoU of each instance with each object: shared / (size + ps_G - shared)."""
    union = tally.size[:, None] + truth.ps_G[None, :] - tally.shared
    return np.where(union > 0, tally.shared / np.maximum(union, 1), 0.0)


def _proposals(tally: Tally) -> np.ndarray:
    """The instances that are object proposals: those holding a label."""
    return np.flatnonzero(tally.label >= 0)


def omq(tally: Tally, truth: FieldTruth) -> dict[str, float]:
    """BenchBot's OMQ: pairwise quality sqrt(cuboid IoU x label probability), Hungarian
    matching; OMQ = sum of matched quality / (TP + FN + FP cost)."""
    k = _proposals(tally)
    n = len(truth.ps_G)
    spatial = fk.box_ious(tally.lo[k], tally.hi[k], tally.count[k] >= MIN_BOX_POINTS, truth.center, truth.size,
                          truth.yaw)
    label_q = np.where(truth.category[:, None] == tally.label[k][None, :], tally.confidence[k][None, :], 0.0)
    quality = np.sqrt(spatial * label_q)
    positive = quality > 0
    if (positive.sum(0) <= 1).all() and (positive.sum(1) <= 1).all():  # no pair competes: each is its best
        rows, cols = np.nonzero(positive)
    else:
        rows, cols = linear_sum_assignment(quality, maximize=True)
    tp = quality[rows, cols] > 0
    rows, cols = rows[tp], cols[tp]
    fp = np.setdiff1d(np.arange(len(k)), cols)
    fp_cost = float(tally.confidence[k][fp].sum())
    matched = float(quality[rows, cols].sum())
    ntp, nfn = len(rows), n - len(rows)
    denominator = ntp + nfn + fp_cost
    return {"omq": matched / denominator if denominator > 0 else 0.0,
            "omq_pairwise": matched / ntp if ntp else 0.0,
            "omq_label": float(label_q[rows, cols].sum()) / ntp if ntp else 0.0,
            "omq_spatial": float(spatial[rows, cols].sum()) / ntp if ntp else 0.0,
            "omq_fp_quality": (len(fp) - fp_cost) / len(fp) if len(fp) else 1.0}


def class_aps(tally: Tally, truth: FieldTruth) -> np.ndarray:
    """(C, 10) ScanNet AP of each class holding samples at IoU > 0.50, 0.55, ..., 0.90 and 0.25."""
    k = _proposals(tally)
    return fk.class_aps(iou(tally, truth)[k], tally.label[k], tally.confidence[k], truth.category, truth.classes,
                        np.asarray(AP_THRESHOLDS + (0.25,)))


def ap(tally: Tally, truth: FieldTruth) -> dict[str, float]:
    """ScanNet's AP (mean over classes of the mean over 0.50:0.05:0.90), AP50 and AP25."""
    a = class_aps(tally, truth)
    return {"ap": float(a[:, :-1].mean()) if len(a) else 0.0, "ap50": float(a[:, 0].mean()) if len(a) else 0.0,
            "ap25": float(a[:, -1].mean()) if len(a) else 0.0}


def _prf(matches: int, proposals: int, objects: int) -> tuple[float, float, float]:
    p = matches / proposals if proposals else 0.0
    r = matches / objects if objects else 0.0
    return p, r, 2 * p * r / (p + r) if p + r > 0 else 0.0


def _one_to_one(candidates: np.ndarray, weight: np.ndarray) -> int:
    """Matches of a one-to-one assignment maximising the total weight among candidate pairs."""
    if not candidates.any():
        return 0
    if (candidates.sum(0) <= 1).all() and (candidates.sum(1) <= 1).all():  # no pair competes: all match
        return int(candidates.sum())
    w = np.where(candidates, weight, 0.0)
    rows, cols = linear_sum_assignment(w, maximize=True)
    return int(candidates[rows, cols].sum())


def objects(tally: Tally, truth: FieldTruth) -> dict[str, float]:
    """Precision, recall and F1 of labelled instances against objects of their label, one to
    one: at surface IoU >= 0.25 and >= 0.5, and by centroid containment (weak: the
    instance's centroid in the object's box; strict: also the box's centre in the
    instance's cuboid; an instance of fewer than MIN_BOX_POINTS points has no cuboid and
    matches neither)."""
    k = _proposals(tally)
    n = len(truth.ps_G)
    same = tally.label[k][:, None] == truth.category[None, :]
    overlap = iou(tally, truth)[k]
    out = {}
    for th in PR_THRESHOLDS:
        p, r, f = _prf(_one_to_one(same & (overlap >= th), overlap), len(k), n)
        out.update({f"precision{round(100 * th)}": p, f"recall{round(100 * th)}": r, f"f1_{round(100 * th)}": f})
    weak, strict = fk.containment(tally.centroid[k], tally.lo[k], tally.hi[k], same, truth.center, truth.size,
                                  truth.yaw)
    boxed = (tally.count[k] >= MIN_BOX_POINTS)[:, None]  # no cuboid under MIN_BOX_POINTS: not a proposal here
    weak, strict = weak & boxed, strict & boxed
    closeness = -np.linalg.norm(tally.centroid[k][:, None, :] - truth.center[None, :, :], axis=-1) if len(k) else \
        np.zeros((0, n))
    for name, cand in (("_weak", weak), ("_strict", strict)):
        p, r, f = _prf(_one_to_one(cand, 10.0 + closeness), len(k), n)
        out.update({f"precision{name}": p, f"recall{name}": r, f"f1{name}": f})
    return out


def geometry(tally: Tally, truth: FieldTruth) -> dict[str, float]:
    """Accuracy (points within tau of a sample), completeness (samples within tau of a
    point), their F-score and Khronos' Chamfer distance at tau: the mean inlier distance
    each way, a way with no inliers counting tau."""
    out = {}
    for k, tau in enumerate(TAUS):
        name = f"{round(100 * tau)}cm"
        acc = tally.points_in[k] / tally.points if tally.points else 0.0
        comp = tally.samples_in[k] / tally.samples
        out[f"accuracy_{name}"], out[f"completeness_{name}"] = float(acc), float(comp)
        out[f"fscore_{name}"] = float(2 * acc * comp / (acc + comp)) if acc + comp > 0 else 0.0
        way = [max(0.0, total / n) if n else tau for total, n in ((tally.points_sum[k], tally.points_in[k]),
                                                        (tally.samples_sum[k], tally.samples_in[k]))]
        out[f"chamfer_{name}"] = float(way[0] + way[1])
    return out


def class_segmentation(tally: Tally, truth: FieldTruth) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per class holding samples (C,): IoU, accuracy and its share of the samples."""
    confusion = tally.confusion
    tp = np.diag(confusion[:, :-1]).astype(np.float64)
    truth_n = confusion.sum(1)
    predicted = confusion[:, :-1].sum(0)
    return tp / (truth_n + predicted - tp), tp / truth_n, truth_n / tally.samples


def segmentation(tally: Tally, truth: FieldTruth) -> dict[str, float]:
    """mIoU, mean class accuracy and frequency-weighted IoU of the samples' labels."""
    iou_c, acc_c, freq = class_segmentation(tally, truth)
    return {"miou": float(iou_c.mean()), "macc": float(acc_c.mean()), "fmiou": float((freq * iou_c).sum())}


_GROUPS = ((OMQ, omq), (AP, ap), (OBJECTS, objects), (GEOMETRY, geometry), (SEGMENTATION, segmentation))


def per_class(tally: Tally, truth: FieldTruth, categories) -> dict[str, dict[str, float]]:
    """{category name: {ap, ap50, ap25, iou, accuracy}} for the classes holding samples."""
    a = class_aps(tally, truth)
    iou_c, acc_c, _ = class_segmentation(tally, truth)
    return {categories[c]: {"ap": float(a[j, :-1].mean()), "ap50": float(a[j, 0]), "ap25": float(a[j, -1]),
                            "iou": float(iou_c[j]), "accuracy": float(acc_c[j])}
            for j, c in enumerate(truth.classes.tolist())}
