"""Load a world (MJCF + semantics) into one immutable :class:`World`.

World file format (standard MJCF; opens in ``python -m mujoco.viewer --mjcf=FILE``):

- geoms directly under ``<worldbody>``: the floor (one ``plane``) and the walls (boxes);
- each body directly under ``<worldbody>`` is one ground-truth object, built from boxes
  (nested bodies belong to their top-level ancestor); bodies carry no joints;
- every box may be rotated about z only (the fast raycast kernel's primitive);
- ``<custom>`` carries the semantics:
  ``<text name="rosmeery:category:BODY" data="CATEGORY"/>`` for every object (a category of
  the taxonomy), ``<numeric name="rosmeery:spawn" data="X Y YAW"/>`` for the robot spawn, and
  optionally ``<text name="rosmeery:title" data="Nice Name"/>``.

Anything else is rejected with one line naming the file and the element.
"""

from __future__ import annotations

import contextlib
import warnings
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np

from rosmeery_jax.core import specs
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.world.freespace import FreeSpace, build_free_space
from rosmeery_jax.world.procedural import procedural_path
from rosmeery_jax.world.scene import WALL, Scene
from rosmeery_jax.world.surface import SurfaceSamples, observable_samples
from rosmeery_jax.world.taxonomy import Predicate, Taxonomy, load_taxonomy

WORLDS_DIR = Path(str(resources.files("rosmeery_jax.builtin_worlds")))  # the repository's worlds/, in the package
PAPER_WORLDS = ("kitchen", "laboratory", "small_office", "large_office")
CATEGORY_PREFIX = "rosmeery:category:"
SPAWN_NAME = "rosmeery:spawn"
TITLE_NAME = "rosmeery:title"
FLOOR_RGB = (0.71, 0.69, 0.65)
MAX_EXTENT = 1000.0  # m: coordinates and box sizes beyond this are refused (an indoor world)


@dataclass(frozen=True)
class WorldConfig:
    """How a world file is turned into ground truth.

    density: surface samples per m^2 (400 = one per 25 cm^2, docs/metrics.md).
    camera_height: the camera's mounting height (m); faces seen only edge-on from that height
        are not observable (None: keep them).
    contact_gap: a face closer than this to another solid (or the floor) is not observable.
    robot_radius / robot_height: the robot's plan radius and height (m), for the free-space
        map, the reachable area and the spawn check.
    ``env.make`` sets robot_radius, robot_height and camera_height from the env's
    ``robot__radius``, ``robot__height`` and ``camera__mount_height`` (their one source).
    map_resolution: cell size of the free-space map (m).
    """

    density: float = 400.0
    camera_height: float | None = 0.5
    contact_gap: float = 0.02
    robot_radius: float = 0.2
    robot_height: float = 0.5
    map_resolution: float = 0.05


@dataclass(frozen=True)
class GroundTruth:
    """SK-GP: what the benchmark scores against. N objects, S samples.

    names, categories, macros, roots: (N,) tuples of str.
    category_index: (N,) int32, index into ``taxonomy.names``.
    pose: (N, 4) float32 body x, y, z, yaw.
    bbox_center: (N, 3), bbox_size: (N, 3), bbox_yaw: (N,): each object's oriented box.
    predicates: (N,) tuple of predicate triples P_G(n); num_predicates: (N,) int32 = |P_G(n)|.
    samples: observable surface samples; ps_G: (N,) int32 samples per object.
    """

    names: tuple[str, ...]
    categories: tuple[str, ...]
    macros: tuple[str, ...]
    roots: tuple[str, ...]
    category_index: np.ndarray
    pose: np.ndarray
    bbox_center: np.ndarray
    bbox_size: np.ndarray
    bbox_yaw: np.ndarray
    predicates: tuple[tuple[Predicate, ...], ...]
    num_predicates: np.ndarray
    samples: SurfaceSamples
    ps_G: np.ndarray

    @property
    def num_objects(self) -> int:
        return len(self.names)


@dataclass(frozen=True)
class World:
    """One loaded world: MuJoCo model, raycast scene, ground truth and 2D free-space map.

    ``mj_model`` is the static world (no robot); the platform adds its robot to ``spec`` and
    puts the result on MJX. Arrays are read-only numpy; ``jnp.asarray`` maps over ``scene``.
    """

    name: str
    title: str
    path: Path
    config: WorldConfig
    taxonomy: Taxonomy
    mj_model: mujoco.MjModel = field(repr=False)
    scene: Scene = field(repr=False)
    truth: GroundTruth = field(repr=False)
    free_space: FreeSpace = field(repr=False)
    spawn: np.ndarray = field(repr=False)

    @property
    def spec(self) -> mujoco.MjSpec:
        """A fresh, editable MjSpec of this world's file."""
        with _mujoco_warnings(self.path):
            return mujoco.MjSpec.from_file(str(self.path))

    def summary(self) -> dict:
        t = self.truth
        return {
            "name": self.name,
            "title": self.title,
            "path": str(self.path),
            "objects": t.num_objects,
            "samples": int(t.ps_G.sum()),
            "boxes": self.scene.num_boxes,
            "reachable_area_m2": round(self.free_space.reachable_area_m2, 2),
            "categories": {c: t.categories.count(c) for c in sorted(set(t.categories))},
        }


