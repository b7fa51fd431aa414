"""Coverage, spatial knowledge, metrics, semantic map export and `rosmeery replay`."""

from __future__ import annotations

import dataclasses
import functools
import json
import re
import warnings
from types import MappingProxyType

import jax
import jax.numpy as jnp
import jsonschema
import numpy as np
import pandas as pd
import pytest
import trimesh
from conftest import room_xml
from hypothesis import given, settings
from hypothesis import strategies as st

from rosmeery_jax import metrics
from rosmeery_jax.apps.cli import main
from rosmeery_jax.env import make
from rosmeery_jax.metrics.map_file import load_schema
from rosmeery_jax.metrics.trajectory import replay
from rosmeery_jax.sim.knowledge import GroundTruthTable, ObjectLog, predicate_tables
from rosmeery_jax.world.taxonomy import load_taxonomy

# A room 8 m across. The camera (robot at the origin facing +x: camera at (0.1, 0, 0.5))
# sees the 1 m x 1 m front face of "front" (x = 1.7), and nothing else of it: its sides lie
# in the planes y = +-0.5, on either side of the camera, and its top (z = 1 m, above the
# camera) is not observable. "hidden" stands right behind it; "behind" is behind the camera.
_BOXES = """
<body name="front" pos="2.0 0 0.5"><geom type="box" size="0.3 0.5 0.5"/></body>
<body name="hidden" pos="3.2 0 0.3"><geom type="box" size="0.2 0.3 0.3"/></body>
<body name="behind" pos="-2.0 0 0.3"><geom type="box" size="0.3 0.3 0.3"/></body>
"""
_CATEGORIES = {"front": "cabinet", "hidden": "chair", "behind": "couch"}


@pytest.fixture(scope="module")
def three_box_world(tmp_path_factory):
    path = tmp_path_factory.mktemp("worlds") / "three_boxes.xml"
    path.write_text(room_xml(_BOXES, _CATEGORIES, half=4.0))
    return path


@functools.lru_cache(maxsize=None)
def _env(path: str, **overrides):
    return make(path, **overrides)


def _one_pose(env):
    return replay(env, np.array([0.0]), np.zeros((1, 3), np.float32))


def test_single_box_covers_its_visible_face_and_nothing_hidden(three_box_world):
    env = _env(str(three_box_world))
    truth = env.world.truth
    run = _one_pose(env)
    ps = run.logs.ps[-1]
    front, hidden, behind = (truth.names.index(n) for n in ("front", "hidden", "behind"))
    # By hand: observable surface of "front" = front + back faces (1 x 1 m each) + the two
    # side faces (0.6 x 1 m each) = 3.2 m^2 (top above the camera, bottom on the floor);
    # the visible front face is 1 m^2 of it.
    assert ps[front] / truth.ps_G[front] == pytest.approx(1.0 / 3.2, abs=0.02)
    # Exactly the samples on the face looking at the camera, all of them.
    s = truth.samples
    on_front_face = (s.object == front) & (s.normals[:, 0] < -0.99)
    seen = run.knowledge.seen
    assert np.array_equal(seen & (s.object == front), on_front_face)
    assert ps[hidden] == 0
    assert ps[behind] == 0


def test_object_beyond_camera_range_is_not_covered(three_box_world):
    env = _env(str(three_box_world), camera__max_range=1.5)  # "front" is 1.6 m away
    assert int(_one_pose(env).logs.ps[-1].sum()) == 0


def test_turning_round_covers_the_box_behind(three_box_world):
    env = _env(str(three_box_world))
    behind = env.world.truth.names.index("behind")
    run = replay(env, np.array([0.0, 1.0]), np.array([[0, 0, 0], [0, 0, np.pi]], np.float32))
    assert run.logs.ps[0, behind] == 0 and run.logs.ps[1, behind] > 0


def test_soft_coverage_is_a_smooth_version_of_the_hard_test(three_box_world):
    hard = _one_pose(_env(str(three_box_world)))

    env = _env(str(three_box_world), knowledge__coverage__soft=True, knowledge__coverage__temperature=0.01)
    soft = _one_pose(env)
    front = env.world.truth.names.index("front")
    assert soft.logs.ps[-1, front] == pytest.approx(hard.logs.ps[-1, front], rel=0.1)
    # and it has a gradient with respect to the pose
    from rosmeery_jax.raycast.sensors import depth_seg
    from rosmeery_jax.sim import coverage


    def covered(x):
        pose = jnp.array([0.0, 0.0, 0.0]) + jnp.array([x, 0.0, 0.0])
        depth, _ = depth_seg(env.rays, env.config.camera, pose)
        return coverage.observed_soft(env.sk.table, env.sk.cfg.coverage, env.config.camera, pose, depth).sum()

    g = jax.grad(covered)(0.0)
    assert np.isfinite(g) and g != 0.0


