"""The perceived mapper: depth inside detector boxes, association by overlap, no ground truth."""

from __future__ import annotations

from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import room_xml
from hypothesis import given, settings
from hypothesis import strategies as st

from rosmeery_jax import metrics
from rosmeery_jax.detector.dataset import visible_boxes
from rosmeery_jax.env import make
from rosmeery_jax.mapping import perceived
from rosmeery_jax.mapping.kernels import HashTable
from rosmeery_jax.mapping.perceived import PerceivedConfig, PerceivedMapper
from rosmeery_jax.mapping.protocol import Camera, DepthFrame, OnlineScorer
from rosmeery_jax.mapping.voxel_table import Rows, cube_keys, first_of_lowest_rank
from rosmeery_jax.metrics.map_file import build_map, write_map
from rosmeery_jax.metrics.map_score import read_map, score, tie
from rosmeery_jax.raycast.sensors import rgbd
from rosmeery_jax.sim.knowledge import GroundTruthTable
from rosmeery_jax.world.taxonomy import load_taxonomy

# Apart: a chair (0.4 m cube) and a desk (0.6 m cube) 2 m apart; together: the same two
# touching, side by side at the same distance from the camera.
APART = """
<body name="chair"><geom type="box" pos="-1 0 0.2" size="0.2 0.2 0.2"/></body>
<body name="desk"><geom type="box" pos="1 0 0.3" size="0.3 0.3 0.3"/></body>
"""
TOGETHER = """
<body name="chair"><geom type="box" pos="-0.2 0 0.2" size="0.2 0.2 0.2"/></body>
<body name="desk"><geom type="box" pos="0.3 0.1 0.3" size="0.3 0.3 0.3"/></body>
"""
# By the wall: a chair 0.3 m in front of the room's far wall (y = -2), 3 m from the camera.
BY_WALL = """
<body name="chair"><geom type="box" pos="0 -1.5 0.3" size="0.2 0.2 0.3"/></body>
"""
# The same, the chair's faces off the mappers' 5 cm cell boundaries (a face on a boundary
# puts its points in either layer of cells, a frame's worth of rounding apart).
OFF_GRID = """
<body name="chair"><geom type="box" pos="0.013 -1.487 0.3" size="0.2 0.2 0.3"/></body>
"""
# Flush: a chair against the left wall, seen from 1 m to its right: its front face runs into
# the wall with no depth discontinuity, so the chair and the walls are one depth segment.
FLUSH = """
<body name="chair"><geom type="box" pos="-1.8 -1.0 0.3" size="0.2 0.2 0.3"/></body>
"""
# Frame: a "chair" of four 2 cm bars, 1 m square, 1.2 m in front of the camera and 2.4 m in
# front of the far wall: the wall seen through it fills most of its box.
FRAME = """
<body name="chair">
  <geom type="box" pos="-0.49 0.4 0.55" size="0.01 0.01 0.5"/><geom type="box" pos="0.49 0.4 0.55" size="0.01 0.01 0.5"/>
  <geom type="box" pos="0 0.4 1.04" size="0.5 0.01 0.01"/><geom type="box" pos="0 0.4 0.06" size="0.5 0.01 0.01"/>
</body>
"""
# Parts: a "chair" of a low front block and a tall back 0.25 m behind its front face, a
# depth step between them (two depth segments of one object).
PARTS = """
<body name="chair">
  <geom type="box" pos="0 0.05 0.2" size="0.2 0.05 0.2"/><geom type="box" pos="0 -0.2 0.45" size="0.2 0.05 0.45"/>
</body>
"""
# Beside: a chair and a smaller chair 0.15 m to its right, 0.1 m further back.
BESIDE = """
<body name="chair"><geom type="box" pos="-0.25 0 0.2" size="0.2 0.2 0.2"/></body>
<body name="small_chair"><geom type="box" pos="0.2 0 0.1" size="0.1 0.1 0.1"/></body>
"""
POSE = np.array([0.0, 1.6, -np.pi / 2], np.float32)  # looking down -y at both objects
ONE = PerceivedConfig(min_views=1, min_conf=0.0)  # instances in the map from the first detection, however sure


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """{name: (env, render(pose) -> depth, labels)}, one compile each."""
    out = {}
    for name, bodies, height in (("apart", APART, 2), ("together", TOGETHER, 2), ("by_wall", BY_WALL, 2),
                                 ("off_grid", OFF_GRID, 2), ("flush", FLUSH, 2), ("frame", FRAME, 2),
                                 ("flush_tall", FLUSH, 3), ("parts", PARTS, 2), ("beside", BESIDE, 2)):
        path = tmp_path_factory.mktemp(name) / "room.xml"
        cats = {"chair": "chair", "desk": "desk", "small_chair": "chair"}
        cats = {b: c for b, c in cats.items() if f'name="{b}"' in bodies}
        path.write_text(room_xml(bodies, cats, spawn=(0.0, 1.0, 0.0), height=height))
        env = make(str(path), camera__hfov=float(np.deg2rad(90)))
        render = jax.jit(lambda pose, env=env: rgbd(env.rays, env.config.camera, pose)[1:])
        out[name] = env, render
    return out


def _frame(scenes, name, pose=POSE):
    env, render = scenes[name]
    depth, label = (np.asarray(a) for a in render(jnp.asarray(pose)))
    return env, depth, label


def _ori(env, log):
    t = env.world.truth
    table = GroundTruthTable(np.asarray(t.ps_G), np.asarray(t.num_predicates), np.asarray(t.category_index))
    return {k: float(v) for k, v in metrics.compute(log, table).items()}


def _log(env, m):
    """The mapper's map now, scored (fields (N,))."""
    return OnlineScorer(env.world, 0.05).score(m.semantic_map()).log


def _spanning(boxes: np.ndarray) -> np.ndarray:
    """(1, 4) the one box spanning ``boxes`` (D, 4)."""
    return np.concatenate([boxes[:, :2].min(0), boxes[:, 2:].max(0)])[None]


def _tight(label):
    b = visible_boxes(label, 40)  # rows object, x1, y1, x2, y2, pixels
    return b[:, 0], b[:, 1:5].astype(np.float32)


def test_tight_boxes_give_one_instance_per_object_and_points_only_on_objects(scenes, tmp_path):
    env, depth, label = _frame(scenes, "apart")
    obj, boxes = _tight(label)
    assert list(obj) == [0, 1]  # both objects in view
    m = PerceivedMapper(Camera.of(env.config.camera), cfg=ONE)
    assert list(_log(env, m).ps) == [0, 0]  # before the frame: nothing
    m.fold(POSE, depth, boxes, np.array([0, 4]), np.array([0.8, 0.6], np.float32))  # chair, desk (indices)
    categories = env.world.taxonomy.names
    assert categories[0] == "chair" and categories[4] == "desk"
    points, instance, _, _ = m.semantic_map()
    assert m.instances == 2 and set(instance) == {0, 1}
    assert points[:, 2].min() >= 0.03  # the floor is dropped
    log = _log(env, m)
    assert (log.ps > 0).all() and list(log.label) == [0, 4]
    np.testing.assert_allclose(log.conf_true, [0.8, 0.6])
    sc = score(env.world, _as_map(tmp_path, env, m))
    assert sc.off_object == 0.0 and list(sc.matched) == [0, 1]