def world_names() -> tuple[str, ...]:
    """Built-in worlds (the four paper worlds first, then any other file in worlds/)."""
    found = sorted(p.stem for p in WORLDS_DIR.glob("*.xml"))
    return tuple(n for n in PAPER_WORLDS if n in found) + tuple(n for n in found if n not in PAPER_WORLDS)


def resolve_world_path(name_or_path: str | Path) -> Path:
    """A built-in world name, a procedural name (``procedural:KIND:SEED``), or a path to a
    user's MJCF file."""
    text = str(name_or_path)
    if specs.kind(text) == "procedural":  # generated on first use (rosmeery_jax/world/procedural.py)
        return procedural_path(text)
    if "/" not in text and not text.endswith(".xml"):
        path = WORLDS_DIR / f"{text}.xml"
        if not path.is_file():
            raise InputError(text, "", f"no built-in world of that name (built-in: {', '.join(world_names())}); "
                                       "give a path to an MJCF file for your own")
        return path
    path = Path(text).expanduser().resolve()
    if not path.is_file():
        raise InputError(path, "", "is a folder, not a world file" if path.is_dir() else "world file not found")
    return path


def load_world(name_or_path: str | Path, config: WorldConfig | None = None,
               taxonomy: str | Path | None = None) -> World:
    """Load a world by built-in name or MJCF path (cached per file, config and taxonomy)."""
    if config is not None and not isinstance(config, WorldConfig):
        raise TypeError(f"load_world: config must be a WorldConfig, not {type(config).__name__}")
    path = resolve_world_path(name_or_path)
    return _load(path, path.stat().st_mtime_ns, config or WorldConfig(),
                 str(taxonomy) if taxonomy is not None else None)


@lru_cache(maxsize=16)
def _load(path: Path, _mtime: int, config: WorldConfig, taxonomy_path: str | None) -> World:
    taxonomy = load_taxonomy(taxonomy_path)
    try:
        path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as err:
        raise InputError(path, "file", f"not UTF-8 text (byte {err.start}): save the world as UTF-8") from None
    except OSError as err:
        raise InputError(path, "file", f"unreadable ({err.strerror or err})") from None
    with _mujoco_warnings(path):
        try:
            model = mujoco.MjModel.from_xml_path(str(path))
        except ValueError as err:
            raise InputError(path, "", "invalid MJCF: " + " ".join(str(err).split())) from None
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)

    texts = _texts(model)
    objects = _objects(model, path)
    categories = _categories(model, path, texts, objects, taxonomy)
    spawn = _spawn(model, path)
    scene = _scene(model, data, path, objects)
    truth = _truth(path, model, data, scene, objects, categories, taxonomy, config)
    free = build_free_space(scene, spawn[:2], config.robot_radius, config.robot_height, config.map_resolution)
    _check_layout(path, objects, model, truth, free, spawn, config, scene)

    title = texts.get(TITLE_NAME) or path.stem.replace("_", " ").title()
    for arr in (*scene, spawn, *_arrays(truth), *_arrays(free)):
        if isinstance(arr, np.ndarray):
            arr.flags.writeable = False
    return World(path.stem, title, path, config, taxonomy, model, scene, truth, free, spawn)


@contextlib.contextmanager
def _mujoco_warnings(path: Path):
    """MuJoCo's warnings while it reads ``path``, as Python warnings naming the file, but for
    a NaN's (the checks after it name the element, in one error line). Left to itself
    MuJoCo appends them to MUJOCO_LOG.TXT in the working directory, a file the user never
    asked for."""
    caught: list[str] = []
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(caught.append)
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(previous)
        for message in caught:
            if "NaN" not in message:
                warnings.warn(f"{path}: MuJoCo: {message.strip()}", stacklevel=3)


def _arrays(nt) -> list:
    vals = nt.__dict__.values() if hasattr(nt, "__dict__") else nt
    out = []
    for v in vals:
        out.extend(v if isinstance(v, tuple) and hasattr(v, "_fields") else [v])
    return out


def _name(model, kind, i) -> str:
    return mujoco.mj_id2name(model, kind, i) or f"#{i}"