def _table_log():
    # Two objects, two times. Hand arithmetic in the test below.
    log = ObjectLog(ps=np.array([[0, 0], [50, 25]], float), conf_true=np.array([[0, 0], [0.8, 0]]),
                    conf_any=np.array([[0, 0], [0.8, 0.5]]), label=np.array([[-1, -1], [3, 7]]),
                    declared=np.array([[0, 0], [3, 3]]), correct=np.array([[0, 0], [3, 1]]))
    truth = GroundTruthTable(ps_G=np.array([100, 50]), P_G=np.array([3, 3]), category=np.array([3, 5]))
    return log, truth


def test_a_log_and_truth_that_disagree_are_refused_not_broadcast():
    log, truth = _table_log()
    one = GroundTruthTable(*(a[:1] for a in truth))  # one object's truth broadcast over the log's two
    with pytest.raises(ValueError, match=r"truth.ps_G has shape \(1,\): the log holds N = 2 objects"):
        metrics.compute(log, one)
    with pytest.raises(ValueError, match=r"log.label has shape \(2, 1\)"):
        metrics.compute(log._replace(label=log.label[:, :1]), truth)
    with pytest.raises(ValueError, match=r"log.ps has shape \(\)"):
        metrics.compute(ObjectLog(*(a[1, 0] for a in log)), truth)
    step = metrics.compute(ObjectLog(*(a[1] for a in log)), truth)  # one step's log (N,): its value
    assert step["ori"] == pytest.approx(0.5)
    with pytest.raises(TypeError, match=r"log must be ObjectLog\(ps, .*not NoneType"):
        metrics.compute(None, truth)
    with pytest.raises(TypeError, match="truth must be GroundTruthTable"):
        metrics.compute(log, {"ps_G": truth.ps_G})


def test_a_metric_plugin_that_fails_on_the_sessions_log_is_one_line_naming_it(tmp_path):
    """Checked on a log of 3 steps when registered, a metric may fail on the session's: it
    raises (a traceback from the session) or gives a curve of another length."""
    from rosmeery_jax.core.errors import InputError

    plugin = tmp_path / "late_metrics.py"
    plugin.write_text("def raises_late(log, truth):\n    if log.ps.shape[-2] != 3:\n"
                      "        raise ValueError('only three steps')\n    return log.ps.sum(-1)\n\n"
                      "def three_only(log, truth):\n    return log.ps.sum(-1)[:3]\n")
    log, truth = _table_log()  # 2 steps
    metrics.resolve([f"{plugin}:raises_late", f"{plugin}:three_only"])  # both pass the check on 3 steps
    head = f"config: metrics: plugin '{plugin}:"
    with pytest.raises(InputError) as raised:
        metrics.compute(log, truth, ["ori", "raises_late"])
    assert str(raised.value) == head + "raises_late' failed in its curve of 2 steps: ValueError: only three " \
                                      "steps (late_metrics.py, line 3, in raises_late)"
    long = ObjectLog(*(np.concatenate([a, a, a]) for a in log))  # 6 steps
    with pytest.raises(InputError) as raised:
        metrics.compute(long, truth, ["ori", "three_only"])
    assert str(raised.value) == head + "three_only' gave a curve of shape (3,) for a log of (6,) steps: one " \
                                      "value per step is needed"
    # One registered in Python is named as registered, in both errors alike.
    @metrics.register("late_in_python")
    def _late(log, truth):
        if log.ps.shape[-2] != 3:
            raise IndexError("only three steps")
        return log.ps.sum(-1)

    with pytest.raises(InputError, match=r"^config: metrics: metric 'late_in_python' failed in its curve of 2 "
                                         r"steps: IndexError"):
        metrics.compute(log, truth, ["late_in_python"])