NEAR = POSE + np.array([0.0, -0.3, 0.0], np.float32)  # 0.3 m closer to both objects


def test_two_boxes_of_one_frame_never_join_one_instance(scenes):
    env, _ = scenes["apart"]
    m = PerceivedMapper(Camera.of(env.config.camera))
    pts = np.stack(np.meshgrid(np.arange(10) * 0.025, np.arange(10) * 0.025, [0.5]), -1).reshape(-1, 3) + 0.01
    keys, cells = cube_keys(pts.T, 0.025), np.unique(cube_keys(pts.T, 0.05))  # a 25 cm patch: 100 voxels, 25 cells
    first = m._associate(cells, 0, set())
    m._claim(np.array([first]), keys, pts, cells)
    assert m._associate(cells, 0, set()) == first  # another frame's box on the patch joins it
    second = m._associate(cells, 0, {first})  # the same frame's second box on it: another object
    assert second != first and m._associate(cells, 0, set()) == first  # and the patch stays the first's


def test_a_detection_joins_an_instance_of_its_label_on_a_smaller_overlap(scenes):
    """A long object seen in parts: a box holding a few of an instance's cells joins it if
    the two carry one label (``same_overlap``), and starts an instance of its own if not
    (``overlap``)."""
    env, _ = scenes["apart"]
    cfg = PerceivedConfig(overlap=0.2, same_overlap=0.05)
    strip = np.stack(np.meshgrid(np.arange(40) * 0.05, [0.0], [0.5]), -1).reshape(-1, 3) + 0.01  # 2 m of 5 cm cells
    part, rest = strip[:10], strip[8:]  # the second box reaches 10 cm into the first part
    for label, joins in ((4, True), (0, False)):
        m = PerceivedMapper(Camera.of(env.config.camera), cfg=cfg)
        cells = np.unique(cube_keys(part.T, 0.05))
        first = m._associate(cells, 4, set())
        m._claim(np.array([first]), cube_keys(part.T, 0.025), part, cells)
        m.label[first] = 4  # a desk
        later = np.unique(cube_keys(rest.T, 0.05))
        held = (m.cells.get(later) == first).mean()  # its two cells and the neighbour's
        assert cfg.same_overlap <= held < cfg.overlap
        assert (m._associate(later, label, set()) == first) == joins


def _two_views(scenes):
    """The "apart" scene from POSE and from NEAR: env, depth, label, tight boxes, then the
    nearer view's depth and tight boxes."""
    env, depth, label = _frame(scenes, "apart")
    _, depth2, label2 = _frame(scenes, "apart", NEAR)
    return env, depth, label, _tight(label)[1], depth2, _tight(label2)[1]


def _as_map(tmp_path, env, m):
    points, instance, label, conf = m.semantic_map()
    names = [f"instance_{i}" for i in range(len(label))]
    ply, _ = write_map(tmp_path, "perceived", *build_map(env.world, points, instance, names, label, conf, 1.0))
    return read_map(ply, env.world.taxonomy)


def test_a_second_view_joins_the_same_instance_and_a_more_confident_label_replaces_the_first(scenes, tmp_path):
    env, depth, label, boxes, depth2, boxes2 = _two_views(scenes)
    m = PerceivedMapper(Camera.of(env.config.camera), cfg=ONE)
    m.fold(POSE, depth, boxes[:1], np.array([3]), np.array([0.5], np.float32))  # the chair, mislabelled
    first = _log(env, m)
    m.fold(NEAR, depth2, boxes2[:1], np.array([0]), np.array([0.9], np.float32))  # seen again, right label
    assert m.instances == 1
    second = _log(env, m)
    assert first.label[0] == 3 and first.conf_true[0] == 0.0  # after frame 0: wrong label, no cORI
    assert second.label[0] == 0 and second.conf_true[0] == pytest.approx(0.9)
    assert second.ps[0] >= first.ps[0] > 0  # the nearer view adds samples, never removes
    assert _ori(env, second)["cori"] > 0


def test_one_box_over_two_touching_objects_merges_them_and_loses_the_smaller(scenes, tmp_path):
    env, depth, label = _frame(scenes, "together")
    obj, boxes = _tight(label)
    assert list(obj) == [0, 1]
    union = _spanning(boxes)
    merged = PerceivedMapper(Camera.of(env.config.camera), cfg=ONE)
    merged.fold(POSE, depth, union, np.array([4]), np.array([0.9], np.float32))
    separate = PerceivedMapper(Camera.of(env.config.camera), cfg=ONE)
    separate.fold(POSE, depth, boxes, np.array([0, 4]), np.array([0.9, 0.9], np.float32))
    lm, ls = (_log(env, m) for m in (merged, separate))
    assert merged.instances == 1 and separate.instances == 2
    assert lm.ps[0] == 0 and lm.ps[1] == ls.ps[1] > 0  # the desk keeps its samples, the chair has none
    assert _ori(env, lm)["ori"] < _ori(env, ls)["ori"]


def test_padding_and_empty_boxes_add_nothing(scenes, tmp_path):
    env, depth, _ = _frame(scenes, "apart")
    m = PerceivedMapper(Camera.of(env.config.camera))
    m.fold(POSE, depth, np.zeros((3, 4), np.float32), np.array([-1, -1, 2]), np.zeros(3, np.float32))
    assert m.instances == 0 and len(m.semantic_map().points) == 0
    log = _log(env, m)
    assert log.ps.shape == (2,) and not log.ps.any() and (log.label == -1).all()


def test_a_repeated_frame_reuses_its_voxels_and_builds_the_same_map(scenes, monkeypatch):
    env, depth, label, boxes, depth2, boxes2 = _two_views(scenes)
    obj = _tight(label)[0]
    moved = depth.copy()
    moved[label == obj[0]] += 0.01  # one object 1 cm further: a different frame
    frames = [(POSE, depth, boxes), (POSE, depth, boxes), (POSE, moved, boxes), (POSE, moved, boxes),
              (NEAR, depth2, boxes2), (POSE, depth, boxes)]
    calls = []
    points = perceived.boxes_pass  # once per frame it does not reuse
    monkeypatch.setattr(perceived, "boxes_pass", lambda *a: calls.append(1) or points(*a))

    def build(memo: bool) -> PerceivedMapper:
        m = PerceivedMapper(Camera.of(env.config.camera))
        for f, (pose, d, b) in enumerate(frames):
            if not memo:
                m._last = None
            m.fold(pose, d, b, np.array([0, 4])[: len(b)], np.array([0.8, 0.6], np.float32)[: len(b)])
        return m

    kept, plain = build(True), build(False)
    assert len(boxes) == len(boxes2) == 2
    assert len(calls) == 4 + 6  # with the memory: A, moved, the nearer view, A again; without: all 6
    for a, b in zip(kept.semantic_map(), plain.semantic_map()):
        np.testing.assert_array_equal(a, b)
    assert kept.instances == plain.instances == 2


