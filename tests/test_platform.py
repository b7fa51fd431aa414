"""The batched platform: raycast vs MuJoCo, physics, mapping, navigation, determinism."""

from __future__ import annotations

import functools
import re
from dataclasses import replace

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from conftest import OPTIMIZED
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from rosmeery_jax.env import make
from rosmeery_jax.raycast.kernel import cast, ray_scene
from rosmeery_jax.sim import occupancy
from rosmeery_jax.sim.navigation import STATUS_NAMES
from rosmeery_jax.sim.robot import penetration
from rosmeery_jax.world import PAPER_WORLDS, WALL, load_world
from rosmeery_jax.world.freespace import rasterize


@pytest.mark.parametrize("name", PAPER_WORLDS)
def test_raycast_agrees_with_mj_ray(name):
    w = load_world(name)
    rng = np.random.default_rng(1)
    cells = np.argwhere(w.free_space.reachable)
    pick = cells[rng.integers(len(cells), size=6)]
    fs = w.free_space
    org = np.stack([fs.origin[0] + (pick[:, 1] + 0.5) * fs.resolution,
                    fs.origin[1] + (pick[:, 0] + 0.5) * fs.resolution, rng.uniform(0.05, 2.0, 6)], -1)
    d = rng.normal(size=(6, 100, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    hit = jax.jit(lambda o, d: cast(ray_scene(w.scene), o, d, 50.0))(jnp.asarray(org, jnp.float32), jnp.asarray(d, jnp.float32))
    m = w.mj_model
    data = mujoco.MjData(m)
    mujoco.mj_forward(m, data)
    floor = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    gid = np.zeros(1, np.int32)
    matched = 0
    o32, d32 = org.astype(np.float32).astype(np.float64), d.astype(np.float32).astype(np.float64)
    for b in range(6):
        for r in range(100):
            dist = mujoco.mj_ray(m, data, o32[b], d32[b, r], None, 1, -1, gid)
            box = int(hit.box[b, r])
            ours = int(w.scene.geom[box]) if box >= 0 else (floor if int(hit.label[b, r]) == -2 else -1)
            theirs = int(gid[0]) if dist >= 0 else -1
            if dist >= 0:
                assert abs(float(hit.dist[b, r]) - dist) <= 1e-4 * max(dist, 1.0)
            # Same geom, except where two boxes share the hit point (overlapping walls, desks
            # touching end to end): then the distance check above already pins the surface.
            assert ours == theirs or (dist >= 0 and box >= 0), (b, r, ours, theirs)
            matched += ours == theirs
    assert matched >= 0.97 * 600


@pytest.mark.parametrize("name", ["kitchen", "large_office"])  # kitchen and office furniture, four heights each
def test_laser_on_the_boxes_crossing_its_plane_is_the_full_cast(name):
    """The laser casts only against the boxes crossing its plane: bitwise the same ranges and
    labels as against every box, at the default height and at heights where furniture tops
    and bottoms lie exactly on the plane."""
    from rosmeery_jax.apps.bench import random_targets
    from rosmeery_jax.raycast import sensors

    w = load_world(name)
    poses = jnp.asarray(random_targets(w, 64, 4))
    cast = jax.jit(jax.vmap(sensors.laser, in_axes=(None, None, 0)), static_argnums=1)
    s = w.scene
    edges = np.concatenate([s.center[:, 2] - s.half[:, 2], s.center[:, 2] + s.half[:, 2]])
    for h in [0.3] + sorted(set(edges[(edges > 0.05) & (edges < 1.5)].tolist()))[:3]:
        env = make(w, laser__height=float(h))
        assert env.laser_rays.num_boxes < env.rays.num_boxes
        full, plane = cast(env.rays, env.config.laser, poses), cast(env.laser_rays, env.config.laser, poses)
        for a, b in zip(full, plane):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        assert (np.asarray(full[1]) >= 0).mean() > 0.1  # not vacuous: beams hit objects


@pytest.mark.parametrize("name", ["large_office", "small_office"])
def test_camera_column_kernel_and_cull_agree_with_plain_cast(name):
    """The level-camera kernel is exact; the frustum cull only drops boxes that are hidden."""
    from dataclasses import replace

    from rosmeery_jax.apps.bench import random_targets
    from rosmeery_jax.raycast import sensors

    w = load_world(name)
    rs = ray_scene(w.scene)
    cfg = sensors.CameraConfig()
    poses = jnp.asarray(random_targets(w, 16, seed=3))

    def plain(p):
        o, axis = sensors.camera_pose(cfg, p)
        d = sensors._yaw_rotate(jnp.asarray(sensors.camera_rays(cfg, cfg.width, cfg.height)), p[2])
        hit = cast(rs, o, d, cfg.max_range)
        depth = jnp.where(hit.label == -3, cfg.max_range, hit.dist * (d @ axis))
        return depth.reshape(cfg.height, cfg.width), hit.label.reshape(cfg.height, cfg.width)

    ref_depth, ref_label = jax.jit(jax.vmap(plain))(poses)
    depth, label = jax.jit(jax.vmap(lambda p: sensors.depth_seg(rs, replace(cfg, cull=0), p)))(poses)
    np.testing.assert_array_equal(np.asarray(label), np.asarray(ref_label))
    np.testing.assert_allclose(np.asarray(depth), np.asarray(ref_depth), rtol=1e-4, atol=1e-4)
    _, culled = jax.jit(jax.vmap(lambda p: sensors.depth_seg(rs, cfg, p)))(poses)
    wrong = np.mean(np.asarray(culled) != np.asarray(ref_label))
    if w.scene.num_boxes <= cfg.cull:
        assert wrong == 0.0
    assert wrong <= 0.002


def test_boxes_per_scan_step_change_no_hit(monkeypatch):
    """Casting 16, 4 (the default) or 1 box per scan step gives every hit the same, bitwise,
    for both kernels; a value that does not divide a chunk is one line naming the variable."""
    from rosmeery_jax.apps.bench import random_targets
    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.raycast import kernel, sensors
    w = load_world("kitchen")
    rs = ray_scene(w.scene)
    cfg = sensors.CameraConfig()
    poses = jnp.asarray(random_targets(w, 8, seed=5))

    def hits(per_step):
        def one(p):
            o, _ = sensors.camera_pose(cfg, p)
            d = sensors._yaw_rotate(jnp.asarray(sensors.camera_rays(cfg, cfg.width, cfg.height)), p[2])
            return (kernel.cast(rs, o, d, cfg.max_range, boxes_per_step=per_step),
                    kernel.cast_columns(rs, o, d.reshape(cfg.height, cfg.width, 3), cfg.max_range,
                                         boxes_per_step=per_step))
        return jax.tree.map(np.asarray, jax.jit(jax.vmap(one))(poses))

    ref = hits(16)
    assert (ref[0].label >= 0).mean() > 0.2  # objects in view: the comparison is not vacuous
    for per_step in (4, 1):
        jax.tree.map(np.testing.assert_array_equal, hits(per_step), ref)
    monkeypatch.setenv("ROSMEERY_RAYCAST_UNROLL", "3")
    with pytest.raises(InputError, match=r"ROSMEERY_RAYCAST_UNROLL.*'3' is not a divisor of 16"):
        kernel.unroll()


def test_wide_vectors_change_no_sensor_or_coverage_value():
    """``rosmeery_jax.core.xla`` lets LLVM use 512-bit vectors as a speed choice: the laser, the
    depth and label images and the coverage counts are bitwise those of XLA's default."""
    from rosmeery_jax.apps.bench import random_targets
    from rosmeery_jax.raycast import sensors

    env = _env("target")
    poses = jnp.asarray(random_targets(env.world, 16, seed=5))
    knowledge = jax.vmap(lambda _: env.sk.init())(poses)

    def sense(p, k):
        ranges, labels = sensors.laser(env.laser_rays, env.config.laser, p)
        depth, seg = sensors.depth_seg(env.rays, env.config.camera, p)
        return ranges, labels, depth, seg, env.sk.observe(k, p, depth)

    plain = jax.jit(jax.vmap(sense))(poses, knowledge)
    wide = jax.jit(jax.vmap(sense), compiler_options={"xla_cpu_prefer_vector_width": 512})(poses, knowledge)
    for a, b in zip(jax.tree.leaves(plain), jax.tree.leaves(wide)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert (np.asarray(plain[3]) >= 0).mean() > 0.2  # not vacuous: the camera sees objects


@functools.lru_cache(maxsize=None)
def _env(mode):
    return make("small_office", action_mode=mode)


@functools.lru_cache(maxsize=None)
def _rollout(mode, steps, optimized=False):
    """jit(vmap) rollout of ``steps`` steps: (keys (B,), actions (steps, B, A)) -> poses, final
    state; ``optimized``: compiled with XLA's optimisations (conftest.OPTIMIZED), for long runs."""
    env = _env(mode)

    def run(keys, actions):
        s = jax.vmap(env.reset)(keys)

        def body(s, a):
            s = jax.vmap(env.step)(s, a)
            return s, s.pose

        return jax.lax.scan(body, s, actions)

    return jax.jit(run, compiler_options=OPTIMIZED if optimized else None)


def test_materialized_changes_no_value():
    from rosmeery_jax.raycast.kernel import materialized

    x = jnp.array([0.0, -0.0, 8.0, 1e-30, -3e38, np.finfo(np.float32).min, np.inf, 7.5], jnp.float32)
    np.testing.assert_array_equal(np.asarray(jax.jit(materialized)(x)), np.asarray(x))
    assert materialized(x.reshape(2, 4)).shape == (2, 4)
    assert materialized(jnp.array([-np.inf]))[0] == np.finfo(np.float32).min  # the one value it moves


def test_robot_stays_out_of_solids_for_10000_random_steps():
    env = _env("velocity")
    b, t = 16, 625
    keys = jax.random.split(jax.random.PRNGKey(0), b)
    lo, hi = jnp.array([-0.3, -3.0]), jnp.array([1.0, 3.0])
    # Hold each random command for 1 s so robots build speed and really hit things.
    cmds = jax.random.uniform(jax.random.PRNGKey(1), (t // 10 + 1, b, 2), minval=lo, maxval=hi)
    actions = jnp.repeat(cmds, 10, axis=0)[:t]
    final, poses = _rollout("velocity", t, optimized=True)(keys, actions)
    poses = np.asarray(poses)
    assert np.isfinite(poses).all()
    assert penetration(env.world, env.config.robot, poses).max() < 0.005
    assert np.abs(poses[-1, :, :2] - poses[0, :, :2]).max() > 0.5, "robots moved"


def test_nearest_proxies_step_as_the_whole_model():
    """MJX holds only the 16 proxies nearest at each control step's start: bitwise the same
    physics as the whole model while robots drive into walls and furniture."""
    near, whole = make("small_office"), make("small_office", robot__near_proxies=0)
    assert near.near_model is not None and near.near_model.ngeom == 17 and whole.near_model is None
    b, t = 16, 200
    cmds = jax.random.uniform(jax.random.PRNGKey(3), (t // 10, b, 2), minval=jnp.array([-0.3, -3.0]),
                              maxval=jnp.array([1.0, 3.0]))
    actions = jnp.repeat(cmds, 10, axis=0)  # held for 1 s, so robots build speed and hit things

    def poses(env):
        keys = jax.random.split(jax.random.PRNGKey(2), b)

        def run(d, actions):
            def body(d, a):
                d = jax.vmap(env.platform.step)(d, a)
                return d, jax.vmap(env.platform.pose)(d)

            return jax.lax.scan(body, d, actions)[1]

        return np.asarray(jax.jit(lambda k, a: run(jax.vmap(env.reset)(k).physics, a))(keys, actions))

    a = poses(near)
    np.testing.assert_array_equal(a, poses(whole))
    touching = replace(near.config.robot, radius=near.config.robot.radius + near.config.robot.skin + 0.005)
    assert (penetration(near.world, touching, a) > 0).sum() > 100, "robots were in contact with solids"
    # Which proxies: the 16 smallest centre distances less bounding radius, in model order.
    m, pos = near.model, np.asarray(near.model.geom_pos)
    for xy in ([2.0, 1.5], [0.5, 3.0]):  # no tie at the 16th
        order = np.argsort(np.linalg.norm(pos[:-1, :2] - xy, axis=1) - np.asarray(m.geom_rbound)[:-1])
        kept = np.asarray(near.platform.nearby(jnp.array(xy + [0.3])).geom_pos)
        np.testing.assert_array_equal(kept, pos[np.append(np.sort(order[:16]), m.ngeom - 1)])


def test_too_few_nearest_proxies_is_refused():
    from rosmeery_jax.core.errors import InputError

    with pytest.raises(InputError, match="robot__near_proxies.*at least robot__max_pairs"):
        make("small_office", robot__near_proxies=4)


@pytest.mark.parametrize("mode, good, bad", [("target", (3,), [(1,), (), (1, 3), (2,)]),
                                             ("velocity", (2,), [(3,), (1,), ()])])
def test_an_action_of_another_shape_is_refused_when_traced(mode, good, bad):
    """A (1,) or scalar target broadcast over the pose, and a (3,) velocity ran on its first
    two values: refused by the step's trace, under jit and vmap alike (no run-time cost)."""
    env = make("kitchen", action_mode=mode)
    state = jax.eval_shape(env.reset, jax.random.key(0))
    assert jax.eval_shape(env.step, state, jnp.zeros(good)).pose.shape == (3,)
    for shape in bad:
        with pytest.raises(TypeError, match=rf"'{mode}' action is .*shape {re.escape(str(good))} per env .*not "
                                            rf"{re.escape(str(shape))}"):
            jax.eval_shape(env.step, state, jnp.zeros(shape))
    with pytest.raises(TypeError, match="not None"):
        jax.eval_shape(env.step, state, None)
    batch = jax.tree.map(lambda a: jax.ShapeDtypeStruct((4, *a.shape), a.dtype), state)
    with pytest.raises(TypeError, match=r"not \(4,"):  # a batch's actions stepped without vmap
        jax.eval_shape(env.step, state, jnp.zeros((4, *good)))
    assert jax.eval_shape(jax.vmap(env.step), batch, jnp.zeros((4, *good))).pose.shape == (4, 3)


def test_same_key_same_trajectory_and_no_recompile():
    keys = jax.random.split(jax.random.PRNGKey(7), 2)
    actions = jnp.tile(jnp.array([[0.6, 0.8]]), (30, 2, 1))
    run = _rollout("velocity", 30)
    a = np.asarray(run(keys, actions)[1])
    b = np.asarray(run(keys, actions)[1])
    np.testing.assert_array_equal(a, b)
    assert run._cache_size() == 1
    other = np.asarray(run(jax.random.split(jax.random.PRNGKey(8), 2), actions)[1])
    assert not np.allclose(other, a)  # another key: another start heading, another path


def test_navigation_reaches_free_target_and_reports_unreachable():
    env = _env("target")
    # Robot 0: a free spot across the room; robot 1: inside the north wall, which its laser sees.
    targets = jnp.array([[2.6, -0.1, 1.57], [3.0, 1.06, 0.0]])
    final, poses = _rollout("target", 120)(jax.random.split(jax.random.PRNGKey(0), 2), jnp.tile(targets, (120, 1, 1)))
    status = [STATUS_NAMES[s] for s in np.asarray(final.nav.status)]
    assert status[0] == "reached", status
    assert np.linalg.norm(np.asarray(final.pose[0, :2]) - [2.6, -0.1]) < env.config.nav.goal_tolerance + 0.02
    assert status[1] == "unreachable", status
    # Not looped on: the robot stopped once the target was declared unreachable.
    p = np.asarray(poses[:, 1])
    assert np.abs(p[-1] - p[-10]).max() < 1e-3


def test_navigation_sweep_is_the_eight_neighbour_bellman_update():
    """Each sweep is the Bellman update over the 8-neighbourhood, bitwise: a cell's new
    cost-to-go is min over neighbours of (neighbour + its own step cost, x sqrt 2 on
    diagonals); blocked cells and cells off the world's extent stay BIG; the goal is 0."""
    from rosmeery_jax.sim.navigation import BIG

    nav = _env("target").navigator
    hc, wc = nav.coarse_shape
    rng = np.random.default_rng(0)
    field = rng.uniform(0, 300, (hc, wc)).astype(np.float32)
    field[rng.random((hc, wc)) < 0.3] = BIG
    blocked = rng.random((hc, wc)) < 0.1
    cost = (1.0 + 4.0 * (rng.random((hc, wc)) < 0.2)).astype(np.float32)
    goal = (hc // 2, wc // 3)
    got = np.asarray(jax.jit(lambda f: nav.sweep(f, jnp.asarray(blocked), jnp.asarray(cost), goal))(field))

    want = field
    for _ in range(nav.cfg.sweeps):
        p = np.pad(want, 1, constant_values=BIG)
        best = np.full_like(want, BIG)
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                if di or dj:
                    step = cost * np.float32(1.41421356 if di and dj else 1.0)
                    best = np.minimum(best, p[1 + di:1 + di + hc, 1 + dj:1 + dj + wc] + step)
        outside = ~np.asarray(nav.coarse.inside())
        want = np.where(blocked | outside, np.float32(BIG), np.minimum(best, np.float32(BIG)))
        want[goal] = 0.0
    assert got.dtype == np.float32 and np.array_equal(got, want)
    assert (got < BIG).sum() > 0.5 * hc * wc  # the case is not vacuous: most cells are reached


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 13), st.integers(1, 13), st.integers(1, 4), st.integers(0, 2 ** 31 - 1))
def test_block_any_and_grow_match_a_plain_reference(h, w, f, seed):
    """block_any: an f x f block is True when any of its cells is (the grid padded with False
    to whole blocks); grow: the 3 x 3 dilation (scipy's), cells off the grid counting as False."""
    from rosmeery_jax.core import grid

    mask = np.random.default_rng(seed).random((h, w)) < 0.15
    hc, wc = -(-h // f), -(-w // f)
    padded = np.zeros((hc * f, wc * f), bool)
    padded[:h, :w] = mask
    want = np.array([[padded[i * f:(i + 1) * f, j * f:(j + 1) * f].any() for j in range(wc)] for i in range(hc)])
    assert np.array_equal(np.asarray(grid.block_any(jnp.asarray(mask), f)), want.reshape(hc, wc))
    assert np.array_equal(np.asarray(grid.grow(jnp.asarray(mask))), ndimage.binary_dilation(mask, np.ones((3, 3), bool)))


def test_occupancy_map_marks_seen_walls_occupied_and_space_free():
    env = _env("velocity")
    # two robots, as the same-key test: one compiled rollout serves both
    final, _ = _rollout("velocity", 30)(jax.random.split(jax.random.PRNGKey(0), 2), jnp.tile(jnp.array([[0.0, 1.0]]), (30, 2, 1)))
    occ = np.asarray(env.occupancy(final))[0]
    w = env.world
    walls = rasterize(w.scene, w.scene.object_id == WALL, w.free_space.origin, occ.shape, w.free_space.resolution)
    marked = occ == occupancy.OCCUPIED
    assert marked.sum() > 50
    # Nearly every occupied cell is on or next to a real solid, and many wall cells were seen.
    truth = w.free_space.occupied
    near = ndimage.binary_dilation(truth, iterations=1)
    assert (marked & near).sum() / marked.sum() > 0.95
    assert (marked & ndimage.binary_dilation(walls, iterations=1)).sum() > 30
    # No cell inside a solid cut by the laser's plane is marked free.
    z = env.config.laser.height
    s = w.scene
    at_laser = (s.center[:, 2] - s.half[:, 2] < z) & (s.center[:, 2] + s.half[:, 2] > z)
    solid = rasterize(s, at_laser, w.free_space.origin, occ.shape, w.free_space.resolution)
    free = occ == occupancy.FREE
    # (beyond one cell: a beam may graze through the 1 cm gap left between a desk and a wall)
    assert free.sum() > 200 and not (free & ndimage.binary_erosion(solid, iterations=2)).any()


def test_hit_normals_labels_and_distances_by_hand():
    """One box turned 30 degrees (centre (2, 0, 0.5), half 0.5) and the floor: the face a ray
    enters gives the normal, turned with the box; the floor's is +z; a miss has none."""
    from rosmeery_jax.raycast.kernel import RayScene
    from rosmeery_jax.world.scene import FLOOR, NOTHING

    yaw = np.pi / 6
    far = np.full((15, 3), 1e6)
    rs = RayScene(jnp.asarray(np.vstack([[2.0, 0.0, 0.5], far]), jnp.float32), jnp.full((16, 3), 0.5, jnp.float32),
                  jnp.asarray([np.cos(yaw)] + [1.0] * 15, jnp.float32), jnp.asarray([np.sin(yaw)] + [0.0] * 15, jnp.float32),
                  jnp.asarray([7] + [NOTHING] * 15, jnp.int32), jnp.zeros((16, 3), jnp.float32), jnp.zeros(3, jnp.float32))
    origins = jnp.asarray([[0.0, 0.0, 0.5], [2.0, 0.0, 3.0], [0.0, 3.0, 0.5], [0.0, 0.0, 0.5]], jnp.float32)
    dirs = jnp.asarray([[[1.0, 0.0, 0.0]], [[0.0, 0.0, -1.0]], [[0.0, 0.0, -1.0]], [[-1.0, 0.0, 0.0]]], jnp.float32)
    hit = jax.jit(lambda o, d: cast(rs, o, d, 8.0))(origins, dirs)
    c, s = np.cos(yaw), np.sin(yaw)
    t0 = (2.0 * c - 0.5) / c  # local x of the origin is -2 cos(yaw); the ray's local x speed is cos(yaw)
    np.testing.assert_allclose(np.asarray(hit.dist[:, 0]), [t0, 2.0, 0.5, 8.0], rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(hit.label[:, 0]), [7, 7, FLOOR, NOTHING])
    np.testing.assert_array_equal(np.asarray(hit.box[:, 0]), [0, 0, -1, -1])
    np.testing.assert_allclose(np.asarray(hit.normal[:, 0]), [[-c, -s, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0],
                                                              [0.0, 0.0, 0.0]], atol=1e-6)
