"""A world as data: every array the jitted step, policies and metrics read, padded to sizes
shared by a session's worlds, so one compiled function serves them all.

A session stacks its worlds' :class:`WorldData` along a leading world axis and passes it
to its one compiled chunk function as an argument; each env gathers its own world. Padding
never changes a result (tests/test_engine.py runs a world alone and beside a larger one):

- raycast boxes: far away, never hit (the camera keeps the nearest ``cull`` boxes in view,
  and the packed key's index bits are fixed, so padding changes neither choice); the laser
  casts only against the boxes that cross its plane, in their order in the scene;
- collision proxies: inert boxes far away, never among the nearest pairs MJX keeps;
- grid rows and columns beyond the world's extent: never written, read as off the map;
- samples: far away on the last object, never observed; objects: no samples, never named;
- reachable cells: repeated, but only the first ``n_reachable`` are drawn.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.env.config import EnvConfig
from rosmeery_jax.raycast.kernel import CHUNK, RayScene, crosses_plane, ray_scene
from rosmeery_jax.sim.coverage import SampleTable
from rosmeery_jax.sim.knowledge import GroundTruthTable, predicate_tables
from rosmeery_jax.sim.mjx import mjx
from rosmeery_jax.sim.occupancy import GridGeometry
from rosmeery_jax.sim.robot import PROXY_FIELDS, RobotConfig, near_model, proxy_boxes, robot_model
from rosmeery_jax.world import World

NEVER = 2.0 ** 30  # ps_G of a padding object: no observed share ever names it
# The MJX model fields that differ between worlds of one padded structure. Only these are
# data; the rest of the model (the robot, solver settings) stays a compile-time constant,
# which XLA folds (passing the whole model as an argument measured 14 % slower).
PHYSICS_FIELDS = PROXY_FIELDS + ("body_pos", "body_quat", "qpos0")


@dataclass(frozen=True)
class Sizes:
    """Padded sizes: boxes (raycast, whole chunks), laser_boxes (those crossing the laser's
    plane, whole chunks), proxies (collision), grid (H, W), samples S, objects N,
    categories C, reachable cells M."""

    boxes: int
    laser_boxes: int
    proxies: int
    grid: tuple[int, int]
    samples: int
    objects: int
    categories: int
    reachable: int

    @staticmethod
    def of(world: World, config: EnvConfig) -> "Sizes":
        """A world's own sizes under an env ``config`` (its ``robot`` and ``laser``)."""
        t, chunks = world.truth, lambda n: max(CHUNK, -(-n // CHUNK) * CHUNK)
        laser_boxes = int(crosses_plane(world.scene, config.laser.height).sum())
        return Sizes(chunks(world.scene.num_boxes), chunks(laser_boxes), len(proxy_boxes(world, config.robot)),
                     tuple(world.free_space.occupied.shape), len(t.samples.object), int(t.num_objects),
                     len(world.taxonomy.names), int(world.free_space.reachable.sum()))

    @staticmethod
    def union(sizes: list["Sizes"]) -> "Sizes":
        """The largest of each size."""
        return Sizes(max(s.boxes for s in sizes), max(s.laser_boxes for s in sizes), max(s.proxies for s in sizes),
                     (max(s.grid[0] for s in sizes), max(s.grid[1] for s in sizes)),
                     max(s.samples for s in sizes), max(s.objects for s in sizes),
                     max(s.categories for s in sizes), max(s.reachable for s in sizes))


class WorldData(NamedTuple):
    """One world on device. physics: the world's MJX model fields (``PHYSICS_FIELDS``: the
    proxies' geometry, the robot's spawn); spawn (3,); rays: the raycast scene (G boxes);
    laser_rays: its boxes that cross the laser's plane; grid: the free-space grid geometry
    (H, W); samples: (S,) ground truth samples of N objects; category (N,) int32; ps_G (N,)
    float32; declared (C,) and correct (N, C) int32 predicate tables; reachable (M, 2) cell
    centres, the first ``n_reachable`` real."""

    physics: dict
    spawn: jax.Array
    rays: RayScene
    laser_rays: RayScene
    grid: GridGeometry
    samples: SampleTable
    category: jax.Array
    ps_G: jax.Array
    declared: jax.Array
    correct: jax.Array
    reachable: jax.Array
    n_reachable: jax.Array


def world_data(world: World, config: EnvConfig, sizes: Sizes | None = None,
               model: mjx.Model | None = None) -> WorldData:
    """``world`` as data under an env ``config`` (its ``robot`` and ``laser``), padded to
    ``sizes`` (its own sizes by default); ``model``: its :func:`physics_model` at those sizes,
    when the caller has built it already."""
    robot = config.robot
    own = Sizes.of(world, config)
    sizes = sizes or own
    t, fs = world.truth, world.free_space
    model = model if model is not None else physics_model(world, robot, sizes)
    extra = sizes.objects - own.objects
    declared, correct = predicate_tables(world.taxonomy, t.categories)
    declared = np.pad(declared, (0, sizes.categories - len(declared)))
    correct = np.pad(correct, ((0, extra), (0, sizes.categories - correct.shape[1])))
    i, j = np.nonzero(fs.reachable)
    cells = np.stack([fs.origin[0] + (j + 0.5) * fs.resolution, fs.origin[1] + (i + 0.5) * fs.resolution], -1)
    cells = np.concatenate([cells, np.repeat(cells[-1:], sizes.reachable - len(cells), 0)])
    return WorldData(
        physics={f: getattr(model, f) for f in PHYSICS_FIELDS},
        spawn=jnp.asarray(world.spawn, jnp.float32),
        rays=ray_scene(world.scene, sizes.boxes),
        laser_rays=ray_scene(world.scene.select(crosses_plane(world.scene, config.laser.height)), sizes.laser_boxes),
        grid=GridGeometry.of(fs, sizes.grid),
        samples=SampleTable.of(t, sizes.samples, sizes.objects),
        category=jnp.asarray(np.pad(np.asarray(t.category_index, np.int32), (0, extra)), jnp.int32),
        ps_G=jnp.asarray(np.pad(np.asarray(t.ps_G, np.float32), (0, extra), constant_values=NEVER), jnp.float32),
        declared=jnp.asarray(declared, jnp.int32),
        correct=jnp.asarray(correct, jnp.int32),
        reachable=jnp.asarray(cells, jnp.float32),
        n_reachable=jnp.int32(len(i)),
    )


def physics_model(world: World, robot: RobotConfig, sizes: Sizes) -> mjx.Model:
    """The MJX model of ``world`` with its proxies padded to ``sizes``. The two static (numpy)
    fields that differ between worlds of one structure get one value, so any world's model
    can stand for the others with ``PHYSICS_FIELDS`` swapped in: ``geom_sameframe`` (0 = no
    shortcut, always correct) and ``geom_rbound_hfield`` (read only for height fields)."""
    return _put(robot_model(world, robot, sizes.proxies))


def near_physics_model(world: World, robot: RobotConfig, sizes: Sizes) -> mjx.Model | None:
    """The structure :class:`~rosmeery_jax.sim.robot.Platform` fills with the nearest
    ``robot.near_proxies`` proxies each control step; None when that is every proxy."""
    if robot.near_proxies == 0 or robot.near_proxies >= sizes.proxies:
        return None
    return _put(near_model(world, robot, robot.near_proxies))


def _put(model) -> mjx.Model:
    model = mjx.put_model(model)
    impl = model._impl.replace(geom_rbound_hfield=np.zeros_like(model._impl.geom_rbound_hfield))
    return model.replace(geom_sameframe=np.zeros_like(model.geom_sameframe), _impl=impl)


def truth_table(world: World) -> GroundTruthTable:
    """The host-side ground truth the metrics read (the world's own N objects)."""
    t = world.truth
    return GroundTruthTable(np.asarray(t.ps_G), np.asarray(t.num_predicates), np.asarray(t.category_index))


def stack(datas: list[WorldData]) -> WorldData:
    """Worlds of equal padded sizes along a leading world axis (W, ...)."""
    return jax.tree.map(lambda *a: jax.device_put(np.stack(a)), *datas)  # on the host: no compile per leaf


def pick(stacked: WorldData, index: jax.Array) -> WorldData:
    """World ``index`` of a stacked WorldData (in a jitted function: a gather)."""
    return jax.tree.map(lambda a: a[index], stacked)
