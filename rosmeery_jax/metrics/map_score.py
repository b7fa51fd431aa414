"""Score a semantic map made by any mapper against a world's ground truth (docs/metrics.md).

A map is the paper's SM = <R, M, P>: ``MAP.ply`` (vertices x, y, z and an instance id,
``object_id`` or ``instance``; optional per-point ``label`` (taxonomy index, -1 none) and
``confidence``) and, beside it, ``MAP.json`` (``frame``: ``world``, ``time_s``; ``objects``:
``id`` (the instance id), ``label`` (a category name, or null), ``confidence``). The maps
``rosmeery run`` exports (``maps/``) are valid input.

Scoring, as in the paper but with the association a real mapper must make itself:

1. Each point is tied to the nearest ground-truth surface sample within ``tolerance``
   (scipy cKDTree). Counting is per sample, not per point, so a denser cloud cannot
   inflate ps. A point near no sample lies on no object (walls, floor, or wrong places).
2. Each map instance is matched to at most one object and each object to at most one
   instance: the Hungarian assignment (scipy) maximising the samples they share.
3. ps(n) counts the samples of n covered by the instance matched to n only: merged or
   split instances lose what their unmatched parts hold.
4. cORI weighs ps(n) by the instance's confidence when its label is n's category; OPI and
   OPI-strict count the predicates the label declares through the taxonomy (3 per label),
   of which those on the category -> macro -> root chain of n are correct.

The result is one :class:`ObjectLog` per map, so the session's metric functions score it.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from pathlib import Path
from typing import NamedTuple

import numpy as np
import trimesh
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from rosmeery_jax import metrics
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.metrics import field, tasks
from rosmeery_jax.results import tables
from rosmeery_jax.sim.knowledge import GroundTruthTable, ObjectLog, predicate_tables
from rosmeery_jax.world import load_world
from rosmeery_jax.world.episodes import generate as generate_episodes

TOLERANCE = 0.05  # m: a point within this of a surface sample lies on it (samples are 5 cm apart)
INSTANCE_FIELDS = ("object_id", "instance")


class SemanticMap(NamedTuple):
    """A map read from disk. points (P, 3) float64; instance (P,) int64; labels / confidence:
    per instance id, the category name (None: unlabelled) and its confidence."""

    path: Path
    points: np.ndarray
    instance: np.ndarray
    labels: dict
    confidence: dict
    world: str | None
    time_s: float | None


class Score(NamedTuple):
    """A map scored against a world: log (ObjectLog, fields (N,)); matched (N,) instance id of
    each object (-1 none); off_object: share of points on no object; unmatched: instances
    matched to no object; field: {name: value} of the map metrics asked for (field:
    :mod:`rosmeery_jax.metrics.field`, and task: :mod:`rosmeery_jax.metrics.tasks`), and
    tally, what the field metrics were computed from."""

    log: ObjectLog
    matched: np.ndarray
    off_object: float
    unmatched: int
    field: dict | None = None
    tally: field.Tally | None = None


def read_map(ply: str | Path, taxonomy) -> SemanticMap:
    """``ply`` and the JSON beside it (its world, time and instance labels; required, so a
    map of another world is refused rather than scored); one InputError naming the file
    and field."""
    ply = Path(ply)
    meta_path = ply.with_suffix(".json")
    if not ply.is_file():  # before its JSON: a mistyped map path names the map
        raise InputError(ply, "file", "not found")
    if not meta_path.is_file():
        raise InputError(meta_path, "file", "not found: each map needs its JSON beside it (frame.world, "
                         "frame.time_s, objects), the format `rosmeery run` writes")
    vertex = _vertices(ply)
    names = vertex.dtype.names
    field = next((f for f in INSTANCE_FIELDS if f in names), None)
    if field is None:
        raise InputError(ply, "vertex", f"needs an instance id field ({' or '.join(INSTANCE_FIELDS)})")
    columns = PointColumns(np.stack([vertex[a].astype(np.float64) for a in "xyz"], -1).reshape(-1, 3),
                           vertex[field].astype(np.float64), field,
                           vertex["label"].astype(np.float64) if "label" in names else None,
                           vertex["confidence"].astype(np.float64) if "confidence" in names else None)
    points, instance, labels, conf = read_columns(ply, "vertex", columns, taxonomy)
    world, time_s, extra_labels, extra_conf = _read_meta(meta_path, taxonomy)
    pointless = sorted(set(extra_labels) - set(labels))
    if pointless:
        raise InputError(meta_path, "objects", f"id {pointless[0]} has no points in {ply.name} (its instance ids: "
                         f"{_some(sorted(labels))}): the JSON and the PLY are of different maps?")
    labels.update(extra_labels)
    conf.update(extra_conf)
    return SemanticMap(ply, points, instance, labels, conf, world, time_s)


def _vertices(ply: Path) -> np.ndarray:
    empty = _empty_vertices(ply)
    if empty is not None:  # trimesh cannot read an ASCII PLY of no vertices
        return empty
    try:
        with warnings.catch_warnings():  # trimesh casts an ASCII value its type cannot hold with a warning only
            warnings.simplefilter("error", RuntimeWarning)
            mesh = trimesh.load(str(ply), file_type="ply", process=False)
        vertex = mesh.metadata["_ply_raw"]["vertex"]["data"]
    except FileNotFoundError:
        raise InputError(ply, "file", "not found") from None
    except RuntimeWarning:
        raise InputError(ply, "vertex", "holds a value its property's type cannot (NaN, infinity or out of range "
                         "in an integer property)") from None
    except Exception as err:  # trimesh raises many kinds on a malformed file
        raise InputError(ply, "file", f"not a readable PLY point cloud ({type(err).__name__}: {err})") from None
    if isinstance(vertex, dict):  # an ASCII PLY: trimesh gives one (n, 1) column per property
        _check_ascii_body(ply)
        vertex = _columns(ply, vertex)
    missing = [a for a in "xyz" if a not in (vertex.dtype.names or ())]
    if missing:
        raise InputError(ply, f"vertex {missing[0]}", "missing")
    return vertex


def _empty_vertices(ply: Path) -> np.ndarray | None:
    """A PLY whose header declares no vertices (a mapper that saw nothing writes one) as an
    empty vertex table of its properties; None for any other file."""
    try:
        head = ply.read_bytes()[:4096].decode("ascii", "replace")
    except OSError:
        return None
    if "end_header" not in head:
        return None
    lines = [ln.split() for ln in head[:head.index("end_header")].splitlines()]
    vertex = next((k for k, w in enumerate(lines) if w[:2] == ["element", "vertex"]), None)
    if vertex is None or lines[vertex][2:] != ["0"]:
        return None
    props = []
    for w in lines[vertex + 1:]:
        if w[:1] != ["property"]:
            break
        if len(w) == 3:  # a list property holds no per-vertex number
            props.append((w[2], "f8"))
    return np.zeros(0, props) if {"x", "y", "z"} <= {n for n, _ in props} else None


def _check_ascii_body(ply: Path) -> None:
    """An ASCII PLY's body holds what its header declares: as many lines as its elements
    count, each vertex line one number per property (a binary body is held to its header
    by its length; an ASCII one was read as far as the header said, whatever followed)."""
    lines = ply.read_bytes().decode("ascii", "replace").splitlines()
    end = next((i for i, ln in enumerate(lines) if ln.strip() == "end_header"), None)
    if end is None:
        raise InputError(ply, "header", "has no end_header line")
    elements: list[list] = []  # [name, count, properties, has a list property]
    for ln in lines[1:end]:
        words = ln.split()
        if words[:1] == ["element"] and len(words) == 3:
            if not words[2].isdigit():
                raise InputError(ply, f"element {words[1]}", f"{words[2]!r} is not a count")
            elements.append([words[1], int(words[2]), 0, False])
        elif words[:1] == ["property"] and elements:
            elements[-1][2] += 1
            elements[-1][3] |= words[1:2] == ["list"]
    body = [ln.split() for ln in lines[end + 1:] if ln.strip()]
    declared = sum(e[1] for e in elements)
    if len(body) != declared:
        raise InputError(ply, "body", f"{len(body)} lines where the header declares {declared} "
                         f"({', '.join(f'{e[1]} {e[0]}' for e in elements)})")
    row = 0
    for name, count, props, listed in elements:
        for k in range(count):
            if not listed and len(body[row + k]) != props:
                raise InputError(ply, f"{name} {k}", f"{len(body[row + k])} values where the header declares "
                                 f"{props} properties")
        row += count


def _columns(ply: Path, columns: dict) -> np.ndarray:
    """An ASCII PLY's vertex columns as one record array (numbers only, one per vertex)."""
    if not columns:
        return np.zeros(0, [("x", "f4")])
    try:
        arrays = [np.asarray(v) for v in columns.values()]
        if any(a.dtype.kind not in "iuf" or a.ndim != 2 or a.shape[1] != 1 or len(a) != len(arrays[0])
               for a in arrays):
            raise ValueError("one number per vertex and property")
        return np.rec.fromarrays([a[:, 0] for a in arrays], names=list(columns))
    except (TypeError, ValueError) as err:
        raise InputError(ply, "vertex", f"not a point cloud's vertex table ({err})") from None


