"""Third-party RL on our envs, unmodified: Gymnasium's checker and Stable-Baselines3 PPO on
``rosmeery_jax.gym``; gymnax's wrappers and rejax PPO on ``rosmeery_jax.rl.ExplorationEnv``."""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import room_xml

from rosmeery_jax.gym import Env, GymConfig, VectorEnv
from rosmeery_jax.mapping.protocol import MapState

BODIES = """
<body name="chair_1"><geom type="box" pos="1.0 0.6 0.25" size="0.25 0.25 0.25"/></body>
<body name="desk_1"><geom type="box" pos="-1.0 -0.8 0.35" size="0.5 0.3 0.35"/></body>
"""
# 48 x 40 pixels: the smallest Stable-Baselines3's image encoder takes is 36 x 36
SMALL = GymConfig(duration=3.0, env={"camera": {"rgb_width": 48, "rgb_height": 40}})
# The vector env tests share one setting (two robots, the privileged view), so one compiled step.
VECTOR = GymConfig(duration=3.0, privileged=True, env=SMALL.env)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    path = tmp_path_factory.mktemp("gym") / "room.xml"
    path.write_text(room_xml(BODIES, {"chair_1": "chair", "desk_1": "desk"}, spawn=(0.0, 0.0, 0.0), half=2.2))
    return str(path)


@pytest.fixture(scope="module")
def env(world):
    return Env(world, SMALL)


def test_gymnasiums_env_checker_passes(env):
    from gymnasium.utils.env_checker import check_env

    check_env(env, skip_render_check=True)


def test_a_non_finite_or_misshapen_action_and_a_seed_beyond_int32_are_refused(env):
    """A NaN target was driven to; an action of the wrong size was a reshape error; a seed
    of 2**80 an OverflowError inside JAX."""
    env.reset(seed=0)
    state = env.vec.state
    for bad, needle in ((np.float32([np.nan, 0, 0]), r"^an action of shape \(3,\) must be finite"),
                        (np.float32([1, 0]), r"^an action of shape \(2,\) must be finite numbers of shape \(3,\)$")):
        with pytest.raises(ValueError, match=needle):
            env.step(bad)
    assert env.vec.state is state and env.vec.t == 0  # nothing stepped
    with pytest.raises(ValueError, match=r"seed 2147483648 must be at most 2\*\*31 - num_envs \(2147483647\)"):
        env.reset(seed=2**31)


def test_observations_are_what_the_robot_perceives_and_episodes_end_at_the_duration(env):
    obs, _ = env.reset(seed=3)
    assert set(obs) == {"rgb", "depth", "scan", "pose", "occupancy", "nav_status", "time"}  # no ground truth
    again, _ = env.reset(seed=3)
    for k in obs:
        np.testing.assert_array_equal(obs[k], again[k])  # the same seed, the same start
    rewards = []
    for t in range(1, 4):
        target = np.float32([obs["pose"][0] + 1.0, obs["pose"][1], 0.0])
        obs, reward, terminated, truncated, _ = env.step(target)
        assert env.observation_space.contains(obs) and obs["time"][0] == pytest.approx(t * 1.0)
        assert not terminated and truncated == (t == 3)  # 3 decisions of 1 s
        rewards.append(reward)
    assert sum(rewards) > 0 and min(rewards) >= 0  # ORI only grows while the robot looks around
    assert (obs["occupancy"] == 0).any() and (obs["occupancy"] == 1).any()  # its own map: free and walls
    with pytest.raises(RuntimeError, match=r"truncated: call reset\(\) first"):  # not a new episode, silently
        env.step(np.float32([0, 0, 0]))
    obs, _ = env.reset(seed=3)
    assert obs["time"][0] == 0.0
    with pytest.raises(TypeError, match="options must be a dict or None, not str"):
        env.reset(options="nope")


@pytest.mark.parametrize("duration", [3.05, 0.4])
def test_a_duration_that_is_not_whole_decisions_is_refused(world, duration):
    """3.05 s ran as 3 decisions and 0.4 s as one of 1 s; sessions refuse both, and so does the env."""
    with pytest.raises(ValueError, match=f"duration {duration:g} s is not a whole number of decisions \\(1 s each\\)"):
        VectorEnv([world], 1, GymConfig(duration=duration))


@pytest.mark.parametrize("duration", [float("inf"), float("nan"), 0.0])
def test_a_duration_that_is_no_finite_positive_number_is_refused(world, duration):
    """An infinite episode was an OverflowError from counting its decisions."""
    with pytest.raises(ValueError, match="duration.* must be a finite number"):
        VectorEnv([world], 1, GymConfig(duration=duration))