def test_metrics_match_hand_arithmetic():
    log, truth = _table_log()
    c = metrics.compute(log, truth)
    # ORI(t1) = 1 - (|100 - 50| / 100 + |50 - 25| / 50) / 2 = 0.5
    np.testing.assert_allclose(c["ori"], [0.0, 0.5], atol=1e-6)
    # cORI(t1) = 1 - (|100 - 0.8 * 50| / 100 + |50 - 0| / 50) / 2 = 1 - (0.6 + 1) / 2 = 0.2
    np.testing.assert_allclose(c["cori"], [0.0, 0.2], atol=1e-6)
    # label-agnostic: 1 - (0.6 + |50 - 0.5 * 25| / 50) / 2 = 1 - (0.6 + 0.75) / 2 = 0.325
    np.testing.assert_allclose(c["cori_any"], [0.0, 0.325], atol=1e-6)
    # OPI(t1) = 1 - (0 + 0) / 2 = 1; strict: object 2 has 1 correct, 2 false:
    # 1 - (0 + (|3 - 1| + 2) / 3) / 2 = 1 - 2 / 3
    np.testing.assert_allclose(c["opi"], [0.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(c["opi_strict"], [0.0, 1 / 3], atol=1e-6)


def test_summary_figures():
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    s = metrics.summarize(t, np.array([0.0, 0.2, 0.5, 0.9, 1.0]))
    assert s["final"] == 1.0
    assert s["auc"] == pytest.approx((0.1 + 0.35 + 0.7 + 0.95) / 4)
    assert s["t50_s"] == 2.0 and s["t90_s"] == 3.0
    assert np.isnan(metrics.summarize(t, np.zeros(5))["t50_s"])
    assert np.isnan(metrics.summarize(t, np.full(5, np.nan))["t90_s"])  # was 0.0: a time for no value


@pytest.mark.parametrize("times, curve, needle", [
    ([], [], "non-empty"), ([0.0, 1.0, 2.0], [0.1, 0.2], "(3,) and curve (2,)"),  # an IndexError; a wrong area
    ([2.0, 1.0, 0.0], [0.1, 0.2, 0.3], "increasing order"), ([0.0, np.inf], [0.1, 0.2], "finite"),
])
def test_summary_figures_of_a_malformed_curve_are_refused(times, curve, needle):
    with pytest.raises(ValueError, match=re.escape(needle)):
        metrics.summarize(np.array(times), np.array(curve))


def test_predicates_from_labels_count_correct_levels():
    tax = load_taxonomy()
    declared, correct = predicate_tables(tax, ("chair", "refrigerator"))
    assert set(declared) == {3}
    assert correct[0, tax.index("chair")] == 3
    assert correct[0, tax.index("couch")] == 2  # same macro (seating) and root
    assert correct[0, tax.index("desk")] == 1  # same root (furniture) only
    assert correct[1, tax.index("chair")] == 0


def test_predicate_tables_are_cached_per_taxonomy_content(tmp_path):
    """The tables are cached (a perceived map is scored once per frame), so the cache key
    must be the taxonomy's content: the same file with one macro changed gets its own
    tables, and the shared arrays cannot be edited in place."""
    path = tmp_path / "tax.toml"
    path.write_text("[roots]\nroot = 'x'\n[macros]\nm1 = 'root'\nm2 = 'root'\n"
                    "[categories.a]\nmacro = 'm1'\n[categories.b]\nmacro = 'm1'\n")
    same = load_taxonomy(path)
    apart = dataclasses.replace(same, categories=MappingProxyType(
        {**same.categories, "b": dataclasses.replace(same["b"], macro="m2")}))
    assert predicate_tables(same, ("a",))[1].tolist() == [[3, 2]]  # b shares a's macro and root
    assert predicate_tables(apart, ("a",))[1].tolist() == [[3, 1]]  # the root only
    assert predicate_tables(same, ("a",))[1] is predicate_tables(load_taxonomy(path), ("a",))[1]
    with pytest.raises(ValueError):
        predicate_tables(same, ("a",))[1][0, 0] = 0


def test_unknown_metric_is_one_clear_error():
    with pytest.raises(Exception, match="unknown metric 'nope'"):
        metrics.resolve(["ori", "nope"])


_TRAJ_LEN = 6


@functools.lru_cache(maxsize=None)
def _small_office():
    return make("small_office", start_yaw="spawn")  # the hand-made cases start at the spawn heading


@st.composite
def _trajectories(draw):
    env = _small_office()
    cells = np.argwhere(env.world.free_space.reachable)
    fs = env.world.free_space
    idx = draw(st.lists(st.integers(0, len(cells) - 1), min_size=_TRAJ_LEN, max_size=_TRAJ_LEN))
    yaw = draw(st.lists(st.floats(-np.pi, np.pi), min_size=_TRAJ_LEN, max_size=_TRAJ_LEN))
    c = cells[idx]
    return np.stack([fs.origin[0] + (c[:, 1] + 0.5) * fs.resolution, fs.origin[1] + (c[:, 0] + 0.5) * fs.resolution,
                     np.asarray(yaw)], -1).astype(np.float32)


@settings(max_examples=8, deadline=None)
@given(_trajectories(), st.integers(0, 2**31 - 1))
def test_metric_invariants_on_random_trajectories(poses, det_seed):
    env = _small_office()
    times = np.arange(_TRAJ_LEN, dtype=float)
    run = replay(env, times, poses)
    # Detections with random labels and confidences, attached as a detector would, so cORI
    # and OPI-strict see wrong labels and confidences below 1.
    rng = np.random.default_rng(det_seed)
    n, ncat = env.world.truth.num_objects, len(env.world.taxonomy.names)
    k = env.sk.init()._replace(seen=jnp.asarray(run.knowledge.seen))
    logs = []
    for _ in range(_TRAJ_LEN):
        obj = rng.integers(-1, n, 5)
        lab = np.where(rng.random(5) < 0.5, np.asarray(env.world.truth.category_index)[np.maximum(obj, 0)],
                       rng.integers(0, ncat, 5))
        k = env.sk.attach(k, jnp.asarray(obj, jnp.int32), jnp.asarray(lab, jnp.int32), jnp.asarray(rng.random(5), jnp.float32))
        logs.append(env.sk.log(k))
    det_logs = jax.tree.map(lambda *a: np.stack(a), *logs)
    for log in (run.logs, det_logs):
        c = metrics.compute(log, env.sk.truth)
        for name, curve in c.items():
            assert np.all((curve >= 0) & (curve <= 1)), name
        assert np.all(np.diff(c["ori"]) >= -1e-9)
        assert np.all(np.diff(c["opi"]) >= -1e-9)
        assert np.all(c["cori"] <= c["ori"] + 1e-9)
        assert np.all(c["cori_any"] <= c["ori"] + 1e-9)
    # c_t(n) is what a map of the held labels earns: their confidence where they are right
    right = det_logs.label == np.asarray(env.world.truth.category_index)
    np.testing.assert_array_equal(det_logs.conf_true, np.where(right, det_logs.conf_any, 0.0))
    again = replay(env, times, poses)
    for a, b in zip(run.logs, again.logs):
        np.testing.assert_array_equal(a, b)


def test_cori_weighs_the_held_label_only_while_it_is_right():
    """One object, by hand: right at 0.5, outbid by a wrong label at 0.8 (a right 0.6 does
    not win it back), then right at 0.9. c_t follows the held label, as the map's file does."""
    env = _small_office()
    right = int(env.world.truth.category_index[0])
    wrong = (right + 1) % len(env.world.taxonomy.names)
    k, held = env.sk.init(), []
    for label, conf in ((right, 0.5), (wrong, 0.8), (right, 0.6), (right, 0.9)):
        k = env.sk.attach(k, jnp.asarray([0], jnp.int32), jnp.asarray([label], jnp.int32),
                          jnp.asarray([conf], jnp.float32))
        log = env.sk.log(k)
        held.append((int(log.label[0]), float(log.conf_true[0]), float(log.conf_any[0])))
    assert held == [(right, 0.5, 0.5), (wrong, 0.0, pytest.approx(0.8)), (wrong, 0.0, pytest.approx(0.8)),
                    (right, pytest.approx(0.9), pytest.approx(0.9))]


def test_an_exported_map_with_outbid_labels_scores_the_sessions_cori(tmp_path):
    """A turn on the spot, then every seen object labelled: the even ones right at 0.7, the
    odd ones right at 0.5 and then outbid by a wrong label at 0.8. The exported map of that
    knowledge, scored as any map is, gives the session's cORI."""
    from rosmeery_jax.metrics.map_file import write_semantic_map
    from rosmeery_jax.metrics.map_score import evaluate

    env = _small_office()
    sx, sy, syaw = env.world.spawn
    run = replay(env, np.arange(8.0), np.stack([np.full(8, sx), np.full(8, sy), syaw + np.linspace(0, 6.3, 8)], 1))
    k = env.sk.init()._replace(seen=jnp.asarray(run.knowledge.seen))
    seen = np.flatnonzero(np.asarray(env.sk.log(k).ps) > 0)
    right = np.asarray(env.world.truth.category_index)[seen]
    wrong = (right + 1) % len(env.world.taxonomy.names)
    odd = seen % 2 == 1
    for label, conf in ((right, np.where(odd, 0.5, 0.7)), (np.where(odd, wrong, right), np.where(odd, 0.8, 0.0))):
        k = env.sk.attach(k, jnp.asarray(seen, jnp.int32), jnp.asarray(label, jnp.int32), jnp.asarray(conf, jnp.float32))
    assert odd.any() and (~odd).any()  # both kinds are in the map
    log = jax.tree.map(lambda a: np.asarray(a)[None], env.sk.log(k))
    ours = metrics.compute(log, env.sk.truth)
    write_semantic_map(tmp_path, "m", env.world, jax.tree.map(np.asarray, k), 8.0)
    scored = evaluate(env.world, tmp_path / "m.ply")[3]
    for m in ("ori", "cori", "opi"):
        assert scored[m] == pytest.approx(float(ours[m][-1]), abs=1e-6), m
    assert scored["cori"] < scored["ori"]


def test_env_rollout_coverage_grows_and_logs_vmap():
    env = _small_office()
    keys = jax.random.split(jax.random.key(0), 2)
    state = jax.jit(jax.vmap(env.reset))(keys)
    step = jax.jit(jax.vmap(env.step))
    log = jax.jit(jax.vmap(env.log))
    first = log(state).ps.sum(-1)
    target = jnp.tile(jnp.asarray(env.world.spawn, jnp.float32) + jnp.array([0.0, 0.0, np.pi]), (2, 1))
    for _ in range(15):
        state = step(state, target)
    last = log(state)
    assert np.all(np.asarray(last.ps.sum(-1)) > np.asarray(first))
    assert np.all(np.asarray(last.ps) <= np.asarray(env.world.truth.ps_G))
    # The same through RobotEnv.rollout, which logs every step: ORI non-decreasing per env.
    state = jax.jit(jax.vmap(env.reset))(keys)
    _, logs = jax.jit(jax.vmap(env.rollout))(state, jnp.broadcast_to(target[:, None], (2, 15, 3)))
    ori = metrics.compute(jax.tree.map(np.asarray, logs), env.sk.truth, ["ori"])["ori"]
    assert ori.shape == (2, 15) and np.all(np.diff(ori, axis=-1) >= -1e-9)
    assert np.asarray(logs.ps)[:, -1].sum() == np.asarray(last.ps).sum()




@metrics.register("half_ori")
def _half_ori(log, truth):
    return 0.5 * metrics.REGISTRY["ori"](log, truth)


def test_a_built_in_metric_cannot_be_replaced_but_your_own_can_be_re_registered():
    """``@register("ori")`` silently replaced the paper's ORI in every later session."""
    from rosmeery_jax.core.errors import InputError

    ori = metrics.REGISTRY["ori"]
    with pytest.raises(InputError, match="register_metric: name: 'ori' is a built-in metric"):
        metrics.register("ori")(_half_ori)
    assert metrics.REGISTRY["ori"] is ori
    metrics.register("half_ori")(_half_ori)  # a notebook cell run twice
    assert metrics.REGISTRY["half_ori"] is _half_ori


def test_a_metric_registered_in_python_is_checked_before_a_session(tmp_path):
    """A non-function was registered (a TypeError after the session's simulation), and so
    was one that cannot trace (the session simulated, then failed on it)."""
    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.session.config import SessionConfig

    with pytest.raises(TypeError, match=r"register_metric\('not_a_fn'\) decorates a function .*not int"):
        metrics.register("not_a_fn")(3)
    assert "not_a_fn" not in metrics.REGISTRY

    @metrics.register("untraceable")
    def _untraceable(log, truth):
        return np.asarray(log.ps).sum(-1)  # numpy on a tracer

    cfg = SessionConfig(worlds=("kitchen",), policies=("random",), seeds=1, duration=1.0, detector="off",
                        metrics=("ori", "untraceable"), out=str(tmp_path / "o"))
    with pytest.raises(InputError, match=r"^config: metrics: metric 'untraceable' cannot run under JAX on an "
                                         r"object log: TracerArrayConversionError"):
        cfg.validate()
    assert not (tmp_path / "o").exists()
    metrics.register("untraceable")(lambda log, truth: log.ps.sum(-1))  # mended in the notebook: checked again
    assert metrics.resolve(["untraceable"]) == ("untraceable",)


@pytest.fixture(scope="module")
def replay_dir(tmp_path_factory):
    """`rosmeery replay` on a turn on the spot in the Small Office, with a user metric."""
    from rosmeery_jax.world import load_world

    d = tmp_path_factory.mktemp("replay")
    sx, sy, syaw = load_world("small_office").spawn
    t = np.arange(0.0, 8.0, 0.5)
    pd.DataFrame({"t": t, "x": sx, "y": sy, "yaw": syaw + np.linspace(0, 2 * np.pi, len(t))}).to_csv(d / "p.csv", index=False)
    assert main(["replay", "--world", "small_office", "--poses", str(d / "p.csv"), "--out", str(d / "out"),
                 "--metrics", "ori,cori,opi,half_ori"]) == 0
    return d / "out"


def test_metric_times_are_written_to_the_microsecond():
    from rosmeery_jax.results.tables import metric_frame

    df = metric_frame({"ori": np.array([0.0, 0.25, 0.5, 0.5])}, np.arange(4) * 0.1, world="w", policy="p",
                      detector="off", seed=0)
    assert df.time_s.tolist() == [0.0, 0.1, 0.2, 0.3]  # 3 * 0.1 is 0.30000000000000004
    assert "0.3,ori,0.5" in df.to_csv(index=False)
    from rosmeery_jax.results.tables import seconds

    with warnings.catch_warnings():  # a map's time of 1e308 s: kept, not overflowed to inf
        warnings.simplefilter("error")
        assert seconds([1e308, 2.0 ** 60, 0.1 * 3]).tolist() == [1e308, 2.0 ** 60, 0.3]
    assert isinstance(seconds(0.1 * 3), float) and seconds(0.1 * 3) == 0.3  # a scalar stays one (JSON)


def test_replay_writes_curves_with_a_user_metric(replay_dir):
    df = pd.read_csv(replay_dir / "metrics.csv")
    assert list(df.columns) == ["world", "policy", "detector", "mapper", "seed", "time_s", "metric", "value"]
    assert set(df.metric) == {"ori", "cori", "opi", "half_ori"}
    assert set(df.policy) == {"replay"}
    ori = df[df.metric == "ori"].value.to_numpy()
    np.testing.assert_allclose(df[df.metric == "half_ori"].value.to_numpy(), 0.5 * ori)
    assert ori[-1] > 0.1 and np.all(np.diff(ori) >= 0)
    objects = pd.read_csv(replay_dir / "objects.csv")
    assert list(objects.columns) == ["world", "policy", "detector", "mapper", "seed", "object", "category", "ps_G", "ps",
                                     "coverage", "label", "confidence", "P_G", "p"]
    assert len(objects) == 11 and (objects.ps <= objects.ps_G).all()


def test_exported_semantic_map_opens_and_validates(replay_dir):
    cloud = trimesh.load(replay_dir / "semantic_map.ply", process=False)
    raw = cloud.metadata["_ply_raw"]["vertex"]["data"]
    assert set(raw.dtype.names) == {"x", "y", "z", "object_id", "label", "confidence"}
    meta = json.loads((replay_dir / "semantic_map.json").read_text())
    jsonschema.validate(meta, load_schema())
    objects = pd.read_csv(replay_dir / "objects.csv")
    assert len(cloud.vertices) == objects.ps.sum()
    assert {o["name"] for o in meta["objects"]} == set(objects.object[objects.ps > 0])
    assert len(meta["predicates"]) == objects.p.sum()


@pytest.mark.parametrize("text, field", [
    ("t,x,y\n0,1,2\n", "columns"),
    ("t,x,y,yaw\n0,1,2,0\n0,1,2,0\n", "row 3, column t"),
    ("t,x,y,yaw\n0,1,abc,0\n", "row 2, column y: 'abc' is not"),
    ("t,x,y,yaw\n0,1,2,1e308\n", "row 2, column yaw: 1e+308 is not"),  # the number as written, not numpy's repr
    ("", "file"),
])
def test_bad_pose_file_is_one_line_naming_file_and_field(tmp_path, capsys, text, field):
    path = tmp_path / "poses.csv"
    path.write_text(text)
    assert main(["replay", "--world", "small_office", "--poses", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(path) in err and field in err
    assert not (tmp_path / "o").exists()


def test_replay_takes_one_run_of_a_session_trajectory_file(tmp_path, capsys):
    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.metrics.trajectory import read_poses
    from rosmeery_jax.world import load_world

    office, kitchen = load_world("small_office"), load_world("kitchen")
    (ox, oy, _), (kx, ky, _) = office.spawn, kitchen.spawn
    rows = [("small_office", "random", 0, 0.0, ox, oy, 0.0), ("small_office", "random", 0, 1.0, ox, oy, 1.0),
            ("small_office", "my.py:Mine", 1, 0.0, ox + 0.5, oy, 0.5), ("small_office", "my.py:Mine", 1, 1.0, ox, oy, 2.0),
            ("kitchen", "frontier", 0, 0.0, kx, ky, 3.0)]
    path = tmp_path / "trajectories.csv"
    pd.DataFrame(rows, columns=["world", "policy", "seed", "time_s", "x", "y", "yaw"]).to_csv(path, index=False)
    t, poses = read_poses(path, office, ("my.py:Mine", 1))  # a policy name holding a colon
    assert t.tolist() == [0.0, 1.0] and poses.tolist() == [[ox + 0.5, oy, 0.5], [ox, oy, 2.0]]
    t, poses = read_poses(path, kitchen)  # the world's only run: no --run needed
    assert t.tolist() == [0.0] and poses.tolist() == [[kx, ky, 3.0]]
    rows[3] = ("small_office", "my.py:Mine", 1, 0.0, ox, oy, 2.0)  # time stands still on the file's 5th line
    pd.DataFrame(rows, columns=["world", "policy", "seed", "time_s", "x", "y", "yaw"]).to_csv(path, index=False)
    with pytest.raises(InputError, match=r"row 5, column time_s: times must strictly increase"):
        read_poses(path, office, ("my.py:Mine", 1))
    plain = tmp_path / "poses.csv"
    plain.write_text(f"t,x,y,yaw\n0,{ox},{oy},0\n")
    for poses_file, run, field in ((path, None, "run: holds 2 runs (random:0, my.py:Mine:1)"),
                                   (path, "random:7", "run: no run random:7"), (path, "random", "--run"),
                                   (plain, "random:0", "columns: no world")):
        extra = [] if run is None else ["--run", run]
        assert main(["replay", "--world", "small_office", "--poses", str(poses_file), "--out", str(tmp_path / "o"),
                     *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and field in err
        assert not (tmp_path / "o").exists()


def test_compare_sessions_finals_aucs_and_noise_flags(tmp_path):
    """scripts/compare_sessions.py on two hand-made folders: 2 seeds, curves over 0..2 s."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("compare_sessions", Path(__file__).parents[1] / "scripts" /
                                                  "compare_sessions.py")
    cs = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cs)

    def folder(name, curves):  # curves: {(policy, seed): [v at 0, 1, 2 s]}
        rows = [("kitchen", p, "yolo", "oracle", seed, float(t), "ori", v)
                for (p, seed), vals in curves.items() for t, v in enumerate(vals)]
        (tmp_path / name).mkdir()
        pd.DataFrame(rows, columns=["world", "policy", "detector", "mapper", "seed", "time_s", "metric", "value"]
                     ).to_csv(tmp_path / name / "metrics.csv", index=False)
        return cs.per_seed(tmp_path / name, ["ori"])

    a = folder("a", {("random", 0): [0, 0.4, 0.6], ("random", 1): [0, 0.4, 0.8], ("frontier", 0): [0, 1, 1]})
    b = folder("b", {("random", 0): [0, 0.4, 0.6], ("random", 1): [0, 0.4, 0.8], ("frontier", 0): [0, 0.5, 0.5],
                     ("frontier", 1): [0, 0.5, 0.5]})
    seed1 = a[(a.policy == "random") & (a.seed == 1)].iloc[0]
    assert seed1.final == 0.8 and abs(seed1.auc - (0.2 + 0.6) / 2) < 1e-12  # trapezoids over 2 s
    t = cs.compare(a, b).set_index(["policy", "figure"])
    assert len(t) == 4  # both policies, final and AUC; nothing only one side has
    assert not t.loc[("random", "final"), "beyond_1std"] and t.loc[("random", "final"), "p"] == 1.0
    assert t.loc[("frontier", "final"), "diff"] == -0.5 and t.loc[("frontier", "final"), "beyond_1std"]
    assert t.loc[("frontier", "auc"), "diff"] == -0.375  # AUC 0.75 -> 0.375


def test_learned_table_joins_folders_and_compares_every_policy_with_one(tmp_path, capsys, monkeypatch):
    """scripts/learned_table.py on two hand-made folders: a measure run in one world of two,
    paired by seed with the evaluation's runs; curves over 0..2 s, so AUC = 0.75 x final."""
    import importlib.util
    import sys
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("learned_table", Path(__file__).parents[1] / "scripts" /
                                                  "learned_table.py")
    lt = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(lt)

    def folder(name, finals):  # finals: {(world, policy): [final ORI of seeds 0, 1, 2]}
        rows = [(w, p, "yolo", "oracle", seed, float(t), "ori", v * min(t, 1))
                for (w, p), vals in finals.items() for seed, v in enumerate(vals) for t in range(3)]
        (tmp_path / name).mkdir()
        pd.DataFrame(rows, columns=["world", "policy", "detector", "mapper", "seed", "time_s", "metric", "value"]
                     ).to_csv(tmp_path / name / "metrics.csv", index=False)
        return str(tmp_path / name)

    ev = folder("eval", {(w, p): [0.4, 0.4, 0.4] for w in ("kitchen", "laboratory", "small_office")
                         for p in ("random", "semantic_nbv")})
    more = folder("measure", {("kitchen", "variant"): [0.6, 0.8, 0.4], ("laboratory", "variant"): [0.6]})
    monkeypatch.setattr(sys, "argv", ["learned_table.py", ev, "--with", more, "--against", "semantic_nbv"])
    lt.main()
    out = capsys.readouterr().out
    row = {line.split(" | ")[0]: line for line in out.splitlines() if line.startswith("| ")}
    assert row["| Small Office"].endswith("| - |")  # the measure did not run there
    assert row["| *mean, paper worlds*"].endswith("| - |")  # nor is it averaged over the worlds it ran
    assert "**0.450 [" in row["| Laboratory"]  # its one seed: its mean, best (nothing shown behind)
    # AUC differences by seed 0.75 x (0.2, 0.4, 0): mean 0.15, SD 0.15, so 1.0 SD; the sign-flip
    # test's 8 patterns sum to +-0.45 four times in all, as extreme as the data: p 0.5. In the
    # Laboratory the measure ran seed 0 alone: it is paired on that seed only, and said so.
    assert "  variant: Kitchen +0.150 (+1.0) p 0.500; Laboratory +0.150 (no spread) p 1.000 (1 seeds)" in out
    assert "  random: Kitchen +0.000 (no spread) p 1.000; Laboratory +0.000 (no spread) p 1.000" in out
    assert "nan" not in out.split("against semantic_nbv")[1]  # a seed or two: no interval, but every comparison
    assert "variant" not in out.split("mean ORI AUC over the 3 paper worlds")[1].split("\n\n")[0]


@pytest.mark.parametrize("script", ["paper_table.py", "compare_sessions.py", "learned_table.py"])
def test_the_table_scripts_refuse_a_folder_that_is_not_results_in_one_line(script, tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    (tmp_path / "metrics.csv").write_text("garbage\n")  # paper_table and compare_sessions: tracebacks
    args = [str(tmp_path)] * (2 if script == "compare_sessions.py" else 1)
    done = subprocess.run([sys.executable, str(Path(__file__).parents[1] / "scripts" / script), *args],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr == f"error: {tmp_path / 'metrics.csv'}: columns: missing world, policy, detector, seed, " \
                          "time_s, metric, value\n"


def test_the_paper_table_names_a_paper_world_or_policy_the_folder_lacks(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    rows = [dict(world=w, policy=p, detector="off", seed=s, time_s=t, metric="ori", value=t / 2, mapper="oracle")
            for w in ("kitchen", "laboratory", "small_office", "large_office") for p in ("frontier", "random")
            for s in range(3) for t in (0.0, 1.0)]
    pd.DataFrame(rows).to_csv(tmp_path / "metrics.csv", index=False)  # a traceback (an empty argmax) before
    done = subprocess.run([sys.executable, str(Path(__file__).parents[1] / "scripts" / "paper_table.py"),
                           str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr.startswith(f"error: {tmp_path / 'metrics.csv'}: policy: no semantic_nbv rows: the paper "
                                  "table needs") and done.stderr.count("\n") == 1


def test_the_paper_table_of_one_seed_says_it_has_no_intervals_and_why(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    worlds, policies = ("kitchen", "laboratory", "small_office", "large_office"), ("frontier", "random", "semantic_nbv")
    rows = [dict(world=w, policy=p, detector="off", seed=0, time_s=t, metric=m, value=t / (2 + k), mapper="oracle")
            for w in worlds for k, p in enumerate(policies) for t in (0.0, 1.0) for m in ("ori", "cori", "opi")]
    pd.DataFrame(rows).to_csv(tmp_path / "metrics.csv", index=False)
    track = [dict(world=w, policy=p, seed=0, time_s=t, x=t, y=0.0) for w in worlds for p in policies for t in (0, 1)]
    pd.DataFrame(track).to_csv(tmp_path / "trajectories.csv", index=False)
    done = subprocess.run([sys.executable, str(Path(__file__).parents[1] / "scripts" / "paper_table.py"),
                           str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("note: 1 seed in the smallest run group: an interval needs 3, and a paired test 6")
    assert "| Kitchen | ORI | **0.50 [< 3 seeds]** | **0.33 [< 3 seeds]** | **0.25 [< 3 seeds]** |" in done.stdout
    assert "random - frontier     -0.167 [< 3 seeds]  p = 1.0000  (1 seed): no difference shown" in done.stdout
    assert "nan" not in done.stdout.lower()  # "[nan, nan]" and a zero-width difference interval before


def test_plot_results_draws_a_figure_per_world_and_metric_and_refuses_a_table_it_cannot_read(tmp_path):
    from rosmeery_jax.results.plots import plot_results

    rows = [dict(world=w, policy="random", detector="off", seed=s, time_s=t, metric=m, value=t / 2)
            for w in ("a", "b") for s in (0, 1) for t in (0.0, 1.0) for m in ("ori", "opi")]
    df = pd.DataFrame(rows)  # no mapper column: the oracle's, as older tables
    paths = plot_results(df, tmp_path / "p")
    assert sorted(p.name for p in paths) == ["a_opi.png", "a_ori.png", "b_opi.png", "b_ori.png"]
    assert all(p.read_bytes().startswith(b"\x89PNG") for p in paths)
    with pytest.raises(ValueError, match="plot_results: the table lacks world, metric"):  # an AttributeError
        plot_results(df.drop(columns=["world", "metric"]), tmp_path / "q")
    with pytest.raises(ValueError, match="has no rows"):
        plot_results(df.iloc[:0], tmp_path / "q")
    with pytest.raises(TypeError, match=r"plot_results: a results table \(load_results\(folder\)\), not str"):
        plot_results(str(tmp_path), tmp_path / "q")  # a folder for its table (an AttributeError)
    assert not (tmp_path / "q").exists()


@pytest.mark.parametrize("wanted", ["field", "ori,field"])
def test_replay_scores_the_field_metrics_of_the_map_it_grows(replay_dir, tmp_path, wanted):
    """`replay --metrics field` (alone or beside ori) writes every metric asked for, and the
    last row equals `evaluate` of the replay's exported map."""
    out = tmp_path / "o"
    assert main(["replay", "--world", "small_office", "--poses", str(replay_dir.parent / "p.csv"), "--out", str(out),
                 "--metrics", wanted]) == 0
    df = pd.read_csv(out / "metrics.csv")
    want = set(metrics.resolve(wanted.split(",")))
    assert set(df.metric) == want and not df.value.isna().any()
    comp = df[df.metric == "completeness_5cm"].sort_values("time_s").value.to_numpy()
    assert comp[0] <= comp[-1] and comp[-1] > 0
    ev = tmp_path / "ev"
    assert main(["evaluate", "--world", "small_office", "--map", str(out / "semantic_map.ply"), "--metrics", "field",
                 "--out", str(ev)]) == 0
    summary = json.loads((ev / "summary.json").read_text())
    last = df[df.time_s == df.time_s.max()].set_index("metric").value
    for name in ("omq", "ap50", "completeness_5cm", "miou"):
        assert last[name] == pytest.approx(summary[name], abs=1e-6), name
