"""The RL env's contract (shapes, auto-reset, determinism per key, jit and vmap), its goal
grid and reward by hand, and PPO: a short run raises the return, a resumed run reaches the
same parameters, the trained policy runs in a session."""

from __future__ import annotations

from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import room_xml
from rosmeery_jax.rl import network, ppo
from rosmeery_jax.rl.env import ExplorationEnv, RLConfig, goal, goal_offsets, score, split_obs

BODIES_A = """
<body name="chair_1" pos="-1.0 -1.0 0"><geom type="box" pos="0 0 0.25" size="0.22 0.22 0.25"/></body>
<body name="desk_1" pos="1.0 0.6 0"><geom type="box" pos="0 0 0.4" size="0.5 0.3 0.4"/></body>
"""
BODIES_B = """
<body name="couch_1" pos="1.6 -1.2 0"><geom type="box" pos="0 0 0.3" size="0.4 0.8 0.3"/></body>
"""
CFG = RLConfig(decide_every=5, episode_s=1.5, goal_grid=3, crop=16)  # 3 decisions per episode
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
    assert env.horizon == 3 and env.num_actions == 9
    steps = _episode(rl, 0, [1, 5, 7, 3])
    flat, state = steps[0][:2]
    assert flat.shape == (B, 16 * 16 * 4 + 4) and flat.dtype == jnp.float32
    assert env.observation_space(env.default_params).shape == flat.shape[1:]
    obs = split_obs(flat, 16)
    assert obs.maps.shape == (B, 16, 16, 4) and obs.pose.shape == (B, 4)
    assert float(obs.maps.min()) >= 0 and float(obs.maps.max()) <= 1
    assert float(obs.maps[..., 1].sum()) > 0  # the first scan already shows free space
    rewards = []
    for t, (obs, state, reward, done, info) in enumerate(steps[1:], 1):
        assert reward.shape == (B,) and done.shape == (B,) and done.dtype == jnp.bool_
        rewards.append(np.asarray(reward))
        assert bool(jnp.all(done == (t == 3)))
        if t == 3:  # a new episode: time back to 0, the finished episode's return reported
            assert bool(jnp.all(state.t == 0)) and bool(jnp.all(state.ret == 0))
            np.testing.assert_allclose(info["return"], np.sum(rewards, 0), rtol=1e-5)
            assert bool(jnp.all((info["score"] >= 0) & (info["score"] <= 1))) and float(info["score"].max()) > 0
        else:
            assert bool(jnp.all(state.t == t % 3)) and bool(jnp.all(info["return"] == 0))
    assert set(np.asarray(steps[0][1].world).tolist()) <= {0, 1}


def test_same_key_same_episode_other_keys_other_episodes(rl):
    first, again, other = (_episode(rl, s, [1, 5, 7]) for s in (3, 3, 4))
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


def test_goal_grid_by_hand():
    offsets = goal_offsets(RLConfig(goal_grid=3, goal_spacing=1.0))  # rows: ahead -1, 0, +1; cols: left
    pose = jnp.asarray([1.0, 2.0, np.pi / 2])  # facing +y: ahead is +y, left is -x
    np.testing.assert_allclose(goal(pose, 7, offsets), [1.0, 3.0, np.pi / 2], atol=1e-6)  # row 2 col 1: ahead
    np.testing.assert_allclose(goal(pose, 5, offsets), [0.0, 2.0, -np.pi], atol=1e-6)  # row 1 col 2: left
    np.testing.assert_allclose(goal(pose, 4, offsets), [1.0, 2.0, -np.pi / 2], atol=1e-6)  # centre: turn round
    back = goal(pose, 1, offsets)  # row 0 col 1: behind, facing away
    np.testing.assert_allclose(back[:2], [1.0, 1.0], atol=1e-6)
    assert abs(abs(float(back[2])) - np.pi / 2) < 1e-6 and float(back[2]) < 0


def test_reward_is_the_increase_of_the_metric(rl, worlds):
    """score() is the session's ORI of the world alone (padding objects left out)."""
    from rosmeery_jax.scoring import metrics

    env, params, reset, step = rl
    steps = _episode(rl, 1, [7, 7])
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

    with pytest.raises(ValueError, match="reward"):
        ExplorationEnv(world_bank(worlds[:1]), replace(CFG, reward="speed"))