class PointColumns(NamedTuple):
    """A map's per-point columns as read, before any check (every way a map comes in, PLY
    or a ROS PointCloud2, fills one): xyz (P, 3), instance (P,) under the field name
    ``instance_field``, label (P,) or None, confidence (P,) or None, all float64."""

    xyz: np.ndarray
    instance: np.ndarray
    instance_field: str
    label: np.ndarray | None
    confidence: np.ndarray | None


def read_columns(source, element: str, cols: PointColumns, taxonomy) -> tuple[np.ndarray, np.ndarray, dict, dict]:
    """The one reader contract of a map's points: x, y, z finite; instance ids and labels
    whole numbers an int32 holds; labels taxonomy indices or -1; confidences in [0, 1].
    Returns points (P, 3), instance (P,) int64, and per instance id its points' most common
    label (a category name, None: unlabelled) and highest confidence (1 without the column).
    An empty map is valid (a mapper's first map often is). One InputError naming ``source``
    and ``element``'s field otherwise."""
    bad = ~np.isfinite(cols.xyz).all(1)
    if bad.any():
        raise InputError(source, f"{element} x, y, z", f"{int(bad.sum())} points are not finite numbers (first: row "
                         f"{int(np.argmax(bad))})")
    instance = _whole_numbers(source, element, cols.instance_field, cols.instance)
    label = None if cols.label is None else _whole_numbers(source, element, "label", cols.label)
    if label is not None:
        bad = (label < -1) | (label >= len(taxonomy.names))
        if bad.any():
            raise InputError(source, f"{element} label", f"{label[np.argmax(bad)]} (row {int(np.argmax(bad))}) is not "
                             f"a category index of the taxonomy (0..{len(taxonomy.names) - 1}, -1 none)")
    if cols.confidence is not None:
        bad = ~((cols.confidence >= 0.0) & (cols.confidence <= 1.0))  # NaN too
        if bad.any():
            row = int(np.argmax(bad))
            raise InputError(source, f"{element} confidence", f"{cols.confidence[row]} (row {row}) is not a number "
                             "in [0, 1]")
    labels, conf = _instance_labels(instance, label, cols.confidence, taxonomy)
    return cols.xyz, instance, labels, conf


