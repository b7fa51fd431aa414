"""Compiled kernels of the field's map metrics (numba; :mod:`.field`): the loops a map's
scoring runs for every sampled second of a session, where numpy would run many small array
operations.

- :func:`near`: nearest neighbours within a radius, both ways between new map points and
  the ground-truth surface samples (a dense grid of cells over the samples);
- :func:`box_iou`: the 3D IoU of an axis-aligned cuboid and a yaw-rotated one;
- :func:`in_box`: whether a point lies inside a yaw-rotated cuboid;
- :func:`class_ap`: ScanNet's instance AP of one class at one IoU threshold.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def near(points, base, instance, origin, cell, dims, start, order, samples, sample_class, r2, seg_r2, taus2,
         point_d2, sample_d2, sample_point, samples_in, samples_sum, near_class):
    """For new map points (k, 3), numbered ``base``, ``base + 1``, ... (``instance`` the ids
    of every point): each point's squared distance to its nearest sample within sqrt(r2)
    (``point_d2`` (k,), left as is beyond), and each sample's nearest map point so far
    (``sample_d2``, ``sample_point`` (S,), updated in place; a tie keeps the earlier point)
    with what is counted on it, kept up to date: per tau of ``taus2`` the samples within it
    and the sum of their distances (``samples_in``, ``samples_sum``), and per id the samples
    within sqrt(seg_r2) whose nearest point it holds, by class (``near_class``). The samples
    are sorted by cell (``order``), cell c's at ``order[start[c]:start[c + 1]]``; cells are
    ``cell`` wide (at least sqrt(r2)) on a ``dims`` grid from ``origin``."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    for j in range(points.shape[0]):
        px, py, pz = points[j, 0], points[j, 1], points[j, 2]
        cx = int(math.floor((px - origin[0]) / cell))
        cy = int(math.floor((py - origin[1]) / cell))
        cz = int(math.floor((pz - origin[2]) / cell))
        for ix in range(max(cx - 1, 0), min(cx + 2, nx)):
            for iy in range(max(cy - 1, 0), min(cy + 2, ny)):
                for iz in range(max(cz - 1, 0), min(cz + 2, nz)):
                    c = (ix * ny + iy) * nz + iz
                    for k in range(start[c], start[c + 1]):
                        s = order[k]
                        dx, dy, dz = samples[s, 0] - px, samples[s, 1] - py, samples[s, 2] - pz
                        d2 = dx * dx + dy * dy + dz * dz
                        if d2 > r2:
                            continue
                        if d2 < point_d2[j]:
                            point_d2[j] = d2
                        old = sample_d2[s]
                        if d2 < old:
                            for t in range(taus2.shape[0]):
                                if old <= taus2[t]:
                                    samples_in[t] -= 1
                                    samples_sum[t] -= math.sqrt(old)
                                if d2 <= taus2[t]:
                                    samples_in[t] += 1
                                    samples_sum[t] += math.sqrt(d2)
                            if old <= seg_r2:
                                near_class[instance[sample_point[s]], sample_class[s]] -= 1
                            if d2 <= seg_r2:
                                near_class[instance[base + j], sample_class[s]] += 1
                            sample_d2[s] = d2
                            sample_point[s] = base + j


@njit(cache=True, nogil=True)
def _clip(xs, ys, n, axis, bound, keep_below):
    """Sutherland-Hodgman: the convex polygon (xs, ys)[:n] clipped to one half-plane
    (coordinate ``axis`` <= bound if keep_below, else >= bound). Returns new arrays, count."""
    ox, oy = np.empty(n + 4), np.empty(n + 4)
    m = 0
    for i in range(n):
        ax, ay = xs[i], ys[i]
        bx, by = xs[(i + 1) % n], ys[(i + 1) % n]
        va, vb = (ax if axis == 0 else ay), (bx if axis == 0 else by)
        ina = va <= bound if keep_below else va >= bound
        inb = vb <= bound if keep_below else vb >= bound
        if ina:
            ox[m], oy[m] = ax, ay
            m += 1
        if ina != inb:
            t = (bound - va) / (vb - va)
            ox[m], oy[m] = ax + t * (bx - ax), ay + t * (by - ay)
            m += 1
    return ox, oy, m


