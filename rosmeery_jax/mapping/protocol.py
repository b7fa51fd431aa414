"""The mapper protocol: a researcher's own semantic mapper in the loop (docs/byo.md).

A mapper is a class, named like a policy plugin (``--mapper FILE.py:Name`` or
``package.module:Name``), built once per robot with the camera and the taxonomy's category
names. The session hands it every detector frame (:class:`Frame`) in time order, and, if
it overrides :meth:`Mapper.add_depth`, the depth camera of every control step between them
(:class:`DepthFrame`); at each sampled time it asks for its semantic map
(:class:`MapState`), which is scored by the evaluator of ``rosmeery evaluate``
(:mod:`rosmeery_jax.metrics.map_score`). The built-in ``perceived`` mapper
(:mod:`rosmeery_jax.mapping.perceived`) is one implementation.

Conventions: the world frame is the benchmark's (x, y on the floor, z up, metres); the
camera's pose and intrinsics follow OpenCV (x right, y down, z forward; pixel (u, v) is
column u, row v, centres at whole numbers); depth is the distance along the optical axis.

Each map is tied to the ground truth point by point; a map that only grows (new points
appended, earlier ones unchanged, as most mappers' clouds do) is tied only for its new
points. Shapes: H x W the detector frame, D detections, V points, I instances.
"""

from __future__ import annotations

import contextlib
from abc import ABC, abstractmethod
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from rosmeery_jax.core import plugins, specs
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.metrics import field, tasks
from rosmeery_jax.metrics.map_score import Score, score_instances, tie
from rosmeery_jax.raycast.sensors import CameraConfig

BUILT_IN = ("oracle", "perceived", "fused")  # "oracle": the built-in knowledge (no mapper object)


class Camera(NamedTuple):
    """The detector camera: width x height pixels, intrinsics (3, 3) K, and the benchmark's
    own camera settings (mount, field of view; ``config.width`` x ``config.height`` the depth
    camera of every step) for mappers that want them."""

    width: int
    height: int
    intrinsics: np.ndarray
    config: CameraConfig

    @staticmethod
    def of(cfg: CameraConfig) -> "Camera":
        return Camera(cfg.rgb_width, cfg.rgb_height, intrinsics(cfg, cfg.rgb_width, cfg.rgb_height), cfg)

    @property
    def depth_intrinsics(self) -> np.ndarray:
        """(3, 3) K of the depth camera of every step (:class:`DepthFrame`)."""
        return intrinsics(self.config, self.config.width, self.config.height)

    def pose(self, robot: np.ndarray) -> np.ndarray:
        """(..., 4, 4) world-from-camera transforms (OpenCV axes) for robot poses (..., 3) x, y, yaw."""
        cfg = self.config
        robot = np.asarray(robot, np.float64)
        x, y, yaw = robot[..., 0], robot[..., 1], robot[..., 2]
        c, s, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(cfg.pitch), np.sin(cfg.pitch)
        yaw_r = np.zeros((*yaw.shape, 3, 3))
        yaw_r[..., 0, 0], yaw_r[..., 0, 1], yaw_r[..., 1, 0], yaw_r[..., 1, 1], yaw_r[..., 2, 2] = c, -s, s, c, 1.0
        tilt = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])  # pitched down for positive pitch
        from_cv = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # OpenCV axes in x fwd, y left, z up
        out = np.zeros((*yaw.shape, 4, 4))
        out[..., :3, :3] = yaw_r @ tilt @ from_cv
        out[..., 0, 3], out[..., 1, 3], out[..., 2, 3] = x + cfg.mount_x * c, y + cfg.mount_x * s, cfg.mount_height
        out[..., 3, 3] = 1.0
        return out


class Frame(NamedTuple):
    """One detector frame: index (0, 1, ... in the run), time_s; rgb (H, W, 3) uint8; depth
    (H, W) float32 metres (0: no return); pose (3,) the robot's x, y, yaw; camera_pose (4, 4)
    world-from-camera; boxes (D, 4) pixel corners x1, y1, x2, y2; labels (D,) category
    index (into the names the mapper was built with); confidences (D,)."""

    index: int
    time_s: float
    rgb: np.ndarray
    depth: np.ndarray
    pose: np.ndarray
    camera_pose: np.ndarray
    boxes: np.ndarray
    labels: np.ndarray
    confidences: np.ndarray