def _whole_numbers(source, element: str, name: str, values: np.ndarray) -> np.ndarray:
    """A per-point id column (instance, label) as int64 (P,): whole numbers an int32 holds,
    from an integer or a float field (larger ids would overflow the scoring's pair keys)."""
    bad = ~(np.isfinite(values) & (values == np.round(values)) & (np.abs(values) < 2.0 ** 31))
    if bad.any():
        row = int(np.argmax(bad))
        raise InputError(source, f"{element} {name}", f"{values[row]} (row {row}) is not a whole number between "
                         f"-{2 ** 31 - 1} and {2 ** 31 - 1}")
    return values.astype(np.int64)


def _instance_labels(instance: np.ndarray, label, confidence, taxonomy) -> tuple[dict, dict]:
    """Per instance id: its points' most common label (a category name, None for -1) and
    highest confidence (1 without a confidence column)."""
    if not len(instance):
        return {}, {}
    ids, inst = np.unique(instance, return_inverse=True)
    k = most_common(inst, label, len(ids)) if label is not None else np.full(len(ids), -1)
    best = np.ones(len(ids))
    if confidence is not None:
        best = np.full(len(ids), -np.inf)
        np.maximum.at(best, inst, confidence)
    names = taxonomy.names
    return ({i: names[c] if c >= 0 else None for i, c in zip(ids.tolist(), k.tolist())},
            dict(zip(ids.tolist(), best.tolist())))