@pytest.mark.parametrize("config, num_envs, needle", [
    (GymConfig(duration="3"), 1, "GymConfig: duration: '3' is not of type float"),  # a TypeError
    (GymConfig(decide_every=2.5), 1, "decide_every: 2.5 is not of type int"),
    (GymConfig(camera="no"), 1, "camera: 'no' is not of type bool"),  # taken as True
    (GymConfig(), 2.5, "num_envs 2.5 must be a whole number"),  # ran 3 robots
])
def test_a_config_of_the_wrong_types_is_refused(world, config, num_envs, needle):
    with pytest.raises(ValueError, match=re.escape(needle)):
        VectorEnv([world], num_envs, config)


def test_the_vector_env_batches_robots_over_worlds_and_scores_a_submitted_map(world):
    vec = VectorEnv([world], 2, VECTOR)
    obs, _ = vec.reset(seed=0)
    assert obs["rgb"].shape == (2, 40, 48, 3) and obs["privileged_coverage"].shape[0] == 2
    obs, reward, _, truncated, _ = vec.step(np.zeros((2, 3), np.float32))
    assert reward.shape == (2,) and not truncated.any()
    assert len({tuple(p) for p in np.round(vec.poses(), 4)}) == 2  # robots differ (own keys)
    truth = vec.bank.worlds[0].truth
    samples = np.asarray(truth.samples.points)[np.asarray(truth.samples.object) == 0]
    perfect = MapState(samples, np.zeros(len(samples), np.int64), np.array([truth.category_index[0]]), np.ones(1))
    scores = vec.submit_map(0, perfect)  # one object mapped whole and labelled: ORI is half of two objects
    assert scores["ori"] == pytest.approx(0.5) and scores["cori"] == pytest.approx(0.5)
    assert vec.submit_map(1, MapState(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64),
                                      np.zeros(0)))["ori"] == 0.0
    # a malformed map or robot is one error, checked as a mapper's map is (they reached the scorer)
    nan = perfect._replace(points=np.full_like(samples, np.nan))
    with pytest.raises(ValueError, match="submit_map: robot 0: the map: points that are not finite"):
        vec.submit_map(0, nan)
    with pytest.raises(ValueError, match=r"robot 2: there are 2 \(0 to 1\)"):
        vec.submit_map(2, perfect)


def test_the_pytorch_agent_example_explores_through_the_vector_env(world):
    pytest.importorskip("torch")
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "examples" / "torch_agent.py"
    spec = importlib.util.spec_from_file_location("torch_agent", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    vec = VectorEnv([world], 2, VECTOR)  # the agent reads no privileged field
    agent = example.TorchFrontier(vec)
    obs, _ = vec.reset(seed=0)
    start, gained = obs["pose"][:, :2].copy(), 0.0
    for _ in range(3):
        target = agent.act(obs)
        assert vec.action_space.contains(target)
        obs, reward, _, _, _ = vec.step(target)
        gained += reward
    assert (gained > 0).all() and (np.hypot(*(obs["pose"][:, :2] - start).T) > 0.1).all()  # it drove


def test_stable_baselines3_ppo_trains_on_the_env(env):
    torch = pytest.importorskip("torch")
    from stable_baselines3 import PPO

    model = PPO("MultiInputPolicy", env, n_steps=8, batch_size=8, n_epochs=1, seed=0, device="cpu")
    before = [p.detach().clone() for p in model.policy.parameters()]
    model.learn(16)
    after = list(model.policy.parameters())
    assert all(torch.isfinite(p).all() for p in after)
    assert sum(not torch.equal(a, b) for a, b in zip(before, after)) == len(before)  # every layer learned


def test_rejax_ppo_and_gymnax_wrappers_run_on_the_exploration_env(world):
    import rejax
    from gymnax.wrappers.purerl import FlattenObservationWrapper, LogWrapper

    from rosmeery_jax.env.world_bank import world_bank
    from rosmeery_jax.rl.env import ExplorationEnv, RLConfig

    env = ExplorationEnv(world_bank([world]), RLConfig(decide_every=5, episode_s=1.5, candidates=4))
    params = env.default_params
    assert params.max_steps_in_episode == 15 and env.action_space(params).n == 5
    obs, state = LogWrapper(FlattenObservationWrapper(env)).reset(jax.random.key(0), params)
    assert obs.shape == env.observation_space(params).shape == (5 * 10 + 2,)
    algo = rejax.PPO.create(env=env, env_params=params, total_timesteps=64, num_envs=4, num_steps=8, num_epochs=1,
                            num_minibatches=2, eval_freq=32, skip_initial_evaluation=True)
    algo = algo.replace(eval_callback=lambda a, ts, rng: jnp.float32(0))  # its 128-episode evaluation is slow here
    init = algo.init_state(jax.random.key(0))
    trained, _ = jax.jit(algo.train)(jax.random.key(0))
    moved = jax.tree.map(lambda a, b: bool(jnp.any(a != b)), init.actor_ts.params, trained.actor_ts.params)
    assert all(jax.tree.leaves(moved)) and int(trained.global_step) == 64