@njit(cache=True, nogil=True)
def box_iou(lo, hi, center, size, yaw):
    """3D IoU of the axis-aligned cuboid [lo, hi] (3,) and the cuboid of ``size`` (3,)
    centred at ``center`` (3,), turned by ``yaw`` about z (0 when either has no volume)."""
    za, zb = max(lo[2], center[2] - size[2] / 2), min(hi[2], center[2] + size[2] / 2)
    va = (hi[0] - lo[0]) * (hi[1] - lo[1]) * (hi[2] - lo[2])
    vb = size[0] * size[1] * size[2]
    if zb <= za or va <= 0.0 or vb <= 0.0:
        return 0.0
    c, s = math.cos(yaw), math.sin(yaw)
    xs, ys = np.empty(4), np.empty(4)
    for i, (u, v) in enumerate(((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0))):  # counter-clockwise
        dx, dy = u * size[0] / 2, v * size[1] / 2
        xs[i], ys[i] = center[0] + c * dx - s * dy, center[1] + s * dx + c * dy
    n = 4
    xs, ys, n = _clip(xs, ys, n, 0, lo[0], False)
    xs, ys, n = _clip(xs, ys, n, 0, hi[0], True)
    xs, ys, n = _clip(xs, ys, n, 1, lo[1], False)
    xs, ys, n = _clip(xs, ys, n, 1, hi[1], True)
    area = 0.0
    for i in range(n):
        area += xs[i] * ys[(i + 1) % n] - xs[(i + 1) % n] * ys[i]
    inter = abs(area) / 2 * (zb - za)
    return inter / (va + vb - inter)


@njit(cache=True, nogil=True)
def in_box(p, center, size, yaw):
    """Whether point p (3,) lies inside the cuboid of ``size`` centred at ``center``, turned by ``yaw``."""
    dx, dy = p[0] - center[0], p[1] - center[1]
    c, s = math.cos(yaw), math.sin(yaw)
    u, v = c * dx + s * dy, -s * dx + c * dy
    return abs(u) <= size[0] / 2 and abs(v) <= size[1] / 2 and abs(p[2] - center[2]) <= size[2] / 2


@njit(cache=True, nogil=True)
def class_ap(iou, conf, threshold):
    """ScanNet's AP of one class at one IoU threshold: ``iou`` (P, G) of the class's P
    predictions (in their order) with its G > 0 ground-truth instances, ``conf`` (P,).
    Each ground truth takes, greedily in order, the first unclaimed prediction overlapping
    it by more than ``threshold``; a further one overlapping it counts as a false positive
    at the lower of the two confidences; a prediction overlapping no ground truth by more
    than ``threshold`` is a false positive. AP is the area under the precision-recall
    curve, its steps taken halfway between recall levels (as ScanNet's script)."""
    p, g = iou.shape
    if p == 0:
        return 0.0
    visited = np.zeros(p, np.bool_)
    true, score = np.empty(g + 2 * p), np.empty(g + 2 * p)
    n, misses = 0, 0
    for k in range(g):
        matched, best = False, -np.inf
        for i in range(p):
            if visited[i] or not iou[i, k] > threshold:
                continue
            if matched:
                true[n], score[n] = 0.0, min(best, conf[i])
                n += 1
                best = max(best, conf[i])
            else:
                matched, best, visited[i] = True, conf[i], True
        if matched:
            true[n], score[n] = 1.0, best
            n += 1
        else:
            misses += 1
    for i in range(p):
        found = False
        for k in range(g):
            if iou[i, k] > threshold:
                found = True
        if not found:
            true[n], score[n] = 0.0, conf[i]
            n += 1
    if n == 0:
        return 0.0
    order = np.argsort(score[:n], kind="mergesort")
    t, sc = true[:n][order], score[:n][order]
    cum = np.cumsum(t)
    total = cum[-1]
    firsts = [0]  # each distinct score's first index (sorted ascending)
    for i in range(1, n):
        if sc[i] != sc[i - 1]:
            firsts.append(i)
    m = len(firsts) + 1
    precision, recall = np.zeros(m), np.zeros(m)
    for r, i in enumerate(firsts):
        below = cum[i - 1] if i > 0 else 0.0
        tp = total - below
        fp = n - i - tp
        fn = below + misses
        precision[r] = tp / (tp + fp)
        recall[r] = tp / (tp + fn) if tp + fn > 0 else 0.0
    precision[-1], recall[-1] = 1.0, 0.0
    ap = 0.0
    for r in range(m):  # step widths: half the recall drop on each side
        left = recall[r - 1] if r > 0 else recall[0]
        right = recall[r + 1] if r + 1 < m else 0.0
        ap += precision[r] * (left - right) / 2
    return ap