def _some(ids: list) -> str:
    """A few of ``ids`` for a message."""
    return ", ".join(map(str, ids[:5])) + (", ..." if len(ids) > 5 else "") if ids else "none"


def most_common(group: np.ndarray, value: np.ndarray, groups: int) -> np.ndarray:
    """(G,) each group's most common value, the smallest of those tied (as np.unique and
    argmax pick), in one sort: O(P log P) for P points, whatever the number of groups."""
    pairs, counts = np.unique(np.stack([group, value.astype(np.int64)]), axis=1, return_counts=True)
    order = np.lexsort((pairs[1], -counts, pairs[0]))  # per group: most points first, then the smallest value
    first = np.r_[True, pairs[0][order][1:] != pairs[0][order][:-1]]
    out = np.empty(groups, np.int64)
    out[pairs[0][order][first]] = pairs[1][order][first]
    return out


def _read_meta(path: Path, taxonomy):
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(path, "file", f"not valid JSON ({err})") from None
    except RecursionError:
        raise InputError(path, "file", "nested too deeply to be a semantic map") from None
    frame = meta.get("frame", {}) if isinstance(meta, dict) else None
    if not isinstance(frame, dict):
        raise InputError(path, "frame", "must be an object")
    if not isinstance(frame.get("world"), str):
        raise InputError(path, "frame.world", "missing: the name of the world the map is of")
    time_s = frame.get("time_s")
    if time_s is not None and (isinstance(time_s, bool) or not isinstance(time_s, (int, float))
                               or not math.isfinite(time_s) or time_s < 0):
        raise InputError(path, "frame.time_s", f"{time_s!r} is not a time in seconds (a finite number >= 0)")
    labels, conf = object_labels(path, meta.get("objects", []), taxonomy)
    return frame.get("world"), time_s, labels, conf


def object_labels(source, objects, taxonomy, where: str = "objects") -> tuple[dict, dict]:
    """A map's objects list (``[{"id", "label", "confidence"}]``) as {id: category name or
    None} and {id: confidence}; one InputError naming ``source`` and the element."""
    if not isinstance(objects, list):
        raise InputError(source, where, "must be a list")
    labels, conf = {}, {}
    for j, obj in enumerate(objects):
        if not isinstance(obj, dict) or not isinstance(obj.get("id"), int) or isinstance(obj.get("id"), bool):
            raise InputError(source, f"{where}[{j}].id", "each object needs an integer id (its points' instance id)")
        if obj["id"] in labels:
            raise InputError(source, f"{where}[{j}].id", f"{obj['id']} appears twice")
        label = obj.get("label")
        if label is not None and label not in taxonomy:
            raise InputError(source, f"{where}[{j}].label", f"{label!r} is not a category of the taxonomy")
        c = obj.get("confidence", 1.0)
        if isinstance(c, bool) or not isinstance(c, (int, float)) or not 0.0 <= c <= 1.0:
            raise InputError(source, f"{where}[{j}].confidence", f"{c!r} is not a number in [0, 1]")
        labels[obj["id"]], conf[obj["id"]] = label, float(c)
    return labels, conf