class DepthFrame(NamedTuple):
    """The depth camera after one control step between detector frames: step (1, 2, ... in
    the run; 10 steps a second), time_s; depth (h, w) float32 metres (0: no return) at the
    depth camera's resolution (``camera.config.width`` x ``height``, intrinsics
    ``camera.depth_intrinsics``); pose (3,) the robot's x, y, yaw; camera_pose (4, 4)
    world-from-camera. No image and no detections: geometry only."""

    step: int
    time_s: float
    depth: np.ndarray
    pose: np.ndarray
    camera_pose: np.ndarray


class MapState(NamedTuple):
    """A semantic map: points (V, 3) world frame; instance (V,) int, the id of each point's
    instance (ids index ``label``); label (I,) int category index (-1 none) and confidence
    (I,) in [0, 1] per instance id. Predicates follow from the label through the taxonomy,
    as ``rosmeery evaluate`` counts them."""

    points: np.ndarray
    instance: np.ndarray
    label: np.ndarray
    confidence: np.ndarray


class Mapper(ABC):
    """The protocol: subclass it, give ``name`` (a plain name: results' ``mapper`` column)
    and implement :meth:`add` and :meth:`semantic_map`. One instance per robot."""

    name = "mapper"

    def __init__(self, camera: Camera, categories: tuple[str, ...]):
        self.camera, self.categories = camera, categories

    @abstractmethod
    def add(self, frame: Frame) -> None:
        """Fold one detector frame into the map."""

    @abstractmethod
    def semantic_map(self) -> MapState:
        """The map now."""

    def add_depth(self, frame: DepthFrame) -> None:
        """Fold the depth camera of one step between detector frames (optional: a mapper
        that does not override it is not sent them)."""

    @classmethod
    def reads_depth(cls) -> bool:
        """Whether the session sends this mapper the depth of every step."""
        return cls.add_depth is not Mapper.add_depth


def intrinsics(cfg: CameraConfig, width: int, height: int) -> np.ndarray:
    """(3, 3) K of the benchmark camera at width x height pixels (OpenCV convention)."""
    f = cfg.focal(width)
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


def mapper_class(spec: str, source: str = "config") -> type[Mapper]:
    """A plugin mapper's class, checked as a class: a Mapper subclass with both methods and a
    plain name."""
    cls = plugins.load(spec, source, "mappers")
    if not (isinstance(cls, type) and issubclass(cls, Mapper)):
        raise InputError(source, "mappers", f"plugin {spec!r} is not a Mapper class (subclass rosmeery_jax.Mapper "
                         "and implement add and semantic_map)")
    for method in ("add", "semantic_map"):
        if getattr(getattr(cls, method), "__isabstractmethod__", False):
            raise InputError(source, "mappers", f"plugin {spec!r} lacks a {method} method")
    if cls.name in ("mapper", *BUILT_IN) or not specs.label_name(cls.name):
        raise InputError(source, "mappers", f"plugin {spec!r} needs a class attribute name that labels its "
                         f"results: a plain name ({specs.LABEL_RULE}), not 'mapper' or a built-in's "
                         f"({', '.join(BUILT_IN)})")
    return cls


def mapper_label(spec: str) -> str:
    """The ``mapper`` column of a mapper entry's results."""
    return spec if spec in BUILT_IN else mapper_class(spec).name


def check_mapper(spec: str, camera: CameraConfig, categories: tuple[str, ...]) -> None:
    """Build the plugin and feed it one made-up frame (a wall 2 m ahead, one box): any
    failure or a malformed map is one InputError naming the plugin, before a session runs."""
    cls = mapper_class(spec)
    cam = Camera.of(camera)
    try:
        mapper = cls(cam, categories)
    except Exception as err:
        raise InputError("config", "mappers", f"plugin {spec!r} cannot be built: {plugins.describe(err)}") from None
    w, h = cam.width, cam.height
    pose = np.zeros(3)
    frame = Frame(0, 1.0, np.zeros((h, w, 3), np.uint8), np.full((h, w), 2.0, np.float32), pose, cam.pose(pose),
                  np.array([[w / 4, h / 4, 3 * w / 4, 3 * h / 4]], np.float32), np.zeros(1, np.int32),
                  np.full(1, 0.9, np.float32))
    try:
        mapper.add(frame)
        m = mapper.semantic_map()
    except Exception as err:
        raise InputError("config", "mappers", f"plugin {spec!r} failed on a test frame: {plugins.describe(err)}") \
            from None
    check_map(spec, m, len(categories))


