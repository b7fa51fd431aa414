"""The RL env's contract (shapes, decisions that last as long as the drive, auto-reset,
determinism per key, jit and vmap), its candidates and reward by hand, and PPO: a short run
raises the return, a resumed run reaches the same parameters, the trained policy runs in a
session."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from conftest import optimized, room_xml

from rosmeery_jax.rl import network, ppo
from rosmeery_jax.rl.candidates import FEATURES, offer, window_means
from rosmeery_jax.rl.env import ExplorationEnv
from rosmeery_jax.rl.task import RLConfig, flat_obs, score, split_obs

BODIES_A = """
<body name="chair_1" pos="-1.0 -1.0 0"><geom type="box" pos="0 0 0.25" size="0.22 0.22 0.25"/></body>
<body name="desk_1" pos="1.0 0.6 0"><geom type="box" pos="0 0 0.4" size="0.5 0.3 0.4"/></body>
"""
BODIES_B = """
<body name="couch_1" pos="1.6 -1.2 0"><geom type="box" pos="0 0 0.3" size="0.4 0.8 0.3"/></body>
"""
CFG = RLConfig(decide_every=5, episode_s=1.5, candidates=4)  # 15 control steps per episode, <= 5 per decision
B = 4


@pytest.fixture(scope="module")
def worlds(tmp_path_factory):
    d = tmp_path_factory.mktemp("rl_worlds")
    a, b = d / "room_a.xml", d / "room_b.xml"
    a.write_text(room_xml(BODIES_A, {"chair_1": "chair", "desk_1": "desk"}, spawn=(0.3, -0.4, 0.0), half=2.2))
    b.write_text(room_xml(BODIES_B, {"couch_1": "couch"}, spawn=(-0.5, 0.5, 0.0), half=2.6))
    return [str(a), str(b)]


@pytest.fixture(scope="module")
def rl(worlds):
    from rosmeery_jax.env.world_bank import world_bank

    env = ExplorationEnv(world_bank(worlds), CFG)
    params = env.default_params
    reset = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))
    step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    return env, params, reset, step


def _episode(rl, seed: int, actions):
    env, params, reset, step = rl
    keys = jax.random.split(jax.random.key(seed), B)
    obs, state = reset(keys, params)
    out = [(obs, state, None, None, None)]
    for t, a in enumerate(actions):
        obs, state, reward, done, info = step(jax.vmap(lambda k: jax.random.fold_in(k, t))(keys), state,
                                              jnp.full(B, a, jnp.int32), params)
        out.append((obs, state, reward, done, info))
    return out


def test_shapes_and_auto_reset_onto_a_bank_world(rl):
    env, *_ = rl
    assert env.horizon == 15 and env.num_actions == 5
    steps = _episode(rl, 0, [1, 2, 3, 4, 0, 1, 2, 3, 4, 1])
    flat, state = steps[0][:2]
    f = len(FEATURES)
    assert flat.shape == (B, 5 * f + 2) and flat.dtype == jnp.float32
    assert env.observation_space(env.default_params).shape == flat.shape[1:]
    obs = split_obs(flat)
    assert obs.candidates.shape == (B, 5, f) and obs.robot.shape == (B, 2)
    assert float(obs.candidates.min()) >= -1 and float(obs.candidates.max()) <= 1
    assert not bool(obs.candidates[:, 0, FEATURES.index("valid")].any())  # no target yet to keep
    clock, rewards, ended, scores = np.zeros(B, int), np.zeros(B), np.zeros(B, int), []
    for obs, state, reward, done, info in steps[1:]:
        taken = np.asarray(info["steps"])
        assert reward.shape == (B,) and done.shape == (B,) and done.dtype == jnp.bool_
        assert ((taken >= 1) & (taken <= 5)).all()  # at most decide_every, at least one step
        clock, rewards = clock + taken, rewards + np.asarray(reward)
        np.testing.assert_array_equal(np.asarray(done), clock >= 15)  # the episode ends on its clock
        for b in np.flatnonzero(np.asarray(done)):  # a new episode: its clock and return back to 0
            assert int(state.env.t[b]) == 0 and float(state.ret[b]) == 0
            np.testing.assert_allclose(float(info["return"][b]), rewards[b], rtol=1e-5)
            scores.append(float(info["score"][b]))
        ended += np.asarray(done)
        clock, rewards = np.where(done, 0, clock), np.where(done, 0.0, rewards)
        np.testing.assert_array_equal(np.asarray(state.env.t), clock)
        assert (np.asarray(info["return"])[~np.asarray(done)] == 0).all()
    assert (ended >= 1).all() and all(0 <= x <= 1 for x in scores) and max(scores) > 0
    assert set(np.asarray(steps[0][1].world).tolist()) <= {0, 1}


def test_same_key_same_episode_other_keys_other_episodes(rl):
    first, again, other = (_episode(rl, s, [1, 3, 2]) for s in (3, 3, 4))
    for x, y in zip(first, again):
        for a, b in zip(jax.tree.leaves(x[:4]), jax.tree.leaves(y[:4])):
            np.testing.assert_array_equal(_host(a), _host(b))
    poses = np.asarray(first[-1][1].env.pose)
    assert not np.allclose(poses, np.asarray(other[-1][1].env.pose))
    assert len({tuple(np.round(p, 4)) for p in poses}) == B  # envs in one batch differ too


def _host(a):
    return np.asarray(jax.random.key_data(a) if jnp.issubdtype(a.dtype, jax.dtypes.prng_key) else a)


def test_jit_and_vmap_agree_with_one_env(rl):
    """One env alone equals its row of the batch (the batch the other tests compiled)."""
    env, params, reset, step = rl
    keys = jax.random.split(jax.random.key(7), B)
    obs1, state1 = jax.jit(env.reset)(keys[1], params)
    obs_b, state_b = reset(keys, params)
    np.testing.assert_allclose(obs1, obs_b[1], atol=1e-6)
    out1 = jax.jit(env.step)(keys[1], state1, jnp.int32(2), params)
    out_b = step(keys, state_b, jnp.full(B, 2, jnp.int32), params)
    np.testing.assert_allclose(out1[1].env.pose, out_b[1].env.pose[1], atol=1e-4)
    np.testing.assert_allclose(out1[2], out_b[2][1], atol=1e-4)
    assert not np.allclose(out_b[1].env.pose[0], out_b[1].env.pose[1])  # the rows are different envs


def test_window_means_by_hand():
    maps = np.zeros((5, 5, 2), np.float32)
    maps[2, 2, 0] = maps[0, 0, 0] = 1.0
    maps[..., 1] = 1.0
    rows, cols = jnp.asarray([2, 0, 1, 4]), jnp.asarray([2, 0, 1, 4])
    got = np.asarray(window_means(jnp.asarray(maps), (rows, cols), 1))
    np.testing.assert_allclose(got[:, 0], [1 / 9, 1 / 9, 2 / 9, 0.0], atol=1e-7)
    np.testing.assert_allclose(got[:, 1], [1.0, 4 / 9, 1.0, 4 / 9], atol=1e-7)  # beyond the grid counts as 0


def test_new_candidates_are_reachable_and_the_kept_target_is_offered_while_driving(rl):
    """Slots 1..K lie in the robot's connected component of open cells (SciPy by hand);
    slot 0 is the target being driven to, offered only while the navigator drives."""
    from scipy import ndimage

    from rosmeery_jax.rl.candidates import driving
    from rosmeery_jax.sim import occupancy

    env, params, _, _ = rl
    state = _episode(rl, 5, [1])[-1][1]
    e = env.env_in(params, int(state.world[0]))
    s = jax.tree.map(lambda a: a[0], state.env)
    o = jax.jit(lambda s, key: offer(e, s, s.nav.target, key, 300, 0.5))(s, jax.random.key(0))
    nav = e.navigator
    open_, _ = nav.open_cells(s.nav, s.pose, e.occupancy(s) == occupancy.OCCUPIED)
    labels, _ = ndimage.label(np.asarray(open_), structure=np.ones((3, 3)))
    here = tuple(int(v) for v in nav.coarse.cell(s.pose[:2]))
    cells = np.asarray(jnp.stack(nav.coarse.cell(o.targets[1:, :2]), -1))
    assert (labels[cells[:, 0], cells[:, 1]] == labels[here]).all() and len({tuple(c) for c in cells}) > 20
    np.testing.assert_array_equal(np.asarray(o.targets[0]), np.asarray(s.nav.target))
    valid = np.asarray(o.features[:, FEATURES.index("valid")])
    assert valid[0] == float(driving(s)) and (valid[1:] == 1).all()
    keep = np.asarray(o.features[:, FEATURES.index("keep")])
    assert keep[0] == 1 and (keep[1:] == 0).all()
    d = np.linalg.norm(np.asarray(o.targets[:, :2] - s.pose[:2]), axis=-1) / 10
    np.testing.assert_allclose(np.asarray(o.features[:, FEATURES.index("distance")]), d, atol=1e-6)


def test_an_untrained_network_picks_uniformly_among_the_offered_candidates():
    """With its last layer zero the network is the random walker's draw; a slot not on
    offer is never picked."""
    net = network.ActorCritic()
    f = len(FEATURES)
    feats = np.random.default_rng(0).uniform(0, 1, (5, f)).astype(np.float32)
    feats[:, FEATURES.index("valid")] = [0, 1, 1, 1, 1]
    flat = jnp.concatenate([jnp.asarray(feats).ravel(), jnp.asarray([0.0, 0.3])])
    params = net.init(jax.random.key(0), flat)
    params = jax.tree_util.tree_map_with_path(
        lambda path, a: jnp.zeros_like(a) if "Dense_2" in jax.tree_util.keystr(path) else a, params)
    logits, value = net.apply(params, flat)
    probs = np.asarray(jax.nn.softmax(logits))
    np.testing.assert_allclose(probs, [0, 0.25, 0.25, 0.25, 0.25], atol=1e-7)
    assert value.shape == ()


def test_reward_is_the_increase_of_the_metric(rl, worlds):
    """score() is the session's ORI of the world alone (padding objects left out)."""
    from rosmeery_jax import metrics

    env, params, reset, step = rl
    steps = _episode(rl, 1, [1, 2])
    state = steps[-1][1]
    for b in range(B):
        world = int(state.world[b])
        e = env.env_in(params, world)
        s = jax.tree.map(lambda a: a[b], state.env)
        alone = env.bank.worlds[world].truth
        n = len(alone.ps_G)
        log = jax.tree.map(lambda a: np.asarray(a)[None, :n], e.log(s))
        from rosmeery_jax.sim.knowledge import GroundTruthTable

        truth = GroundTruthTable(np.asarray(alone.ps_G), np.asarray(alone.num_predicates),
                                 np.asarray(alone.category_index))
        np.testing.assert_allclose(float(score(e, s, "ori")), metrics.compute(log, truth, ["ori"])["ori"][0],
                                   rtol=1e-5)
    r = np.asarray(steps[2][2]) + CFG.fail_penalty * np.asarray(_gave_up(steps[2][1]))
    np.testing.assert_allclose(r, CFG.reward_scale * (np.asarray(steps[2][1].score) - np.asarray(steps[1][1].score)),
                               atol=1e-5)