def score(world, m: SemanticMap, tolerance: float = TOLERANCE, field_names: tuple[str, ...] = ()) -> Score:
    """Score map ``m`` against ``world``'s ground truth (see the module docstring), with
    the field map metrics ``field_names`` (:mod:`rosmeery_jax.metrics.field`)."""
    if m.world is not None and m.world != world.name:
        raise InputError(m.path.with_suffix(".json"), "frame.world", f"{m.world!r} is not the world scored ({world.name!r})")
    names = m.labels

    def labels_of(ids):
        found = [names.get(int(i)) for i in ids]
        label = np.array([world.taxonomy.index(k) if k else -1 for k in found], np.int32)
        conf = np.array([m.confidence.get(int(i), 0.0) for i in ids], np.float32)
        return label, conf

    sample = tie(world, m.points, tolerance)
    sc = score_tied(world, sample, m.instance, labels_of)
    if not field_names:
        return sc
    ids = np.unique(m.instance)
    label, conf = labels_of(ids)
    truth = field.FieldTruth.of(world)
    tally = field.tally_of(truth, m.points, m.instance, dict(zip(ids.tolist(), label)), dict(zip(ids.tolist(), conf)),
                           sample=sample)
    return sc._replace(field=field.values(tally, truth, field_names), tally=tally)


def score_tied(world, sample: np.ndarray, instance: np.ndarray, labels_of) -> Score:
    """Steps 2-4 for points already tied (sample (P,), -1 none) with instance ids (P,);
    ``labels_of(ids (I,))`` gives each instance's category index (-1 none) and confidence."""
    ids, inst = np.unique(instance, return_inverse=True)
    shared = shared_samples(world, inst, sample, len(ids))
    return score_instances(world, ids, shared, labels_of, int((sample >= 0).sum()), len(sample))


def score_instances(world, ids: np.ndarray, shared: np.ndarray, labels_of, on: int, points: int) -> Score:
    """Steps 2-4 for the instances ``ids`` (I,) holding points, with their shared samples
    (I, N); ``on`` of the map's ``points`` lie on an object."""
    if not len(ids):  # an empty map: one instance holding nothing
        shared = np.zeros((1, world.truth.num_objects), np.int64)
    label, conf = labels_of(ids)
    label = np.r_[np.asarray(label, np.int32), np.full(len(shared) - len(ids), -1, np.int32)]
    conf = np.where(label >= 0, np.r_[np.asarray(conf, np.float32), np.zeros(len(shared) - len(ids), np.float32)],
                    0.0).astype(np.float32)
    log, ix = score_shared(world, shared, label, conf)
    off = float(1.0 - on / points) if points else 0.0
    matched = np.r_[ids, -1][np.where(ix >= 0, ix, len(ids))]  # the empty map's placeholder never matches
    return Score(log, matched, off, int(len(ids) - (ix >= 0).sum()))


def tie(world, points: np.ndarray, tolerance: float = TOLERANCE, tree: cKDTree | None = None) -> np.ndarray:
    """(P,) index of the surface sample each point (P, 3) lies on, -1 for none (step 1);
    ``tree``: the samples' KD-tree, when the caller keeps one."""
    if tree is None:
        tree = cKDTree(np.asarray(world.truth.samples.points, np.float64))
    _, s = tree.query(points, distance_upper_bound=tolerance)
    return np.where(s < tree.n, s, -1)