def _texts(model) -> dict[str, str]:
    out = {}
    for i in range(model.ntext):
        adr, size = model.text_adr[i], model.text_size[i]
        raw = bytes(model.text_data[adr:adr + size]).rstrip(b"\0").decode()
        out[_name(model, mujoco.mjtObj.mjOBJ_TEXT, i)] = raw
    return out


def _objects(model, path) -> list[int]:
    """Top-level body ids, in file order (object index n = position in this list)."""
    for b in range(1, model.nbody):
        if model.body_jntnum[b] > 0:
            raise InputError(path, f"body '{_name(model, mujoco.mjtObj.mjOBJ_BODY, b)}'",
                             "has joints; worlds are static (the platform adds the robot itself)")
    return [b for b in range(1, model.nbody) if model.body_parentid[b] == 0]


def _categories(model, path, texts, objects, taxonomy) -> list[str]:
    names = {_name(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in objects}
    for key in texts:
        if key.startswith(CATEGORY_PREFIX) and key[len(CATEGORY_PREFIX):] not in names:
            raise InputError(path, f"text '{key}'", "names no top-level body")
    out = []
    for b in objects:
        body = _name(model, mujoco.mjtObj.mjOBJ_BODY, b)
        cat = texts.get(CATEGORY_PREFIX + body)
        if cat is None:
            raise InputError(path, f"body '{body}'", f"has no category (add <text name=\"{CATEGORY_PREFIX}{body}\" "
                                                     "data=\"CATEGORY\"/> under <custom>)")
        if cat not in taxonomy:
            raise InputError(path, f"body '{body}'", f"unknown category {cat!r} (not in {taxonomy.source})")
        out.append(cat)
    if not out:
        raise InputError(path, "worldbody", "has no objects (top-level bodies)")
    return out


def _spawn(model, path) -> np.ndarray:
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, SPAWN_NAME)
    if i < 0:
        raise InputError(path, "custom", f"missing <numeric name=\"{SPAWN_NAME}\" data=\"X Y YAW\"/>")
    adr, size = model.numeric_adr[i], model.numeric_size[i]
    if size != 3:
        raise InputError(path, f"numeric '{SPAWN_NAME}'", f"needs 3 values (x y yaw), got {size}")
    spawn = np.array(model.numeric_data[adr:adr + 3], dtype=np.float64)
    if not np.all(np.isfinite(spawn)) or np.abs(spawn).max() > MAX_EXTENT:
        raise InputError(path, f"numeric '{SPAWN_NAME}'", f"{spawn.tolist()} must be finite numbers within "
                         f"{MAX_EXTENT:g} m of the origin")
    return spawn.astype(np.float32)


def _scene(model, data, path, objects) -> Scene:
    index = {b: n for n, b in enumerate(objects)}
    centers, halves, yaws, owners, rgbs, geoms = [], [], [], [], [], []
    floors = 0
    for g in range(model.ngeom):
        gname = _name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
        gtype = model.geom_type[g]
        body = model.geom_bodyid[g]
        if gtype == mujoco.mjtGeom.mjGEOM_PLANE:
            if body != 0 or floors:
                raise InputError(path, f"geom '{gname}'", "only one floor plane, directly under <worldbody>, is allowed")
            if abs(data.geom_xmat[g][8] - 1) > 1e-6 or abs(data.geom_xpos[g][2]) > 1e-6:
                raise InputError(path, f"geom '{gname}'", "the floor plane must be z = 0, facing up")
            floors += 1
            continue
        if gtype != mujoco.mjtGeom.mjGEOM_BOX:
            kind = mujoco.mjtGeom(gtype).name.removeprefix("mjGEOM_").lower()
            raise InputError(path, f"geom '{gname}'", f"is a {kind}; worlds are built from boxes rotated about z only")
        numbers = np.concatenate([model.geom_size[g], data.geom_xpos[g]])
        if not np.all(np.isfinite(numbers)) or np.abs(numbers).max() > MAX_EXTENT:
            raise InputError(path, f"geom '{gname}'", f"position or size beyond {MAX_EXTENT:g} m (or not a number)")
        if model.geom_size[g].min() <= 0:
            raise InputError(path, f"geom '{gname}'", "has a zero or negative size")
        xmat = data.geom_xmat[g].reshape(3, 3)
        if abs(xmat[2, 2] - 1) > 1e-6:
            raise InputError(path, f"geom '{gname}'", "is tilted; boxes may only be rotated about z")
        centers.append(data.geom_xpos[g].copy())
        halves.append(model.geom_size[g].copy())
        yaws.append(np.arctan2(xmat[1, 0], xmat[0, 0]))
        root = model.body_rootid[body]
        owners.append(index[root] if root != 0 else WALL)
        mat = model.geom_matid[g]
        rgbs.append((model.mat_rgba[mat] if mat >= 0 else model.geom_rgba[g])[:3].copy())
        geoms.append(g)
    if not floors:
        raise InputError(path, "worldbody", "has no floor (a geom of type plane at z = 0)")
    f32 = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
    return Scene(f32(centers), f32(halves), f32(yaws), np.asarray(owners, np.int32), f32(rgbs), f32(FLOOR_RGB),
                 np.asarray(geoms, np.int32))


