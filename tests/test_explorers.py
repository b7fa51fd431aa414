"""Explorers: the soft coverage and gradient_nbv's view model against finite differences;
no policy reads hidden ground truth (gradient_nbv's session test is in test_rl.py)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import room_xml

from rosmeery_jax.raycast.sensors import CameraConfig
from rosmeery_jax.sim.coverage import CoverageConfig, SampleTable, observed_soft

BODIES = """
<body name="chair_1" pos="-1.0 -1.0 0"><geom type="box" pos="0 0 0.25" size="0.22 0.22 0.25"/></body>
<body name="desk_1" pos="1.2 0.6 0"><geom type="box" pos="0 0 0.4" size="0.5 0.3 0.4"/></body>
<body name="couch_1" pos="-1.2 1.2 0"><geom type="box" pos="0 0 0.3" size="0.4 0.6 0.3"/></body>
"""


def _fd_check(f, x, eps=1e-5, rtol=1e-3, atol=1e-6):
    """f: (3,) float64 -> scalar; its jax.grad against central differences (both compiled:
    op by op, a rendered view takes seconds per evaluation)."""
    grad = np.asarray(jax.jit(jax.grad(f))(x))
    f = jax.jit(f)
    fd = np.array([(f(x + eps * e) - f(x - eps * e)) / (2 * eps) for e in np.eye(3)])
    assert np.abs(grad).max() > 1e-3  # the check is not trivially 0 = 0
    np.testing.assert_allclose(grad, fd, rtol=rtol, atol=atol)


def test_soft_coverage_gradient_matches_finite_differences():
    with jax.enable_x64(True):
        rng = np.random.default_rng(0)
        pts = np.stack([rng.uniform(1.0, 4.0, 60), rng.uniform(-1.5, 1.5, 60), rng.uniform(0.1, 0.9, 60)])
        normals = np.stack([-np.ones(60), np.zeros(60), np.zeros(60)])
        table = SampleTable(jnp.asarray(pts), jnp.asarray(normals), jnp.zeros(60, jnp.int32), 1)
        cfg = CoverageConfig(soft=True, temperature=0.3)
        cam = CameraConfig()
        depth = jnp.full((cam.height, cam.width), 3.0)
        weights = jnp.asarray(rng.uniform(0.5, 1.5, 60))

        def total(pose):
            return jnp.sum(weights * observed_soft(table, cfg, cam, pose, depth))

        _fd_check(total, jnp.asarray([0.2, -0.1, 0.15]))
        # and in the rendered depth: observing more when the occluder is farther
        d_depth = jax.grad(lambda d: jnp.sum(observed_soft(table, cfg, cam, jnp.zeros(3), d)))(depth)
        assert float(d_depth.sum()) > 0 and bool(jnp.all(d_depth >= 0))


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    path = tmp_path_factory.mktemp("explorers") / "room.xml"
    path.write_text(room_xml(BODIES, {"chair_1": "chair", "desk_1": "desk", "couch_1": "couch"},
                             spawn=(0.2, -0.3, 0.0), half=2.4))
    return str(path)


@pytest.fixture(scope="module")
def midrun(room):
    """An env with detector labels, 4 s into a run (a map, some coverage, two held labels)."""
    from rosmeery_jax.env import make

    env = make(room, labels="detections", start_yaw="spawn")
    step = jax.jit(env.step)
    state = jax.jit(env.reset)(jax.random.key(0))
    for t in range(40):
        state = step(state, jnp.asarray([1.2, 0.4, 0.3 * t], jnp.float32))
    state = env.attach(state, jnp.asarray([1, 2]), jnp.asarray([3, 4]), jnp.asarray([0.9, 0.8]))
    return env, state


def test_gradient_nbv_view_model_matches_finite_differences(midrun):
    from rosmeery_jax.policies.gradient_nbv import GradientNBVPolicy

    env, state = midrun
    with jax.enable_x64(True):
        policy = GradientNBVPolicy(env)
        opacity = policy.opacity(state).astype(jnp.float64)
        table, held = policy.belief(state)
        table = jax.tree.map(lambda a: a.astype(jnp.float64) if a.dtype == jnp.float32 else a, table)
        assert float(held.sum()) > 0  # something to look at
        centre = np.asarray(jnp.sum(table.points[:2] * held, 1) / held.sum())
        pose = jnp.asarray([centre[0] + 1.3, centre[1] + 0.4, np.pi + 0.3])  # looking at the belief
        _fd_check(lambda q: policy.gain(opacity, table, held.astype(jnp.float64), q), pose, eps=1e-6, rtol=2e-3,
                  atol=1e-5)
        # the rendered depth itself differentiates in the pose
        d = jax.jit(jax.jacfwd(lambda q: policy.render(opacity, q)[0]))(pose)
        assert float(jnp.abs(d).sum()) > 0


def test_gradient_nbv_hands_over_to_frontier_only_when_no_view_promises_min_gain(midrun):
    """Mid-run, with held labels, some view promises a little: the default ``min_gain``
    drives to it; a ``min_gain`` no view can promise leaves the choice to frontier."""
    from rosmeery_jax.policies.gradient_nbv import GradientNBVPolicy

    env, state = midrun
    key = jax.random.key(5)
    viewing, refusing = GradientNBVPolicy(env), GradientNBVPolicy(env, min_gain=1e9)
    target, ps = jax.jit(viewing.decide)(state, viewing.init(key), key)
    assert not bool(ps.exploring)
    target_r, ps_r = jax.jit(refusing.decide)(state, refusing.init(key), key)
    assert bool(ps_r.exploring)
    start = refusing.init(key)
    f_target, _ = refusing.frontier.decide(state, start.frontier._replace(target=start.target), key)  # its fallback
    np.testing.assert_allclose(np.asarray(target_r), np.asarray(f_target), atol=1e-6)
    assert not np.allclose(np.asarray(target), np.asarray(target_r))


def _taint(env, state):
    """The env's world with every piece of ground truth the robot has not perceived replaced
    by noise: unobserved samples, unlabelled objects' categories, object sample counts, the
    predicate tables, the raycast scene, the physics, the reachable cells."""
    rng = np.random.default_rng(1)
    d = env.data
    k = env.labelled_knowledge(state)

    def noise(a):
        a = np.asarray(a)
        if np.issubdtype(a.dtype, np.integer):
            return jnp.asarray(rng.integers(0, 3, a.shape).astype(a.dtype))
        return jnp.asarray(rng.uniform(-3, 3, a.shape).astype(a.dtype))

    seen = np.asarray(k.seen) > 0
    samples = d.samples
    samples = SampleTable(jnp.where(seen, samples.points, noise(samples.points)),
                          jnp.where(seen, samples.normals, noise(samples.normals)), samples.object,
                          samples.num_objects)
    held = np.asarray(k.label) >= 0
    return env.with_data(d._replace(
        physics=jax.tree.map(noise, d.physics), rays=jax.tree.map(noise, d.rays),
        laser_rays=jax.tree.map(noise, d.laser_rays), samples=samples,
        category=jnp.where(held, d.category, noise(d.category)), ps_G=d.ps_G * 3 + 1,
        declared=noise(d.declared), correct=noise(d.correct), reachable=noise(d.reachable)))


@pytest.mark.parametrize("name", ["random", "frontier", "frontier_nearest", "semantic_nbv", "gradient_nbv",
                                  "learned"])
def test_no_policy_reads_hidden_ground_truth(midrun, name):
    """A policy deciding in the tainted world must decide exactly as in the real one."""
    from rosmeery_jax.policies import POLICIES, make_policy

    assert set(POLICIES) == {"random", "frontier", "frontier_nearest", "semantic_nbv", "gradient_nbv", "learned"}
    env, state = midrun
    with pytest.raises(TypeError, match=r"^make_policy: env must be a RobotEnv .*not str"):
        make_policy(name, "kitchen")  # a world's name was taken, and failed at the first decision
    policy = make_policy(name, env)
    key = jax.random.key(3)
    pstate = policy.init(key)
    decide = jax.jit(lambda data: policy.bind(env.with_data(data)).decide(state, pstate, key))  # one compile
    real, other = decide(env.data), decide(_taint(env, state).data)
    for a, b in zip(jax.tree.leaves(real), jax.tree.leaves(other)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_the_taint_check_catches_a_policy_that_reads_truth(midrun):
    """A cheat that heads for the nearest unobserved ground-truth sample is caught."""
    from rosmeery_jax.policies.base import Policy

    class Cheat(Policy):
        def decide(self, state, pstate, key):
            pts = self.env.sk.table.points[:2].T
            unseen = self.env.labelled_knowledge(state).seen == 0
            d = jnp.where(unseen, jnp.linalg.norm(pts - state.pose[:2], axis=1), 1e9)
            return jnp.concatenate([pts[jnp.argmin(d)], jnp.zeros(1)]), pstate

    env, state = midrun
    cheat = Cheat(env)
    key = jax.random.key(0)
    real = cheat.decide(state, cheat.init(key), key)[0]
    other = cheat.bind(_taint(env, state)).decide(state, cheat.init(key), key)[0]
    assert not np.array_equal(np.asarray(real), np.asarray(other))