def test_perceived_needs_a_detector(tmp_path, capsys):
    from rosmeery_jax.apps.cli import main

    assert main(["run", "--worlds", "small_office", "--detector", "off", "--mapper", "perceived",
                 "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mappers" in err[0] and not (tmp_path / "o").exists()
    assert main(["run", "--worlds", "small_office", "--detector", "oracle", "--mapper", "oracle,ideal",
                 "--out", str(tmp_path / "o")]) == 2
    assert "'ideal' is not a mapper" in capsys.readouterr().err


def test_the_frames_intrinsics_and_camera_pose_put_pixels_on_their_object(scenes):
    """The mapper protocol's camera (OpenCV K and world-from-camera pose): a pixel of an
    object, back-projected with its depth, lies on that object's surface samples."""
    env, depth, label = _frame(scenes, "apart")
    cam = Camera.of(env.config.camera)
    v, u = np.nonzero((label >= 0) & (depth > 0))
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(cam.intrinsics).T
    pose = cam.pose(POSE)
    points = (rays * depth[v, u][:, None]) @ pose[:3, :3].T + pose[:3, 3]
    sample = tie(env.world, points, 0.05)
    obj = np.asarray(env.world.truth.samples.object)
    assert len(points) > 100 and (sample >= 0).mean() > 0.95
    assert (obj[sample[sample >= 0]] == label[v, u][sample >= 0]).mean() > 0.95


def _grown(boxes: np.ndarray, px: float, shape) -> np.ndarray:
    """Boxes px pixels wider on every side (a detector's loose boxes), clipped to the frame."""
    h, w = shape
    return np.clip(boxes + np.array([-px, -px, px, px], np.float32), 0, [w, h, w, h]).astype(np.float32)


def test_two_touching_objects_with_overlapping_boxes_stay_two_instances(scenes, tmp_path):
    env, depth, label = _frame(scenes, "together")
    obj, boxes = _tight(label)
    loose = _grown(boxes, 6, depth.shape)
    assert loose[0, 2] > loose[1, 0]  # the two boxes overlap
    m = PerceivedMapper(Camera.of(env.config.camera), cfg=ONE)
    m.fold(POSE, depth, loose, np.array([0, 4]), np.array([0.8, 0.7], np.float32))
    sc = score(env.world, _as_map(tmp_path, env, m))
    assert m.instances == 2 and list(sc.matched) == [0, 1] and sc.unmatched == 0
    assert sc.off_object == 0.0  # the floor and the wall behind are cut away
    sample = tie(env.world, m.semantic_map().points, 0.05)
    owner = np.asarray(env.world.truth.samples.object)[sample]
    assert (owner == m.semantic_map().instance).all()  # every point lies on its own instance's object


def test_a_boxs_segments_just_behind_its_object_are_its_parts(scenes, tmp_path):
    """The object's back, cut off by a depth step, joins its front: rule 2's parts."""
    env, depth, label = _frame(scenes, "parts")
    _, boxes = _tight(label)
    maps = {}
    for name, cfg in (("parts", ONE), ("front only", replace(ONE, part_share=np.inf))):
        m = PerceivedMapper(Camera.of(env.config.camera), cfg=cfg)
        m.fold(POSE, depth, boxes, np.array([0]), np.array([0.9], np.float32))
        maps[name] = m.semantic_map().points, score(env.world, _as_map(tmp_path / name, env, m))
    (parts, kept), (front, alone) = maps["parts"], maps["front only"]
    assert front[:, 2].max() < 0.45 < parts[:, 2].max()  # the back stands above the front block
    assert kept.off_object == alone.off_object == 0.0 and list(kept.matched) == list(alone.matched) == [0]
    assert kept.log.ps[0] > 1.5 * alone.log.ps[0]


def test_a_neighbour_inside_the_box_gives_points_but_never_merges(scenes, tmp_path):
    """A box over a chair also holds a smaller chair beside it, just behind: the box's points
    include the small chair's (a part, by depth), but the box joins the instance its own
    object's segment leads to, so the two instances stay two."""
    env, depth, label = _frame(scenes, "beside")
    obj, boxes = _tight(label)
    assert list(obj) == [0, 1]
    m = PerceivedMapper(Camera.of(env.config.camera), cfg=ONE)
    m.fold(POSE, depth, boxes[1:], np.array([0]), np.array([0.9], np.float32))  # the small chair alone
    both = _spanning(boxes)  # a loose box, both chairs
    m.fold(POSE, depth, both, np.array([0]), np.array([0.9], np.float32))
    sc = score(env.world, _as_map(tmp_path, env, m))
    assert m.instances == 2 and sorted(sc.matched) == [0, 1] and sc.unmatched == 0
    state = m.semantic_map()
    owner = np.asarray(env.world.truth.samples.object)[tie(env.world, state.points, 0.05)]
    assert (owner >= 0).all() and len(np.unique(state.instance[owner == 0])) == 1  # each chair in one instance


def test_a_boxs_wall_pixels_are_not_kept(scenes, tmp_path):
    env, depth, label = _frame(scenes, "by_wall")
    obj, boxes = _tight(label)
    loose = _grown(boxes, 4, depth.shape)  # much of the box is the wall 0.3 m behind the chair
    inside = np.zeros(depth.shape, bool)
    x1, y1, x2, y2 = loose[0].astype(int)
    inside[y1:y2, x1:x2] = True
    assert (inside & (label < 0) & (depth > 0)).sum() > (inside & (label == 0)).sum()  # more wall than chair
    kept = {}
    for name, cfg in (("segments", ONE), ("no cut", replace(ONE, edge_abs=10.0, inside=0.0))):
        m = PerceivedMapper(Camera.of(env.config.camera), cfg=cfg)
        m.fold(POSE, depth, loose, np.array([0]), np.array([0.9], np.float32))
        kept[name] = score(env.world, _as_map(tmp_path / name, env, m))
    assert kept["segments"].off_object == 0.0 and list(kept["segments"].matched) == [0]
    assert kept["no cut"].off_object > 0.3  # without the depth-discontinuity cut the wall is kept


def test_a_wall_seen_through_a_thin_object_is_not_taken_for_it(scenes, tmp_path):
    env, depth, label = _frame(scenes, "frame")
    obj, boxes = _tight(label)
    x1, y1, x2, y2 = boxes[0].astype(int)
    box = np.s_[y1:y2, x1:x2]
    frame_share = (label[box] == 0).sum() / (depth[box] > 0).sum()
    assert 0.05 < frame_share < 0.2  # the bars hold too little of their box's pixels to be the object for sure
    kept = {}
    for name, behind in (("default", PerceivedConfig().behind), ("off", np.inf)):
        m = PerceivedMapper(Camera.of(env.config.camera), cfg=replace(ONE, behind=behind))
        m.fold(POSE, depth, boxes, np.array([0]), np.array([0.9], np.float32))
        kept[name] = m.semantic_map().points
    assert len(kept["default"]) == 0  # the wall behind the bars is background: the detection adds nothing
    assert len(kept["off"]) > 100 and (tie(env.world, kept["off"], 0.05) < 0).mean() > 0.9  # else the wall is kept


def test_a_wall_seen_above_every_object_is_cut_from_the_chair_against_it(scenes, tmp_path):
    """The flush chair in a room of 3 m walls: the frame sees the walls above 2.2 m, so
    their cells are walls, and the chair is a segment of its own."""
    env, depth, label = _frame(scenes, "flush_tall")
    obj, boxes = _tight(label)
    kept = {}
    for name, above in (("walls", PerceivedConfig().wall_above), ("off", np.inf)):
        m = PerceivedMapper(Camera.of(env.config.camera), cfg=replace(ONE, wall_above=above))
        m.fold(POSE, depth, boxes, np.array([0]), np.array([0.9], np.float32))
        kept[name] = m.semantic_map().points
    assert len(kept["off"]) == 0  # one segment with the walls, running past the box: nothing
    assert len(kept["walls"]) > 100 and (tie(env.world, kept["walls"], 0.05) >= 0).all()  # the chair, no wall


def test_a_wall_cell_stays_a_wall_in_frames_that_see_it_only_low(scenes):
    env, _ = scenes["apart"]
    m = PerceivedMapper(Camera.of(env.config.camera))
    z = np.linspace(0.1, 2.5, 25)
    column = (np.full(25, 1.03), np.full(25, 0.03), z)  # a wall's column, 2.5 m high
    low = (np.full(5, 0.03), np.full(5, 0.03), np.full(5, 0.5))  # a chair's points 1 m away
    assert not m._off_walls(*column).any() and m._off_walls(*low).all()
    later = (np.full(3, 1.07), np.full(3, 0.07), np.full(3, 0.4))  # the wall seen low, same 10 cm cell
    assert not m._off_walls(*later).any()
    assert PerceivedMapper(Camera.of(env.config.camera))._off_walls(*later).all()  # without the first view: kept


def test_a_wall_found_later_takes_its_points_out_of_the_map(scenes):
    """A box on a wall seen only low put the wall's points in the map; once a later frame
    sees that wall above ``wall_above``, its cells' points leave the map, whether already in
    it or still waiting for confirmation, and the scorer scores what is left."""
    env, _ = scenes["apart"]
    m = PerceivedMapper(Camera.of(env.config.camera), cfg=ONE)
    scorer = OnlineScorer(env.world, 0.05)
    y, z = np.meshgrid(np.arange(20) * 0.025, np.arange(20) * 0.05 + 0.1)
    patch = np.stack([np.full(y.size, -1.97), y.ravel() + 0.01, z.ravel()], -1)  # 0.5 m of a wall, low
    cells = np.unique(cube_keys(patch.T, 0.05))
    first = m._associate(cells, 4, set())
    m.views[first] = 1
    m._claim(np.array([first]), cube_keys(patch.T, 0.025), patch, cells)
    before = m.semantic_map()
    assert len(before.points) == len(patch) and scorer.score(before).off_object == 1.0
    other = patch + [0, 0.6, 0]  # a second patch, further along the wall
    other_cells = np.unique(cube_keys(other.T, 0.05))
    unconfirmed = m._associate(other_cells, 4, set())
    m._claim(np.array([unconfirmed]), cube_keys(other.T, 0.025), other, other_cells)
    assert unconfirmed != first and len(m.pending[unconfirmed][0]) == len(other)
    high = patch[patch[:, 1] < 0.09][:1] + [0, 0, 2.3]  # the wall above 2.2 m, in the patch's first 10 cm cell
    m._off_walls(*high.T)
    after = m.semantic_map()
    gone = patch[:, 1] < 0.1
    np.testing.assert_array_equal(after.points, before.points[before.points[:, 1] >= 0.1])  # the rest stays, in order
    assert m.box[first][0, 1] >= 0.1 and m.count[first] == (~gone).sum()
    m.views[unconfirmed] = 1
    m._publish(unconfirmed)  # the second patch, confirmed now, loses nothing: its cells are no wall's
    assert len(m.semantic_map().points) == (~gone).sum() + len(patch)
    m._off_walls(*(high + [0, 0.6, 0]).T)  # the wall seen high in the second patch's first cell
    assert len(m.semantic_map().points) == 2 * (~gone).sum()
    np.testing.assert_equal(scorer.score(m.semantic_map()), OnlineScorer(env.world, 0.05).score(m.semantic_map()))


def test_an_instance_enters_the_map_on_its_second_detection(scenes):
    env, depth, label, boxes, depth2, boxes2 = _two_views(scenes)
    m = PerceivedMapper(Camera.of(env.config.camera))  # the default: two views confirm (under alone_conf)
    m.fold(POSE, depth, boxes[:1], np.array([0]), np.array([0.65], np.float32))
    assert m.instances == 0 and len(m.semantic_map().points) == 0
    m.fold(NEAR, depth2, boxes2[:1], np.array([0]), np.array([0.65], np.float32))
    first = m.semantic_map()
    assert m.instances == 1 and len(first.points) > 0 and set(first.instance) == {0}
    log = _log(env, m)
    assert log.ps[0] > 0 and log.ps[1] == 0


def test_one_very_confident_detection_brings_an_instance_in_alone(scenes):
    """Rule 6's ``alone_conf``: one box at 0.8 (default 0.7) confirms its instance with the
    points of that view; at 0.65 it does not, nor at 0.8 with the rule off."""
    env, depth, label, boxes, depth2, boxes2 = _two_views(scenes)
    cam = Camera.of(env.config.camera)
    for cfg, conf, entered in ((PerceivedConfig(), 0.8, True), (PerceivedConfig(), 0.65, False),
                               (PerceivedConfig(alone_conf=np.inf), 0.8, False)):
        m = PerceivedMapper(cam, cfg=cfg)
        m.fold(POSE, depth, boxes[:1], np.array([0]), np.array([conf], np.float32))
        assert m.instances == int(entered) and (len(m.semantic_map().points) > 0) == entered
    one = PerceivedMapper(cam, cfg=ONE)  # every detection confirms: the same points
    one.fold(POSE, depth, boxes[:1], np.array([0]), np.array([0.8], np.float32))
    sure = PerceivedMapper(cam)
    sure.fold(POSE, depth, boxes[:1], np.array([0]), np.array([0.8], np.float32))
    np.testing.assert_array_equal(np.sort(sure.semantic_map().points, 0), np.sort(one.semantic_map().points, 0))


def test_an_instance_needs_one_confident_detection_to_enter_the_map(scenes):
    """Rule 6's confidence: two detections at 0.5 (under the default 0.6) leave the instance
    out of the map; a third at 0.7 brings it in with every point its views gave."""
    env, depth, label, boxes, depth2, boxes2 = _two_views(scenes)
    m = PerceivedMapper(Camera.of(env.config.camera))
    for pose, d, b in ((POSE, depth, boxes), (NEAR, depth2, boxes2)):
        m.fold(pose, d, b[:1], np.array([0]), np.array([0.5], np.float32))
    assert m.instances == 0 and len(m.semantic_map().points) == 0
    unsure = PerceivedMapper(Camera.of(env.config.camera), cfg=PerceivedConfig(min_conf=0.0))
    for pose, d, b in ((POSE, depth, boxes), (NEAR, depth2, boxes2)):
        unsure.fold(pose, d, b[:1], np.array([0]), np.array([0.5], np.float32))
    m.fold(POSE, depth, boxes[:1], np.array([0]), np.array([0.7], np.float32))
    sure = m.semantic_map()
    assert m.instances == 1 and set(sure.instance) == {0} and sure.confidence[0] == np.float32(0.7)
    np.testing.assert_array_equal(np.sort(sure.points, 0), np.sort(unsure.semantic_map().points, 0))


def test_two_instances_of_one_object_merge_when_a_view_spans_both(scenes):
    """The desk's left and right thirds seen first as two instances; a box on the whole desk
    covers both: they merge into one, and the scorer counts their old points for the merged
    id."""
    env, depth, label = _frame(scenes, "apart")
    obj, boxes = _tight(label)
    desk = boxes[1]
    third = (desk[2] - desk[0]) / 3
    parts = np.array([[desk[0], desk[1], desk[0] + third, desk[3]], [desk[2] - third, desk[1], desk[2], desk[3]]],
                     np.float32)
    m = PerceivedMapper(Camera.of(env.config.camera), cfg=replace(ONE, inside=0.0))  # a part
    # box's segment runs on past it, into the rest of the desk
    scorer = OnlineScorer(env.world, 0.05)
    for part in parts:
        m.fold(POSE, depth, part[None], np.array([4]), np.array([0.7], np.float32))
    assert m.instances == 2
    split = scorer.score(m.semantic_map())
    m.fold(POSE, depth, desk[None], np.array([4]), np.array([0.8], np.float32))
    assert m.instances == 1
    whole = scorer.score(m.semantic_map())
    fresh = OnlineScorer(env.world, 0.05).score(m.semantic_map())
    assert whole.log.ps[1] > split.log.ps[1] and whole.unmatched == 0 < split.unmatched
    for a, b in zip(whole.log, fresh.log):  # incremental after a merge = from scratch
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


NONE = (np.zeros((0, 4), np.float32), np.zeros(0, np.int64), np.zeros(0, np.float32))  # a frame with no detection


def _part(box: np.ndarray, share: float) -> np.ndarray:
    """The left ``share`` of a box (a box that cuts its object short)."""
    return np.array([[box[0], box[1], box[0] + share * (box[2] - box[0]), box[3]]], np.float32)


def test_an_instance_grows_into_its_object_from_frames_without_its_box(scenes, tmp_path):
    """Rule 7: the chair, boxed only in part, then seen with no box from nearer: the frame
    segment it mostly holds grows it, and every point stays on the chair."""
    env, depth, label, boxes, depth2, _ = _two_views(scenes)
    maps = {}
    for grow in (0.5, 0.0):
        m = PerceivedMapper(Camera.of(env.config.camera), cfg=replace(ONE, grow=grow))
        m.fold(POSE, depth, _part(boxes[0], 0.7), np.array([0]), np.array([0.9], np.float32))
        before = _log(env, m).ps[0]
        m.fold(NEAR, depth2, *NONE)
        maps[grow] = m, before, score(env.world, _as_map(tmp_path / str(grow), env, m))
    (m, before, grown), (_, before0, plain) = maps[0.5], maps[0.0]
    assert plain.log.ps[0] == before0 > 0  # without growth the unboxed frame adds nothing
    assert before > before0  # the boxed frame's own segment already runs past the short box
    assert grown.log.ps[0] > before  # and the unboxed frame adds more of the chair
    assert m.instances == 1 and list(grown.matched) == [0, -1] and grown.off_object == 0.0


def test_an_instance_waiting_for_its_second_detection_grows_and_its_points_wait_with_it(scenes, tmp_path):
    """Rules 6-7: the chair boxed in part once (0.65: not confirmed), then seen with no box
    from nearer: nothing enters the map yet; once a second box confirms it, the map holds
    every point the unboxed frame grew it by, as a mapper confirming at once does, and every
    point stays on the chair."""
    env, depth, label, boxes, depth2, _ = _two_views(scenes)
    cam, short, chair, conf = Camera.of(env.config.camera), _part(boxes[0], 0.7), np.array([0]), np.array([0.65])
    waiting, at_once = PerceivedMapper(cam), PerceivedMapper(cam, cfg=ONE)  # two views confirm; one does
    for m in (waiting, at_once):
        m.fold(POSE, depth, short, chair, conf)
    seen = {tuple(p) for p in at_once.semantic_map().points}
    for m in (waiting, at_once):
        m.fold(NEAR, depth2, *NONE)
    assert waiting.instances == 0 and len(waiting.semantic_map().points) == 0
    grown = {tuple(p) for p in at_once.semantic_map().points} - seen
    waiting.fold(POSE, depth, short, chair, conf)  # the second box: confirmed
    assert waiting.instances == 1 and len(grown) > 0
    assert grown <= {tuple(p) for p in waiting.semantic_map().points}
    sc = score(env.world, _as_map(tmp_path, env, waiting))
    assert list(sc.matched) == [0, -1] and sc.off_object == 0.0


@pytest.mark.parametrize("scene", ["by_wall", "together", "flush"])
def test_growth_stops_at_the_wall_behind_and_the_object_beside(scenes, tmp_path, scene):
    """Rule 7 takes only segments the instance mostly holds, one cell beyond it per frame:
    unboxed frames never bring in the wall 0.3 m behind the chair (by_wall), the touching
    desk no box ever named (together), or the walls the chair stands flush against, one
    depth segment with it (flush; the box's own test is off, else the box keeps nothing)."""
    start = POSE + np.array([-1.0 if scene == "flush" else 0.0, 0.0, 0.0], np.float32)
    env, depth, label = _frame(scenes, scene, start)
    _, boxes = _tight(label)
    m = PerceivedMapper(Camera.of(env.config.camera), cfg=replace(ONE, inside=0.0))
    m.fold(start, depth, boxes[:1], np.array([0]), np.array([0.9], np.float32))
    boxed = score(env.world, _as_map(tmp_path / "boxed", env, m))
    for dx in (-0.2, -0.1, 0.1, 0.2):  # the robot sidesteps: each frame a new one, none with a box
        pose = start + np.array([dx, -0.1, 0.0], np.float32)
        m.fold(pose, _frame(scenes, scene, pose)[1], *NONE)
    sc = score(env.world, _as_map(tmp_path, env, m))
    assert sc.log.ps[0] >= boxed.log.ps[0] > 0
    assert sc.off_object <= boxed.off_object + 0.02 and sc.off_object < 0.1  # no wall joins
    assert list(sc.matched) == [0] + [-1] * (len(sc.matched) - 1)


_LOOK = {}  # env -> its depth camera, compiled once


def _sweep(env, pose, step):
    """The depth camera of one step at ``pose`` as the session sends it (no return: 0)."""
    look = _LOOK.setdefault(env, jax.jit(env.look))
    depth = np.asarray(look(jnp.asarray(pose))[0])
    return DepthFrame(step, step / 10, np.where(depth < env.config.camera.max_range, depth, 0.0), pose, None)


@pytest.mark.parametrize("scene", ["off_grid", "together", "flush"])
def test_depth_between_detector_frames_grows_the_object_and_nothing_else(scenes, tmp_path, scene, monkeypatch):
    """Rule 8: the chair, boxed only in part, then the 64 x 48 depth camera of the steps
    after, sidestepping: it grows on the chair and on nothing behind, beside or flush with
    it (flush: one depth segment with the walls, the box's own test off as in rule 7's
    test); with ``depth_every`` 0 the steps add nothing; a frame sent twice is kept once."""
    start = POSE + np.array([-1.0 if scene == "flush" else 0.0, 0.0, 0.0], np.float32)
    env, depth, label = _frame(scenes, scene, start)
    _, boxes = _tight(label)
    poses = [start + np.array([dx, -0.1, 0.0], np.float32) for dx in (-0.2, -0.1, 0.1, 0.2)]
    out = {}
    for every in (1, 0):
        cfg = replace(ONE, depth_every=every, inside=0.0 if scene == "flush" else 0.5)
        m = PerceivedMapper(Camera.of(env.config.camera), cfg=cfg)
        m.fold(start, depth, _part(boxes[0], 0.7), np.array([0]), np.array([0.9], np.float32))
        boxed = score(env.world, _as_map(tmp_path / f"boxed{every}", env, m))
        for step, pose in enumerate(poses, 1):
            m.add_depth(_sweep(env, pose, step))
        out[every] = m, boxed, score(env.world, _as_map(tmp_path / str(every), env, m))
    (m, boxed, swept), (_, boxed0, plain) = out[1], out[0]
    assert plain.log.ps[0] == boxed0.log.ps[0] == boxed.log.ps[0] > 0  # rule 8 off: the steps add nothing
    if scene != "flush":  # on: they add a tenth of what the box held at least
        assert swept.log.ps[0] > 1.1 * boxed.log.ps[0]
    assert swept.off_object <= boxed.off_object + 0.02 and swept.off_object < 0.1  # and no wall
    assert list(swept.matched) == [0] + [-1] * (len(swept.matched) - 1)  # nor the desk beside
    clouds = []
    monkeypatch.setattr(m, "_cloud", lambda *a: clouds.append(a) or PerceivedMapper._cloud(m, *a))
    m.add_depth(_sweep(env, poses[-1], len(poses) + 1))  # the robot at rest: the last frame again
    m.semantic_map()
    assert not clouds
    m.add_depth(_sweep(env, poses[0], len(poses) + 2))  # moved: folded
    m.semantic_map()
    assert len(clouds) == 1


def _creeping_chair(scenes, read_each: bool, margin: float = np.inf):
    """The chair standing flush with the walls (one depth segment with them), boxed in
    part, then 20 depth frames beside it at a share of 1 % (rule 7's ``grow``), the map
    read after each or not: (env, mapper, its map's points after the detection alone)."""
    start = POSE + np.array([-1.0, 0.0, 0.0], np.float32)
    env, depth, label = _frame(scenes, "flush", start)
    _, boxes = _tight(label)
    m = PerceivedMapper(Camera.of(env.config.camera), cfg=replace(ONE, inside=0.0, grow=0.01, grow_margin=margin))
    m.fold(start, depth, _part(boxes[0], 0.7), np.array([0]), np.array([0.9], np.float32))
    boxed = m.semantic_map().points
    for k in range(20):
        m.add_depth(_sweep(env, start + np.array([0.05 * (k % 5) - 0.1, -0.02 * k, 0.0], np.float32), k + 1))
        if read_each:
            m.semantic_map()
    return env, m, boxed


def test_the_depth_between_two_detector_frames_is_folded_together(scenes, tmp_path):
    """Rule 8 judges the depth frames between two detector frames together, against the map
    as it stood before them, so an instance grows by at most a cell beyond it per decision:
    at a share of 1 %, 20 depth frames beside a chair standing flush with the walls (one
    depth segment with them) take none of the walls folded together, and creep into them,
    a cell a frame, when the map is read after each (rule 7's margin off)."""
    off = {}
    for read_each in (False, True):
        env, m, _ = _creeping_chair(scenes, read_each)
        off[read_each] = score(env.world, _as_map(tmp_path / str(read_each), env, m)).off_object
    assert off[False] == 0.0 and off[True] > 0.05


def test_growth_stays_within_reach_of_what_the_detections_took(scenes, tmp_path):
    """Rule 7's margin: the same creeping chair (read after each depth frame) takes walls
    beyond its box with no margin; with a margin of 5 cm every point of its instance lies
    within 5 cm of the 3D box of the points its one detection took, and it holds fewer
    points off the chair."""
    out = {}
    for margin in (np.inf, 0.05):
        env, m, boxed = _creeping_chair(scenes, True, margin)
        points = m.semantic_map().points
        reach = np.maximum(boxed.min(0) - points, points - boxed.max(0)).max(-1)  # how far outside the box, per point
        out[margin] = reach.max(), score(env.world, _as_map(tmp_path / str(margin), env, m)).off_object
    assert out[np.inf][0] > 0.1 and out[np.inf][1] > 0.05  # without a margin it creeps along the walls
    assert out[0.05][0] <= 0.05 + 1e-6 and out[0.05][1] < out[np.inf][1]


def _patch(x: tuple, y: tuple, z: tuple) -> np.ndarray:
    """Points 2.5 cm apart filling x, y, z ranges (start, stop) (a flat range: one layer)."""
    axes = [np.arange(a, b + 1e-9, 0.025) if b > a else np.array([a]) for a, b in (x, y, z)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3) + 0.001


def _seen(m: PerceivedMapper, pts: np.ndarray, label: int) -> int:
    """Fold ``pts`` as one detection of ``label`` seen twice (confirmed); its instance."""
    cells = np.unique(cube_keys(pts.T, m.cfg.cell))
    inst = m._associate(cells, label, set())
    m._claim(np.array([inst]), cube_keys(pts.T, m.cfg.voxel), pts, cells)
    m.label[inst], m.conf[inst], m.views[inst] = label, np.float32(0.9), m.views[inst] + 2
    m._publish(inst)
    return inst


# a desk-like instance: two layers 1 m square, 0.4 m apart
DESK = np.r_[_patch((0.0, 1.0), (0.0, 1.0), (0.3, 0.3)), _patch((0.0, 1.0), (0.0, 1.0), (0.7, 0.7))]


@pytest.mark.parametrize("where, z, label, merged", [
    ((0.3, 0.55), 0.5, 4, True),  # a part of its label between its layers: part of it
    ((0.3, 0.55), 1.2, 4, True),  # above it: part of it too (judged in plan view)
    ((1.5, 1.75), 0.5, 4, False),  # the same beside it: another desk
    ((0.3, 0.55), 0.5, 0, False),  # a chair over its floor area: another object
])
def test_a_small_instance_over_a_larger_one_of_its_label_merges_into_it(scenes, where, z, label, merged):
    env, _ = scenes["apart"]
    m = PerceivedMapper(Camera.of(env.config.camera))
    desk = _seen(m, DESK, 4)
    m._absorb()
    part = _seen(m, _patch(where, where, (z, z)), label)  # 11 x 11 points, 5 cm cells away from both layers
    assert part != desk and m.instances == 2  # a detection of its own: a new instance
    m._absorb()
    assert m.instances == (1 if merged else 2)
    roots = m._roots()
    assert (roots[part] == desk) == merged
    points, instance, labels, _ = m.semantic_map()
    assert len(points) == len(DESK) + 121 and set(labels[np.unique(instance)]) == {4, label}


@pytest.mark.parametrize("under, over, where, merged", [
    ("chair", "monitor", (0.3, 0.55), True),  # a chair's back boxed as a monitor: part of the chair, still a chair
    ("chair", "monitor", (1.5, 1.75), False),  # beside the chair: a monitor of its own
    ("desk", "monitor", (0.3, 0.55), False),  # over a desk, on which monitors stand: a monitor of its own
    ("chair", "desk", (0.3, 0.55), False),  # a desk over a chair: the chair tucked under it
])
def test_a_thing_set_on_furniture_over_a_chair_is_a_part_of_it(scenes, under, over, where, merged):
    """Nothing is set on seating (``bare``): an instance labelled as a thing set on furniture
    (``placed``) mostly over a much larger chair's floor area is a part of it, and the chair
    keeps its label."""
    env, _ = scenes["apart"]
    names = tuple(load_taxonomy().names)
    m = PerceivedMapper(Camera.of(env.config.camera), names)
    whole = _seen(m, DESK, names.index(under))
    part = _seen(m, _patch(where, where, (0.9, 0.9)), names.index(over))
    m.conf[part] = np.float32(0.95)  # surer than the chair's 0.9: still not its label
    m._absorb()
    assert (m._roots()[part] == whole) == merged and m.instances == (1 if merged else 2)
    _, instance, labels, _ = m.semantic_map()
    held = {names[i] for i in labels[np.unique(instance)]}
    assert held == ({under} if merged else {under, over})


@pytest.mark.parametrize("x1, merged", [(0.70, True), (0.75, False)])
def test_a_part_merges_when_enough_of_its_points_lie_inside(scenes, x1, merged):
    """A strip of 20 x 5 points from x1 along x, past the desk's plan-view box widened to x = 1.101:
    17 of its 20 columns inside (85 %) from 0.70, 15 (75 %) from 0.75; 80 % needed."""
    env, _ = scenes["apart"]
    m = PerceivedMapper(Camera.of(env.config.camera))
    desk = _seen(m, DESK, 4)
    part = _seen(m, _patch((x1, x1 + 0.475), (0.3, 0.4), (0.5, 0.5)), 4)
    assert len(m.semantic_map().points) == len(DESK) + 100
    m._absorb()
    assert (m._roots()[part] == desk) == merged


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, 1500), min_size=1, max_size=6), st.integers(0, 2 ** 32))
def test_a_cube_table_answers_as_a_dictionary(sizes, seed):
    """Batches of keys added (the table doubles as it fills), each looked up with as many
    keys never added."""
    table, plain = HashTable(16), {}
    rng = np.random.default_rng(seed)
    for k, size in enumerate(sizes):
        keys = np.unique(np.r_[rng.integers(-2 ** 40, 2 ** 40, size), list(plain)[:size // 2]]).astype(np.int64)
        new = keys[[key not in plain for key in keys.tolist()]]
        table.add(new, np.full(len(new), k))
        plain.update(dict.fromkeys(new.tolist(), k))
        probe = np.r_[keys, rng.integers(-2 ** 40, 2 ** 40, len(keys) + 1)]
        assert table.get(probe).tolist() == [plain.get(p, -1) for p in probe.tolist()]
    assert len(table) == len(plain)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 20), st.integers(0, 3)), max_size=60))