@njit(cache=True, nogil=True)
def box_ious(lo, hi, usable, center, size, yaw):
    """(N, K) :func:`box_iou` of K axis-aligned cuboids (lo, hi (K, 3); ``usable`` (K,) False:
    no cuboid, IoU 0) with N yaw-rotated ones (center, size (N, 3), yaw (N,))."""
    out = np.zeros((center.shape[0], lo.shape[0]))
    for g in range(center.shape[0]):
        c, s = abs(math.cos(yaw[g])), abs(math.sin(yaw[g]))
        ex, ey = (c * size[g, 0] + s * size[g, 1]) / 2, (s * size[g, 0] + c * size[g, 1]) / 2  # its box's reach
        for k in range(lo.shape[0]):
            if usable[k] and lo[k, 0] < center[g, 0] + ex and hi[k, 0] > center[g, 0] - ex \
                    and lo[k, 1] < center[g, 1] + ey and hi[k, 1] > center[g, 1] - ey:
                out[g, k] = box_iou(lo[k], hi[k], center[g], size[g], yaw[g])
    return out


@njit(cache=True, nogil=True)
def containment(centroid, lo, hi, same, center, size, yaw):
    """(K, N) weak: the K instances' centroids inside the N objects' boxes, where ``same``
    (K, N); strict: also the box's centre inside the instance's cuboid [lo, hi]."""
    k_, n_ = same.shape
    weak, strict = np.zeros((k_, n_), np.bool_), np.zeros((k_, n_), np.bool_)
    for k in range(k_):
        for g in range(n_):
            if same[k, g] and in_box(centroid[k], center[g], size[g], yaw[g]):
                weak[k, g] = True
                c = center[g]
                strict[k, g] = (lo[k, 0] <= c[0] <= hi[k, 0] and lo[k, 1] <= c[1] <= hi[k, 1]
                                and lo[k, 2] <= c[2] <= hi[k, 2])
    return weak, strict


@njit(cache=True, nogil=True)
def class_aps(overlap, label, conf, category, classes, thresholds):
    """(C, T) :func:`class_ap` of each class at each threshold: ``overlap`` (K, N) of the K
    proposals (labels (K,), confidences (K,)) with the N objects (categories (N,))."""
    out = np.zeros((classes.shape[0], thresholds.shape[0]))
    for c in range(classes.shape[0]):
        preds = np.flatnonzero(label == classes[c])
        gts = np.flatnonzero(category == classes[c])
        m = np.empty((preds.shape[0], gts.shape[0]))
        for i in range(preds.shape[0]):
            for k in range(gts.shape[0]):
                m[i, k] = overlap[preds[i], gts[k]]
        for t in range(thresholds.shape[0]):
            out[c, t] = class_ap(m, conf[preds], thresholds[t])
    return out