def raised_by(spec: str, doing: str):
    """A plugin mapper's exception during a session as one InputError naming it, what it was
    doing and its line (a traceback through the engine's threads told neither); the built-in
    mappers' raise as they are."""
    return contextlib.nullcontext() if spec in BUILT_IN else plugins.raised_by(spec, "mappers", doing)


def check_map(spec: str, m, categories: int, source: tuple[str, str] | None = None) -> MapState:
    """``m`` as a MapState of numpy arrays, or one InputError naming the plugin and what is
    wrong (type, shape, dtype, finiteness, ids, labels, confidences); ``source``: (source,
    field) of a map handed in otherwise than by a plugin mapper, which ``spec`` then names."""
    def bad(what: str):
        if source:
            return InputError(*source, f"{spec}: {what}")
        return InputError("config", "mappers", f"plugin {spec!r}: semantic_map returned {what}")

    if not isinstance(m, MapState):
        raise bad(f"a {type(m).__name__}, not a MapState")
    points, instance, label, conf = (np.asarray(a) for a in m)
    if points.ndim != 2 or points.shape[1:] != (3,) or not np.issubdtype(points.dtype, np.floating):
        raise bad(f"points of shape {points.shape} and dtype {points.dtype}, not (V, 3) floats")
    if not np.isfinite(points).all():
        raise bad("points that are not finite")
    if instance.shape != points.shape[:1] or not np.issubdtype(instance.dtype, np.integer):
        raise bad(f"instance of shape {instance.shape} and dtype {instance.dtype}, not (V,) integers")
    if label.ndim != 1 or conf.shape != label.shape or not np.issubdtype(label.dtype, np.integer):
        raise bad(f"label {label.shape} {label.dtype} and confidence {conf.shape}: (I,) integers and (I,) numbers needed")
    if len(instance) and (instance.min() < 0 or instance.max() >= len(label)):
        raise bad(f"instance ids outside [0, {len(label)}) (one label per instance id)")
    if len(label) and (label.min() < -1 or label.max() >= categories):
        raise bad(f"labels outside [-1, {categories}) (category indices, -1 none)")
    if not (np.isfinite(conf).all() and ((conf >= 0) & (conf <= 1)).all()):
        raise bad("confidences outside [0, 1]")
    return MapState(points.astype(np.float64), instance.astype(np.int64), label.astype(np.int32),
                    conf.astype(np.float32))