def shared_samples(world, instance: np.ndarray, sample: np.ndarray, instances: int) -> np.ndarray:
    """(I, N) distinct samples of each object that each instance covers, from points'
    instance index (P,) in [0, I) and tied sample (P,) (-1 none)."""
    n_samples = len(world.truth.samples.object)
    on = sample >= 0
    pairs = np.unique(instance[on].astype(np.int64) * n_samples + sample[on])  # distinct (instance, sample)
    shared = np.zeros((instances, world.truth.num_objects), np.int64)
    np.add.at(shared, (pairs // n_samples, np.asarray(world.truth.samples.object)[pairs % n_samples]), 1)
    return shared


def score_shared(world, shared: np.ndarray, label: np.ndarray, conf: np.ndarray) -> tuple[ObjectLog, np.ndarray]:
    """Steps 2-4 for instances with shared samples (I, N), label (I,) category index (-1
    none) and its confidence (I,). Returns the ObjectLog (fields (N,)) and each object's
    instance index (N,), -1 for none."""
    truth, n_obj = world.truth, world.truth.num_objects
    rows, cols = linear_sum_assignment(shared, maximize=True)
    keep = shared[rows, cols] > 0
    rows, cols = rows[keep], cols[keep]
    ix = np.full(n_obj, -1, np.int64)
    ix[cols] = rows
    ps = np.zeros(n_obj, np.float32)
    ps[cols] = shared[rows, cols]
    lab = np.where(ix >= 0, np.asarray(label)[np.maximum(ix, 0)], -1).astype(np.int32)
    c = np.where(lab >= 0, np.asarray(conf)[np.maximum(ix, 0)], 0.0).astype(np.float32)
    declared_table, correct_table = predicate_tables(world.taxonomy, truth.categories)
    has = lab >= 0
    declared = np.where(has, declared_table[np.maximum(lab, 0)], 0).astype(np.int32)
    correct = np.where(has, correct_table[np.arange(n_obj), np.maximum(lab, 0)], 0).astype(np.int32)
    conf_true = np.where(lab == np.asarray(truth.category_index), c, 0.0).astype(np.float32)
    return ObjectLog(ps, conf_true, c, lab, declared, correct), ix


def check_tolerance(tolerance, source: str, where: str) -> None:
    """A tie distance is a finite number of metres > 0 (0 or less ties nothing)."""
    if not (isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and tolerance > 0):
        raise InputError(source, where, f"{tolerance!r} must be a distance > 0 (m)")


def _read_maps(maps, taxonomy) -> list[SemanticMap]:
    """``maps`` as a non-empty list of SemanticMap: files read, anything else a TypeError (a
    path's letters were taken as maps, an AttributeError)."""
    if isinstance(maps, (str, os.PathLike, SemanticMap)):
        maps = [maps]
    try:
        maps = list(maps)
    except TypeError:
        raise TypeError(f"evaluate: maps must be a list of maps or PLY files, not {type(maps).__name__}") from None
    if not maps:
        raise InputError("evaluate", "maps", "is empty: give at least one map")
    for m in maps:
        if not isinstance(m, (str, os.PathLike, SemanticMap)):
            raise TypeError(f"evaluate: maps must be maps read by read_map or PLY files, not {type(m).__name__}")
    return [read_map(m, taxonomy) if isinstance(m, (str, os.PathLike)) else m for m in maps]


def evaluate(world, maps: list[SemanticMap], tolerance: float = TOLERANCE, name: str = "external",
             names=metrics.DEFAULT_METRICS, episodes=None, attempts: int = tasks.ATTEMPTS):
    """Score maps of one run (curves over their ``time_s``, else their order) by the metrics
    ``names`` (``field`` or field map metrics among them: :mod:`rosmeery_jax.metrics.field`;
    ``task`` or map-use metrics: :mod:`rosmeery_jax.metrics.tasks`, against ``episodes``, by
    default the world's generated set, trying ``attempts`` instances).

    Returns (metrics table, objects table of the last map, per-class table, summary dict),
    the first two in the session's formats (policy = ``name``, detector = "own", seed 0).
    ``world``: a World, or a name or file :func:`load_world` takes; ``maps``: maps read by
    :func:`read_map`, or their PLY files (one file alone as well)."""
    if isinstance(world, (str, os.PathLike)):
        world = load_world(world)
    maps = _read_maps(maps, world.taxonomy)
    check_tolerance(tolerance, "evaluate", "tolerance")
    names = metrics.resolve(names)
    field_names = field.wanted(names)
    times = [m.time_s if m.time_s is not None else float(k) for k, m in enumerate(maps)]
    timed = [m.time_s is not None for m in maps]
    if any(timed) and not all(timed):  # times for some, order for others: no one order
        m = maps[timed.index(False)]
        raise InputError(m.path.with_suffix(".json"), "frame.time_s", "missing, while other maps have one: give "
                         "every map its time, or none (then their order is their time)")
    for k, m in enumerate(maps):
        if times.count(times[k]) > 1:
            raise InputError(m.path.with_suffix(".json"), "frame.time_s", f"{times[k]:g} s: two maps have this "
                             "time (one map per time)")
    order = np.argsort(times, kind="stable")
    scores = [score(world, maps[k], tolerance, field_names) for k in order]
    t = world.truth
    table = GroundTruthTable(np.asarray(t.ps_G), np.asarray(t.num_predicates), np.asarray(t.category_index))
    log = ObjectLog(*(np.stack(f) for f in zip(*(sc.log for sc in scores))))
    curves = metrics.compute(log, table, names)
    curves.update({n: np.array([sc.field[n] for sc in scores]) for n in field_names})
    task_names = tasks.wanted(names)
    if task_names:
        tasks.check_attempts(attempts, "evaluate")
        eps = episodes if episodes is not None else generate_episodes(world)
        scorer = tasks.TaskScorer(world, eps, attempts)  # one per run: its maps share what it keeps
        done = [scorer.score(maps[k].points, maps[k].instance, maps[k].labels) for k in order]
        curves.update({n: np.array([r.values[n] for r in done]) for n in task_names})
    curves = {n: curves[n] for n in names}
    tags = dict(policy=name, detector="own", mapper="own", seed=0)
    metric_df = tables.metric_frame(curves, np.asarray(times)[order], world=world.name, **tags)
    objects = tables.object_frame(world, scores[-1].log, **tags)
    objects["instance"] = scores[-1].matched
    classes = _classes(world, objects, scores[-1])
    last = scores[-1]
    summary = {"world": world.name, "maps": [str(maps[k].path) for k in order], "tolerance_m": tolerance,
               **{k: float(v[-1]) for k, v in curves.items()}, "points_on_no_object": round(last.off_object, 6),
               "unmatched_instances": last.unmatched}
    return metric_df, objects, classes, summary


def _classes(world, objects, last: Score):
    """Per category: objects, ps_G, ps, coverage, ORI; with field metrics, its AP (mean over
    0.50:0.90), AP50, AP25, segmentation IoU and accuracy (categories holding no samples: none)."""
    classes = objects.groupby("category").agg(objects=("object", "size"), ps_G=("ps_G", "sum"), ps=("ps", "sum"),
                                              coverage=("coverage", "mean")).reset_index()
    classes["ori"] = classes.coverage  # ORI over a class's objects: ps <= ps_G, so 1 - mean(1 - coverage)
    if last.tally is not None:
        truth = field.FieldTruth.of(world)
        per = field.per_class(last.tally, truth, world.taxonomy.names)
        for key in ("ap", "ap50", "ap25", "iou", "accuracy"):
            classes[key] = [per.get(c, {}).get(key, np.nan) for c in classes.category]
    return classes