# --- PPO ---------------------------------------------------------------------------------


def _train_config(worlds, **ppo):
    """30 updates of 8 envs on the two rooms, a checkpoint after every update. One training
    run (the ``trained`` fixture) serves the learning, resume and session tests: a compile of
    the update is most of a run's time."""
    from rosmeery_jax.rl.ppo import PPOConfig, TrainConfig

    base = dict(num_envs=8, num_steps=6, updates=30, update_epochs=2, minibatches=2, checkpoint_every=1,
                anneal_lr=False, lr=2e-3, ent_coef=0.0)
    return TrainConfig(worlds=tuple(worlds), ppo=PPOConfig(**{**base, **ppo}),
                       rl=RLConfig(decide_every=5, episode_s=3.0, goal_grid=3, crop=16, fail_penalty=0.5))


@pytest.fixture(scope="module")
def trained(worlds, tmp_path_factory):
    """An uninterrupted run (its policy file serves the session test)."""

    out = tmp_path_factory.mktemp("train") / "whole"
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
    with pytest.raises(KeyboardInterrupt):
        ppo.train(_train_config(worlds), out, progress=False)
    assert len(ppo.read_curve(out)) == 2 and not (out / "policy.msgpack").exists()
    monkeypatch.setattr(ppo, "make_update", real)
    ppo.train(_train_config(worlds), out, resume=True, progress=False)
    _, _, whole = network.load_policy(trained / "policy.msgpack")
    _, _, resumed = network.load_policy(out / "policy.msgpack")
    for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(resumed)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    keep = ["update", "env_steps", "return", "loss", "entropy"]
    assert ppo.read_curve(out)[keep].equals(ppo.read_curve(trained)[keep])


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
    first 8 (the policy learns to pick goal cells it can reach and that show new surface)."""

    curve = ppo.read_curve(trained)
    assert list(curve["update"]) == list(range(1, 31))
    assert (trained / "curve.png").read_bytes().startswith(b"\x89PNG")  # drawn at the end
    first, last = curve["return"].head(8).mean(), curve["return"].tail(8).mean()
    assert last > first + 0.2, (first, last)


def test_learned_and_gradient_nbv_run_in_a_session(worlds, trained, tmp_path):
    """Both new policies in one session (one set-up and compile for the two)."""
    from rosmeery_jax.apps.cli import main
    from rosmeery_jax.scoring.results import load

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


def test_the_shipped_policy_loads():
    from rosmeery_jax.policies.learned import SHIPPED

    rl, _, params = network.load_policy(SHIPPED)
    logits, value = network.ActorCritic(rl.actions, rl.crop).apply(params, _blank_obs(rl))
    assert logits.shape == (rl.actions,) and value.shape == ()


def _blank_obs(rl):
    return jnp.zeros(rl.crop * rl.crop * 4 + 4)


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
        with pytest.raises(InputError, match="update 3.*diverged.*loss"):
            ppo.train(_train_config(worlds), out, progress=False)
    assert not (out / "policy.msgpack").exists()
    assert list(ppo.read_curve(out)["update"]) == [1, 2]
    template = ppo.init_runner(_train_config(worlds), ppo.make_env(_train_config(worlds)))
    saved, done, _ = ppo.load_checkpoint(out / "checkpoint.msgpack", template)
    assert done == 2 and all(np.isfinite(np.asarray(a)).all() for a in jax.tree.leaves(saved.train.params))


@pytest.mark.parametrize("field, value, needle", [
    ("rl.decide_every", 0, "rl.decide_every"), ("rl.crop_resolution", float("nan"), "rl.crop_resolution"),
    ("rl.crop", -4, "rl.crop"), ("rl.crop", 100_000, "rl.crop"), ("rl.goal_grid", 7, "params"),
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
        conv = blob["params"]["params"]["Conv_0"]
        if value == "nan":
            conv["bias"] = conv["bias"] * np.nan
        else:  # a kernel of 15 output channels where the network has 16
            conv["kernel"], conv["bias"] = conv["kernel"][..., :15], conv["bias"][:15]
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
        ppo.load_config(None, **override)