def _same_memory(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether arrays a and b view the same memory the same way (a built-in mapper's points
    handed out again: equal without reading them; points are finite)."""
    return (a.shape == b.shape and a.strides == b.strides and a.dtype == b.dtype
            and a.__array_interface__["data"][0] == b.__array_interface__["data"][0])


class OnlineScorer:
    """Scores one robot's maps as they grow (module docstring): ``score(map) -> Score``.

    While a map's points only grow, each new point is tied once, each new (instance, sample)
    pair is added once to the instances' shared samples, and a map unchanged since the last
    call is not scored again. Old points given other instance ids (instances merged) are
    counted again from their ties; any other change scores the map from scratch. The
    result is the same either way. With ``field_names``, the Score's ``field`` carries those
    field map metrics (:class:`rosmeery_jax.metrics.field.FieldScorer`, incremental alike);
    with a ``task`` query, the task metrics too (:class:`rosmeery_jax.metrics.tasks.TaskScorer`)."""

    def __init__(self, world, tolerance: float, field_names: tuple[str, ...] = (), task: tasks.TaskQuery = None):
        self.world, self.tolerance, self.field_names = world, tolerance, tuple(field_names)
        self.field = field.FieldScorer(field.FieldTruth.of(world)) if self.field_names else None
        self.task = task.scorer(world) if task is not None and task.names else None
        self.task_names = task.names if self.task is not None else ()
        self.tree = cKDTree(np.asarray(world.truth.samples.points, np.float64))  # built once, not per map
        self.objects = np.asarray(world.truth.samples.object)
        self._clear()

    def _clear(self) -> None:
        self.points, self.instance = np.zeros((0, 3)), np.zeros(0, np.int64)
        self.sample = np.zeros(0, np.int64)  # per point: its tied sample (-1 none)
        self.shared = np.zeros((0, self.world.truth.num_objects), np.int64)  # per instance id
        self.present = np.zeros(0, bool)  # per instance id: holds a point
        self.pairs: set[int] = set()
        self.last = None  # (label, confidence, Score) of the last call

    def score(self, m: MapState, ties: np.ndarray | None = None) -> Score:
        """Score map ``m``; ``ties`` (V,): its points' tied samples when the caller knows
        them (a map of ground-truth samples), else each new point is looked up."""
        old = len(self.points)
        if not (len(m.points) >= old and (_same_memory(m.points[:old], self.points)
                                          or np.array_equal(m.points[:old], self.points))):
            self._clear()
            old = 0
        elif not np.array_equal(m.instance[:old], self.instance):  # instances merged: same ties, new pairs
            sample = self.sample
            self._clear()
            self.points, self.sample = m.points[:old], sample
            self._count(m.instance[:old], sample)
        elif len(m.points) == old and self.last is not None and np.array_equal(self.last[0], m.label) \
                and np.array_equal(self.last[1], m.confidence):
            return self.last[2]
        if ties is not None:
            sample = np.asarray(ties[old:len(m.points)], np.int64)
        elif len(m.points) > old:
            sample = tie(self.world, m.points[old:], self.tolerance, self.tree)
        else:
            sample = np.zeros(0, np.int64)
        self._count(m.instance[old:], sample)
        self.points, self.instance, self.sample = m.points, m.instance, np.r_[self.sample[:old], sample]
        ids = np.flatnonzero(self.present)
        sc = score_instances(self.world, ids, self.shared[ids], lambda i: (m.label[i], m.confidence[i]),
                             int((self.sample >= 0).sum()), len(self.points))
        if self.field is not None:
            tally = self.field.tally(m.points, m.instance, m.label, m.confidence, self.sample, self.shared)
            sc = sc._replace(field=field.values(tally, self.field.truth, self.field_names), tally=tally)
        if self.task is not None:
            names = self.world.taxonomy.names
            done = self.task.score(m.points, m.instance, {i: names[c] for i, c in enumerate(m.label.tolist()) if c >= 0})
            sc = sc._replace(field={**(sc.field or {}), **{n: done.values[n] for n in self.task_names}})
        self.last = (m.label.copy(), m.confidence.copy(), sc)
        return sc

    def _count(self, instance: np.ndarray, sample: np.ndarray) -> None:
        """Count the new (instance, sample) pairs of points with these ids and ties."""
        if not len(instance):
            return
        top = int(instance.max()) + 1
        if top > len(self.present):
            grow = top - len(self.present)
            self.present = np.r_[self.present, np.zeros(grow, bool)]
            self.shared = np.r_[self.shared, np.zeros((grow, self.shared.shape[1]), np.int64)]
        self.present[instance] = True
        on = sample >= 0
        n = len(self.objects)
        fresh = [k for k in np.unique(instance[on] * n + sample[on]).tolist() if k not in self.pairs]
        self.pairs.update(fresh)
        fresh = np.asarray(fresh, np.int64)
        np.add.at(self.shared, (fresh // n, self.objects[fresh % n]), 1)


def check_entries(entries: tuple[str, ...], camera: CameraConfig, categories: tuple[str, ...]) -> None:
    """A session's mapper entries: each a built-in or a plugin that runs on a test frame,
    their labels distinct (one InputError naming the entry)."""
    for m in entries:
        if m not in BUILT_IN and not specs.is_plugin(m):
            raise InputError("config", "mappers", f"{m!r} is not a mapper ({', '.join(BUILT_IN)}, or a plugin: "
                             "FILE.py:Name or package.module:Name)")
    for m in entries:
        if m not in BUILT_IN:
            check_mapper(m, camera, categories)
    labels = [mapper_label(m) for m in entries]
    twice = next((m for m, name in zip(entries, labels) if labels.count(name) > 1), None)
    if twice is not None:
        raise InputError("config", "mappers", f"{twice!r}: two mappers are named {mapper_label(twice)!r}")