def _gave_up(state):
    from rosmeery_jax.rl.env import gave_up

    return jax.vmap(gave_up)(state.env)


def test_bad_config_is_refused(worlds):
    from rosmeery_jax.env.world_bank import world_bank

    bank = world_bank(worlds[:1])
    with pytest.raises(ValueError, match=r"^ExplorationEnv: config\.reward: 'speed' is not one of"):
        ExplorationEnv(bank, replace(CFG, reward="speed"))
    with pytest.raises(ValueError, match=r"^ExplorationEnv: config\.candidates: 0 must be a whole number"):
        ExplorationEnv(bank, replace(CFG, candidates=0))
    with pytest.raises(TypeError, match=r"^ExplorationEnv takes a WorldBank \(world_bank\(names\)\), not str"):
        ExplorationEnv(worlds[0])  # a world's name (an AttributeError)
    with pytest.raises(TypeError, match=r"^ExplorationEnv takes an RLConfig, not dict"):
        ExplorationEnv(bank, {"candidates": 4})


@pytest.mark.parametrize("text, needle", [
    ("[ppo]\nupdates = 0\n", "ppo.updates: 0 must be"),
    ("[ppo]\nclip_eps = nan\n", "ppo.clip_eps: nan must be a finite number"),  # keys as the file spells them
    ("[env.robot]\nmax_speed = -1.0\n", "env.robot.max_speed: -1.0 must be"),
    ("[rl]\nepisode_s = 1e9\n", "rl.episode_s: 1000000000.0 must be a finite number > 0 and at most 1e+06"),
    ("[rl]\ndecide_every = 1_000_000_000_000\n", "rl.decide_every: 1000000000000 must be a whole number in [1, "),
])
def test_the_train_command_refuses_a_bad_config_in_one_line(tmp_path, capsys, text, needle):
    """`rosmeery train` (which imports the trainer, and gymnax with it, only when it runs);
    an episode or a decision of more control steps than int32 counts was a traceback."""
    from rosmeery_jax.apps.cli import main

    toml, out = tmp_path / "ppo.toml", tmp_path / "o"
    toml.write_text(text)
    assert main(["train", "--config", str(toml), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{toml}: {needle}" in err[0] and not out.exists()


# --- PPO ---------------------------------------------------------------------------------


def _train_config(worlds, **ppo):
    """30 updates of 8 envs on the two rooms, a checkpoint after every update. One training
    run (the ``trained`` fixture) serves the learning, resume and session tests: a compile of
    the update is most of a run's time."""
    from rosmeery_jax.rl.ppo import PPOConfig, TrainConfig

    base = dict(num_envs=8, num_steps=6, updates=30, update_epochs=2, minibatches=2, checkpoint_every=1,
                anneal_lr=False, lr=2e-3, ent_coef=0.0)
    return TrainConfig(worlds=tuple(worlds), ppo=PPOConfig(**{**base, **ppo}),
                       rl=RLConfig(decide_every=5, episode_s=3.0, candidates=4, fail_penalty=0.5))


class AheadEnv(ExplorationEnv):
    """The env with a reward known by hand: the cosine of the chosen target's bearing from
    the robot's heading (+1 straight ahead, -1 behind). A policy that reads its candidates'
    features learns to pick those ahead; ORI gains are too rare in 3 s episodes in two
    small rooms to show learning within a test's budget (the real reward is tested above)."""

    def step_env(self, key, state, action, params):
        obs, stepped, _, done, info = super().step_env(key, state, action, params)
        pose, target = state.env.pose, state.targets[action]
        reward = jnp.cos(jnp.arctan2(target[1] - pose[1], target[0] - pose[0]) - pose[2])
        ret = state.ret + reward
        return obs, stepped._replace(ret=ret), reward, done, {**info, "return": jnp.where(done, ret, 0.0)}


@pytest.fixture(scope="module", autouse=True)
def ahead_reward():
    """Every training run of this module trains on :class:`AheadEnv`."""
    from rosmeery_jax.env import EnvConfig, world_bank

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(ppo, "make_env", lambda cfg: AheadEnv(
            world_bank(cfg.worlds, EnvConfig().with_overrides("config", **cfg.env)), cfg.rl))
        yield


@pytest.fixture(scope="module")
def trained(worlds, tmp_path_factory):
    """An uninterrupted run (its policy file serves the session test)."""

    out = tmp_path_factory.mktemp("train") / "whole"
    with optimized():  # 30 updates: XLA's optimisations repay their compile
        ppo.train(_train_config(worlds), out, progress=False)
    return out


def _each_update(change):
    """``ppo.make_update`` whose k-th update (from 1) runs as ``change(k, update, runner)``."""
    real = ppo.make_update

    def make(cfg, env):
        update, calls = real(cfg, env), []

        def once(runner):
            calls.append(1)
            return change(len(calls), update, runner)

        return once

    return make


def test_a_resumed_training_reaches_the_same_parameters(worlds, trained, tmp_path, monkeypatch):

    out = tmp_path / "interrupted"
    real = ppo.make_update

    def third_interrupted(k, update, runner):
        if k == 3:
            raise KeyboardInterrupt  # Ctrl-C during the third update: two are checkpointed
        return update(runner)

    monkeypatch.setattr(ppo, "make_update", _each_update(third_interrupted))
    with optimized(), pytest.raises(KeyboardInterrupt):  # compiled as the uninterrupted run was
        ppo.train(_train_config(worlds), out, progress=False)
    assert len(ppo.read_curve(out)) == 2 and not (out / "policy.msgpack").exists()
    monkeypatch.setattr(ppo, "make_update", real)
    with optimized():
        ppo.train(_train_config(worlds), out, resume=True, progress=False)
    _, _, whole = network.load_policy(trained / "policy.msgpack")
    _, _, resumed = network.load_policy(out / "policy.msgpack")
    for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(resumed)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    keep = ["update", "env_steps", "return", "loss", "entropy"]
    assert ppo.read_curve(out)[keep].equals(ppo.read_curve(trained)[keep])


def test_the_train_command_ends_with_the_mean_return_or_says_no_episode_ended():
    from rosmeery_jax.apps.cli import trained_summary

    curve = pd.DataFrame({"update": [1, 2, 3], "env_steps": [100, 200, 300], "return": [np.nan, 4.0, 5.0]})
    line = trained_summary(curve, Path("out"))
    assert line.startswith("trained 3 updates (300 env-steps; mean return of the last 10 updates 4.500) -> out/")
    line = trained_summary(curve.assign(**{"return": np.nan}), Path("out"))
    assert "no episode ended in the last 10 updates" in line and "nan" not in line


def test_resume_refuses_another_configuration(worlds, trained, tmp_path):
    import shutil

    from rosmeery_jax.core.errors import InputError

    out = tmp_path / "copy"
    shutil.copytree(trained, out)
    with pytest.raises(InputError, match="already holds a training run"):
        ppo.train(_train_config(worlds), out, progress=False)
    with pytest.raises(InputError, match="ppo"):
        ppo.train(_train_config(worlds, lr=1e-3), out, resume=True, progress=False)


def test_a_short_training_run_raises_the_return(trained):
    """30 updates on the two rooms: the mean episode return of the last 8 updates beats the
    first 8 (the policy learns from its candidates' features which lie ahead)."""

    curve = ppo.read_curve(trained)
    assert list(curve["update"]) == list(range(1, 31))
    assert (trained / "curve.png").read_bytes().startswith(b"\x89PNG")  # drawn at the end
    first, last = curve["return"].head(8).mean(), curve["return"].tail(8).mean()
    assert last > first + 0.2, (first, last)


def test_learned_and_gradient_nbv_run_in_a_session(worlds, trained, tmp_path):
    """Both new policies in one session (one set-up and compile for the two)."""
    from rosmeery_jax.apps.cli import main
    from rosmeery_jax.results.tables import load

    out = tmp_path / "session"
    spec = f"learned:{trained / 'policy.msgpack'}"
    assert main(["run", "--worlds", worlds[0], "--policies", f"{spec},gradient_nbv", "--seeds", "2",
                 "--duration", "8", "--detector", "oracle", "--quiet", "--out", str(out)]) == 0
    df = load(out)
    assert set(df.policy) == {"learned_whole", "gradient_nbv"} and df.value.notna().all()
    ori = df[df.metric == "ori"].groupby(["policy", "seed"]).value.max()
    assert (ori > 0).all(), ori
    assert "learned:" + str(trained / "policy.msgpack") in (out / "config.json").read_text()


def test_a_bad_policy_file_is_one_line(worlds, tmp_path, capsys):
    from rosmeery_jax.apps.cli import main

    bad = tmp_path / "policy.msgpack"
    bad.write_bytes(b"not msgpack at all")
    assert main(["run", "--worlds", worlds[0], "--policies", f"learned:{bad}", "--seeds", "1", "--duration", "2",
                 "--detector", "off", "--quiet", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "policy file" in err[0]
    assert not (tmp_path / "o").exists()


def test_in_sessions_the_policy_sends_the_navigator_to_its_best_scored_candidate(rl):
    """No sampling in sessions: of the offer of CANDIDATES draws, the target sent is the one
    the network scores highest, whatever the key (a sampled choice would differ for some)."""
    from rosmeery_jax.policies.learned import CANDIDATES, Choice, LearnedPolicy

    env, params, _, _ = rl
    state = _episode(rl, 5, [1])[-1][1]
    e = env.env_in(params, int(state.world[0]))
    s = jax.tree.map(lambda a: a[0], state.env)
    policy = LearnedPolicy(e)
    due = Choice(jnp.zeros(3, jnp.float32), jnp.int32(-10**6))  # a choice long due

    @jax.jit
    def choose(key):
        o = offer(e, s, due.target, key, CANDIDATES, policy.rl.radius)
        logits, _ = policy.net.apply(policy.params, flat_obs(o))
        return policy.decide(s, due, key)[0], o.targets, logits

    for k in range(6):
        target, targets, logits = choose(jax.random.key(k))
        assert targets.shape == (CANDIDATES + 1, 3)
        np.testing.assert_array_equal(np.asarray(target), np.asarray(targets[jnp.argmax(logits)]))


def test_the_shipped_policy_loads():
    from rosmeery_jax.policies.learned import SHIPPED

    rl, _, params = network.load_policy(SHIPPED)
    logits, value = network.ActorCritic().apply(params, jnp.ones(rl.obs_size))
    assert logits.shape == (rl.actions,) and value.shape == ()


def test_the_progress_bar_shows_the_last_return_an_episode_gave():
    nan = float("nan")
    curve = [{"update": 1, "return": nan}]
    assert ppo._last_return(curve) == "return - (no episode ended yet)"
    curve += [{"update": 2, "return": 0.25}, {"update": 3, "return": nan}]
    assert ppo._last_return(curve) == "return 0.250 (update 2)"  # not "return nan"
    curve.append({"update": 4, "return": -1.0})
    assert ppo._last_return(curve) == "return -1.000"


def test_a_diverged_training_run_stops_and_keeps_its_last_good_checkpoint(worlds, trained, tmp_path):
    """NaN losses (as lr = 1e30 gives from the second update) stop the run with one error,
    before the NaN state is saved: the checkpoint and curve stay those of update 2."""
    from rosmeery_jax.core.errors import InputError

    out = tmp_path / "diverged"

    def third_diverges(k, update, runner):
        runner, stats = update(runner)
        if k == 3:
            nan = jax.tree.map(lambda a: a * jnp.nan, runner.train.params)
            runner = runner._replace(train=runner.train.replace(params=nan))
            stats = {**stats, "loss": jnp.float32(jnp.nan)}
        return runner, stats

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(ppo, "make_update", _each_update(third_diverges))
        with optimized(), pytest.raises(InputError, match="update 3.*diverged.*loss"):  # compiled as `trained`
            ppo.train(_train_config(worlds), out, progress=False)
    assert not (out / "policy.msgpack").exists()
    assert list(ppo.read_curve(out)["update"]) == [1, 2]
    template = ppo.init_runner(_train_config(worlds), ppo.make_env(_train_config(worlds)))
    saved, done, _ = ppo.load_checkpoint(out / "checkpoint.msgpack", template)
    assert done == 2 and all(np.isfinite(np.asarray(a)).all() for a in jax.tree.leaves(saved.train.params))


@pytest.mark.parametrize("field, value, needle", [
    ("rl.decide_every", 0, "rl.decide_every"), ("rl.radius", float("nan"), "rl.radius"),
    ("rl.candidates", -4, "rl.candidates"), ("rl.candidates", 100_000, "rl.candidates"),
    ("params", "nan", "NaN"), ("params", "kernel", "shape")])
def test_a_broken_policy_file_is_refused_before_a_session(tmp_path, field, value, needle):
    import json as json_

    from flax import serialization

    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.policies.learned import SHIPPED
    from rosmeery_jax.session import load_config

    blob = serialization.msgpack_restore(SHIPPED.read_bytes())
    if field.startswith("rl."):
        rl = json_.loads(blob["rl"])
        rl[field[3:]] = value
        blob["rl"] = json_.dumps(rl)
    else:
        dense = blob["params"]["params"]["Dense_0"]
        if value == "nan":
            dense["bias"] = dense["bias"] * np.nan
        else:  # a layer of 63 units where the network has 64
            dense["kernel"], dense["bias"] = dense["kernel"][..., :63], dense["bias"][:63]
    path = tmp_path / "policy.msgpack"
    path.write_bytes(serialization.msgpack_serialize(blob))
    with pytest.raises(InputError, match=needle) as err:
        load_config(None, worlds="small_office", policies=f"learned:{path}", detector="off", out=str(tmp_path / "o"))
    assert str(path) in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("override, field", [({"ppo__clip_eps": -0.1}, "clip_eps"),
                                              ({"ppo__max_grad_norm": -1.0}, "max_grad_norm"),
                                              ({"ppo__lr": 0.0}, "lr"),
                                              ({"ppo__num_envs": 100_000_000}, "num_envs")])
def test_training_settings_out_of_range_are_refused(override, field):
    from rosmeery_jax.core.errors import InputError

    with pytest.raises(InputError, match=field):
        ppo.load_train_config(None, **override)


@pytest.mark.parametrize("change, needle", [
    ({"ppo": ppo.PPOConfig(lr=-1.0)}, "ppo.lr: -1.0 must be a finite number > 0"),  # it trained
    ({"ppo": ppo.PPOConfig(updates=2.5)}, "ppo.updates: 2.5 is not of type int"),
    ({"rl": RLConfig(reward_scale="x")}, "rl.reward_scale: 'x' is not of type float"),
    ({"worlds": "small_office"}, "worlds: 'small_office' must be a non-empty list"),
])
def test_a_python_built_training_config_is_checked_before_anything_is_written(tmp_path, change, needle):
    """``train(cfg, out)`` as docs/api.md names it: a TrainConfig built in Python skips the
    file loader, so ``train`` checks it."""
    from rosmeery_jax.core.errors import InputError

    with pytest.raises(InputError, match=re.escape(needle)):
        ppo.train(replace(ppo.TrainConfig(), **change), tmp_path / "o", progress=False)
    assert not (tmp_path / "o").exists()
    with pytest.raises(TypeError, match=r"^train takes a TrainConfig \(load_train_config\(path\)\), not dict"):
        ppo.train({"worlds": ["kitchen"]}, tmp_path / "o")  # an AttributeError
    assert not (tmp_path / "o").exists()


def test_an_episode_longer_than_int32_control_steps_is_refused():
    """The horizon is counted in int32: at 1 us a step, 1e6 s is 1e12 steps (an
    OverflowError once it reached JAX)."""
    assert RLConfig(episode_s=120.0).horizon(0.1) == 1200
    with pytest.raises(ValueError, match=r"episode_s 1e\+06 is 1000000000000 control steps of 1e-06 s"):
        RLConfig(episode_s=1e6).horizon(1e-6)