def test_claims_made_together_equal_claims_made_one_after_another(entries):
    keys = np.array([k for k, _ in entries], np.int64)
    rank = np.array([r for _, r in entries], np.int64)
    expect, taken = [], set()
    for r in sorted(set(rank.tolist())):  # each rank in turn takes the keys no earlier rank took
        mine = [i for i in range(len(keys)) if rank[i] == r]
        for key in sorted(set(keys[mine].tolist()) - taken):
            taken.add(key)
            expect.append(min(i for i in mine if keys[i] == key))  # its first entry of that key
    first = first_of_lowest_rank(keys, rank) if len(keys) else np.zeros(0, np.int64)
    assert first[np.lexsort((keys[first], rank[first]))].tolist() == expect


def test_a_maps_points_handed_out_never_change_as_it_grows():
    rows = Rows((3,), np.float64)
    rows.append(np.ones((10, 3)))
    before = rows.rows
    for k in range(2, 8):  # past its capacity several times
        rows.append(np.full((7 * k, 3), float(k)))
    assert (before == 1).all() and len(before) == 10  # the scorer keeps the rows it was given
    assert len(rows.rows) == 10 + 7 * sum(range(2, 8)) and (rows.rows[:10] == 1).all() and (rows.rows[-7:] == 7).all()