def _truth(path, model, data, scene, objects, categories, taxonomy, config) -> GroundTruth:
    names = tuple(_name(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in objects)
    n = len(objects)
    pose = np.zeros((n, 4), np.float32)
    bc, bs, by = np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32), np.zeros(n, np.float32)
    corners = scene.footprint_corners()
    for i, b in enumerate(objects):
        xmat = data.xmat[b].reshape(3, 3)
        yaw = float(np.arctan2(xmat[1, 0], xmat[0, 0]))
        pose[i] = (*data.xpos[b], yaw)
        mine = scene.object_id == i
        if not mine.any():
            raise InputError(path, f"body '{names[i]}'", "has no box geoms")
        c, s = np.cos(yaw), np.sin(yaw)
        pts = (corners[mine].reshape(-1, 2) - data.xpos[b][:2]) @ np.array([[c, -s], [s, c]])
        lo, hi = pts.min(0), pts.max(0)
        z0 = (scene.center[mine, 2] - scene.half[mine, 2]).min()
        z1 = (scene.center[mine, 2] + scene.half[mine, 2]).max()
        mid = (lo + hi) / 2
        bc[i] = (*(data.xpos[b][:2] + np.array([[c, -s], [s, c]]) @ mid), (z0 + z1) / 2)
        bs[i] = (*(hi - lo), z1 - z0)
        by[i] = yaw
    samples = observable_samples(scene, config.density, config.contact_gap, config.camera_height)
    ps_G = np.bincount(samples.object, minlength=n).astype(np.int32)
    chains = [taxonomy.chain(c) for c in categories]
    preds = tuple(taxonomy.predicates(nm, c) for nm, c in zip(names, categories))
    return GroundTruth(
        names, tuple(categories), tuple(ch[1] for ch in chains), tuple(ch[2] for ch in chains),
        np.array([taxonomy.index(c) for c in categories], np.int32), pose, bc, bs, by,
        preds, np.array([len(p) for p in preds], np.int32), samples, ps_G)


def _check_layout(path, objects, model, truth, free: FreeSpace, spawn, config, scene: Scene) -> None:
    walls = scene.object_id == WALL
    if not walls.any() or free.interior.all():
        raise InputError(path, "worldbody", "has no walls enclosing the spawn (wall boxes directly under "
                         "<worldbody>); an open world has no inside to explore")
    top = float((scene.center[walls, 2] + scene.half[walls, 2]).max())
    for i, name in enumerate(truth.names):
        bottom = float(truth.bbox_center[i, 2] - truth.bbox_size[i, 2] / 2)
        if bottom > top:
            raise InputError(path, f"body '{name}'", f"floats at z = {bottom:.2f} m, above the walls' top ({top:.2f} m)")
        xy = truth.bbox_center[i, :2]
        if not free.contains(xy) or not free.interior[free.cell(xy)]:
            raise InputError(path, f"body '{name}'", f"lies outside the walls (centre at {xy[0]:.2f}, {xy[1]:.2f})")
        if truth.ps_G[i] == 0:
            raise InputError(path, f"body '{name}'", "has no observable surface (buried in walls or other objects)")
    sx, sy = float(spawn[0]), float(spawn[1])
    if not free.contains(spawn[:2]) or not free.interior[free.cell(spawn[:2])]:
        raise InputError(path, f"numeric '{SPAWN_NAME}'", f"spawn ({sx:.2f}, {sy:.2f}) lies outside the walls")
    clearance = float(free.clearance[free.cell(spawn[:2])])
    if clearance <= config.robot_radius:
        raise InputError(path, f"numeric '{SPAWN_NAME}'",
                         f"spawn ({sx:.2f}, {sy:.2f}) is inside an obstacle (clearance {clearance:.2f} m, "
                         f"robot radius {config.robot_radius:.2f} m)")


def check_entry(name: str) -> None:
    """A name that is neither a built-in world nor an existing file nor a procedural name is
    the config's error (one line)."""
    if name not in world_names() and not Path(name).is_file() and specs.kind(name) != "procedural":
        raise InputError("config", "worlds", f"{name!r} is neither a built-in world ({', '.join(world_names())}) "
                         "nor an MJCF file nor procedural:KIND:SEED")
