"""The perceived mapper: depth inside detector boxes, association by overlap, no ground truth."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import room_xml
from rosmeery_jax.scoring import metrics
from rosmeery_jax.detector.dataset import visible_boxes
from rosmeery_jax.env import make
from rosmeery_jax.sim.knowledge import GroundTruthTable
from rosmeery_jax.scoring.evaluate import read_map, score, tie
from rosmeery_jax.scoring.mapper import Camera, OnlineScorer
from rosmeery_jax.scoring.perceived import PerceivedMapper, _median
from rosmeery_jax.sim.sensors import rgbd
from rosmeery_jax.scoring.semantic_map import build_map, write_map

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
POSE = np.array([0.0, 1.6, -np.pi / 2], np.float32)  # looking down -y at both objects


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """{name: (env, render(pose) -> depth, labels)}, one compile each."""
    out = {}
    for name, bodies in (("apart", APART), ("together", TOGETHER)):
        path = tmp_path_factory.mktemp(name) / "room.xml"
        path.write_text(room_xml(bodies, {"chair": "chair", "desk": "desk"}, spawn=(0.0, 1.0, 0.0)))
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


def _tight(label):
    b = visible_boxes(label, 40)  # rows object, x1, y1, x2, y2, pixels
    return b[:, 0], b[:, 1:5].astype(np.float32)


def test_tight_boxes_give_one_instance_per_object_and_points_only_on_objects(scenes, tmp_path):
    env, depth, label = _frame(scenes, "apart")
    obj, boxes = _tight(label)
    assert list(obj) == [0, 1]  # both objects in view
    m = PerceivedMapper(Camera.of(env.config.camera))
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
    m = PerceivedMapper(Camera.of(env.config.camera))
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
    union = np.concatenate([boxes[:, :2].min(0), boxes[:, 2:].max(0)])[None]
    merged = PerceivedMapper(Camera.of(env.config.camera))
    merged.fold(POSE, depth, union, np.array([4]), np.array([0.9], np.float32))
    separate = PerceivedMapper(Camera.of(env.config.camera))
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
    voxels = PerceivedMapper._voxels
    monkeypatch.setattr(PerceivedMapper, "_voxels", lambda self, *a: calls.append(1) or voxels(self, *a))

    def build(memo: bool) -> PerceivedMapper:
        m = PerceivedMapper(Camera.of(env.config.camera))
        if not memo:
            m._frame_memo = lambda pose, depth: {}
        for f, (pose, d, b) in enumerate(frames):
            m.fold(pose, d, b, np.array([0, 4])[: len(b)], np.array([0.8, 0.6], np.float32)[: len(b)])
        return m

    kept, plain = build(True), build(False)
    assert len(boxes) == len(boxes2) == 2
    assert len(calls) == 2 * 4 + 2 * 6  # with the memory: A, moved, the nearer view, A again; without: all 6
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


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(float(np.float32(0.01)), 20.0, width=32), min_size=1, max_size=40))
def test_the_depth_median_is_numpys_bitwise(values):
    """The mapper's band filter uses its own median (np.median's overhead was a tenth of the
    mapper's time); it must equal np.median to the bit, odd and even counts alike."""
    v = np.array(values, np.float32)
    ours, ref = _median(v), np.median(v)
    assert ours.dtype == ref.dtype and ours.tobytes() == ref.tobytes()


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