def test_camera_poses_of_many_robot_poses_equal_one_at_a_time(scenes):
    env, _ = scenes["apart"]
    cam = Camera.of(env.config.camera)
    poses = np.random.default_rng(0).uniform(-3, 3, (2, 5, 3))
    many = cam.pose(poses)
    assert many.shape == (2, 5, 4, 4)
    assert np.array_equal(many, np.stack([[cam.pose(p) for p in row] for row in poses]))


def test_the_compiled_kernels_give_what_their_numpy_formulations_give():
    """The union-find segments number as scipy.ndimage.label numbers the image of pixels and
    links (thresholds in float32, as numpy takes them beside float32 depth); the hash table
    answers as a dict; the back-projection matches the numpy expressions bit for bit."""
    from scipy import ndimage

    from rosmeery_jax.mapping.kernels import HashTable, back_project, label_segments

    rng = np.random.default_rng(0)
    within = np.zeros((3, 3, 3), bool)
    within[1] = ndimage.generate_binary_structure(2, 1)
    for _ in range(200):
        f, h, w = rng.integers(1, 4), rng.integers(1, 16), rng.integers(1, 16)
        d = (rng.choice([0.5, 1.0, 1.02, 2.0], (f, h, w)) + rng.normal(0, 0.01, (f, h, w))).astype(np.float32)
        valid = rng.random((f, h, w)) < 0.8
        grid = np.zeros((f, 2 * h - 1, 2 * w - 1), bool)
        grid[:, ::2, ::2] = valid
        for a, b, link in ((np.s_[..., :-1], np.s_[..., 1:], np.s_[:, ::2, 1::2]),
                           (np.s_[:, :-1, :], np.s_[:, 1:, :], np.s_[:, 1::2, ::2])):
            grid[link] = valid[a] & valid[b] & (np.abs(d[a] - d[b]) <= 0.03 + 0.03 * np.minimum(d[a], d[b]))
        label, count = ndimage.label(grid, within)
        got = label_segments(d, valid, np.float32(0.03), np.float32(0.03))
        assert got[0] == count and np.array_equal(got[1], label[:, ::2, ::2][valid] - 1)
    table, held = HashTable(16), {}
    for _ in range(100):
        keys = np.unique(rng.integers(0, 1 << 62, rng.integers(0, 200)))
        np.testing.assert_array_equal(table.get(keys), [held.get(k, -1) for k in keys.tolist()])
        new = keys[table.get(keys) < 0]
        values = rng.integers(0, 50, len(new))
        table.add(new, values)
        held.update(zip(new.tolist(), values.tolist()))
    depth = rng.choice([0.0, 0.7, 2.5], (3, 6, 8)).astype(np.float32)
    rays = tuple(rng.normal(0, 1, (6, 8)) for _ in range(3))
    pose = rng.normal(0, 2, (3, 3)).astype(np.float32)
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    valid, dd, x, y, z = back_project(depth, *rays, c, s, pose[:, 0].copy(), pose[:, 1].copy(), 0.4, np.float32(0.1), 0.03)
    zz = 0.4 + rays[2] * depth
    want = (depth > 0) & (zz >= 0.03)
    at = np.broadcast_to(np.arange(3)[:, None, None], depth.shape)[want]
    rx, ry = rays[0][None].repeat(3, 0)[want] * depth[want], rays[1][None].repeat(3, 0)[want] * depth[want]
    np.testing.assert_array_equal(valid, want)
    np.testing.assert_array_equal(x, pose[at, 0] + 0.1 * c[at] + c[at] * rx - s[at] * ry)
    np.testing.assert_array_equal(y, pose[at, 1] + 0.1 * s[at] + s[at] * rx + c[at] * ry)
    np.testing.assert_array_equal(z, zz[want])


def test_rule_7s_compiled_choice_is_the_sorted_one():
    """grow_ranks gives, point by point, what the numpy formulation (distinct (segment, cell)
    pairs by np.unique, the owner by a lexsort: most cells, then the smaller instance; the
    instances ranked by their first segment) gives."""
    from rosmeery_jax.mapping.kernels import grow_ranks

    def by_sorting(part, cell, held, beside, segments, share):
        cells = len(held)
        pairs, pair_ix = np.unique(part * cells + cell, return_inverse=True)
        seg, cell_of = pairs // cells, pairs % cells
        h = held[cell_of]
        count = np.bincount(seg, minlength=segments)
        on = h >= 0
        if not on.any():
            return np.full(len(part), -1), np.zeros(0, np.int64)
        width = int(h.max()) + 1
        pair, n = np.unique(seg[on] * width + h[on], return_counts=True)
        s, inst = pair // width, pair % width
        o = np.lexsort((-n, s))
        s, inst, n = s[o], inst[o], n[o]
        keep = np.r_[True, s[1:] != s[:-1]] & (n >= share * count[s])
        segs, insts = s[keep], inst[keep]
        if not len(segs):
            return np.full(len(part), -1), np.zeros(0, np.int64)
        ids, first, which = np.unique(insts, return_index=True, return_inverse=True)
        order = np.argsort(first)
        seg_rank = np.full(segments, -1)
        seg_rank[segs] = np.argsort(order)[which]
        rank = seg_rank[seg]
        rank = np.where((rank >= 0) & (beside[cell_of] == ids[order][np.maximum(rank, 0)]), rank, -1)[pair_ix]
        return rank, ids[order]

    rng = np.random.default_rng(3)
    for _ in range(300):
        k, segments, cells = rng.integers(1, 80), rng.integers(1, 8), rng.integers(1, 12)
        part, cell = rng.integers(0, segments, k), rng.integers(0, cells, k)
        held = rng.integers(-1, 4, cells)
        beside = np.where(rng.random(cells) < 0.8, held, rng.integers(-1, 4, cells))
        share = float(rng.choice([0.0, 0.3, 0.5, 1.0]))
        want = by_sorting(part, cell, held, beside, segments, share)
        got = grow_ranks(part, cell, held, beside, segments, cells, share)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])


def test_first_claims_are_the_lowest_rank_then_the_first():
    """The hash-table claims agree with sorting every entry by key, rank and index."""
    rng = np.random.default_rng(4)
    for _ in range(500):
        keys = rng.integers(0, rng.integers(1, 30), rng.integers(0, 50)).astype(np.int64) << 40
        rank = rng.integers(0, rng.integers(1, 4), len(keys))
        o = np.lexsort((rank, keys))
        first = o[np.r_[True, keys[o][1:] != keys[o][:-1]]] if len(keys) else o
        got = first_of_lowest_rank(keys, rank) if len(keys) else np.zeros(0, np.int64)
        np.testing.assert_array_equal(np.sort(got), np.sort(first))



def test_the_fused_mapper_maps_each_object_apart_as_one_instance(scenes):
    """The fused mapper (``rosmeery_jax.mapping.fused``) on the rendered scene: two frames
    of tight boxes, the second's pose estimate 3 cm off, give the chair and the desk one
    instance each with their labels, nearly every point within 5 cm of its object."""
    from rosmeery_jax.mapping.fused import FusedMapper
    from rosmeery_jax.mapping.protocol import Frame

    env, depth, label = _frame(scenes, "apart")
    _, boxes = _tight(label)
    cam = Camera.of(env.config.camera)
    m = FusedMapper(cam, env.world.taxonomy.names)
    for i, est in enumerate([POSE, POSE + np.float32([0.03, 0.0, 0.0])]):
        m.add(Frame(i, float(i), np.zeros((*depth.shape, 3), np.uint8), depth, est, cam.pose(est), boxes,
                    np.array([0, 4]), np.array([0.8, 0.6], np.float32)))
    points, instance, labels, conf = m.semantic_map()
    assert sorted(labels.tolist()) == [0, 4] and len(set(instance.tolist())) == 2
    by_label = dict(zip(labels.tolist(), conf.tolist()))  # two agreeing votes: surer than either alone
    assert 0.8 < by_label[0] < 1 and 0.6 < by_label[4] < 1
    log = _log(env, m)
    assert (log.ps > 0).all() and list(log.label) == [0, 4]
    assert OnlineScorer(env.world, 0.05).score(m.semantic_map()).off_object < 0.05  # the 3 cm frame's edge voxels
