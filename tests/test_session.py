"""Policies and the benchmark session: results folder, resume, config errors, notebook."""

from __future__ import annotations

import json
import os
from dataclasses import replace

import jax
import numpy as np
import pandas as pd
import pytest

from rosmeery_jax.apps.cli import main
from rosmeery_jax.apps.columns import columns
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.env import make
from rosmeery_jax.policies import make_policy
from rosmeery_jax.results import tables
from rosmeery_jax.session.config import SessionConfig
from rosmeery_jax.session.folder import check_out
from rosmeery_jax.session.schedule import frames_before, log_every

# Detector off: the YOLO session has its own test (test_detector); this setting is also
# test_hardening's, so a program one compiles the other can load from the persistent cache.
_ARGS = ["--worlds", "small_office", "--seeds", "2", "--detector", "off", "--duration", "4", "--quiet"]


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("session") / "out"
    assert main(["run", *_ARGS, "--policies", "random", "--out", str(out)]) == 0
    return out


def test_session_writes_the_results_folder(session_dir):
    df = tables.load(session_dir)
    assert list(df.columns) == ["world", "policy", "detector", "mapper", "seed", "time_s", "metric", "value"]
    assert set(df.seed) == {0, 1} and set(df.policy) == {"random"}
    assert set(df.metric) >= {"ori", "cori", "opi"}
    times = sorted(df.time_s.unique())
    assert times[0] == 0.0 and times[-1] == pytest.approx(4.0) and np.all(np.diff(times) <= 1.0 + 1e-9)
    for _, g in df[df.metric == "ori"].groupby("seed"):
        assert np.all(np.diff(g.sort_values("time_s").value) >= -1e-9)
    assert ((df.value >= 0) & (df.value <= 1)).all()
    objects = pd.read_csv(session_dir / "objects.csv")
    assert len(objects) == 2 * 11
    cfg = json.loads((session_dir / "config.json").read_text())
    assert cfg["session"]["seeds"] == 2 and "jax" in cfg["versions"]
    assert (session_dir / "plots" / "small_office_ori.png").stat().st_size > 1000
    assert (session_dir / "maps" / "small_office__random__seed1.ply").exists()


def test_existing_results_are_refused_without_resume_and_resume_skips_finished_runs(session_dir, capsys):
    assert main(["run", *_ARGS, "--policies", "random", "--out", str(session_dir)]) == 2
    assert "--resume" in capsys.readouterr().err
    run_file = session_dir / "runs" / "small_office__random.metrics.csv"
    before = run_file.stat().st_mtime_ns
    assert main(["run", *_ARGS, "--policies", "random,frontier", "--out", str(session_dir), "--resume"]) == 0
    assert run_file.stat().st_mtime_ns == before  # finished run not redone
    table = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith(("world ", "small_office "))]
    assert table[0].split()[:3] == ["world", "policy", "metric"] and len(table) == 1 + 2 * 5
    assert {ln.index("[< 3 seeds]") for ln in table[1:]} == {table[0].index("95% CI")}  # columns line up
    df = tables.load(session_dir)
    assert set(df.policy) == {"random", "frontier"}
    # The interrupted-then-resumed folder equals one uninterrupted session.
    whole = session_dir.parent / "whole"
    assert main(["run", *_ARGS, "--policies", "random,frontier", "--out", str(whole)]) == 0
    key = ["world", "policy", "seed", "metric", "time_s"]
    a = df.sort_values(key).reset_index(drop=True)
    b = tables.load(whole).sort_values(key).reset_index(drop=True)
    pd.testing.assert_frame_equal(a, b)
    # A resume with a different setting is refused, naming the field.
    assert main(["run", *_ARGS[:-3], "--duration", "8", "--quiet", "--out", str(session_dir), "--resume"]) == 2
    assert "duration" in capsys.readouterr().err


def test_a_folder_begun_before_a_setting_existed_resumes_at_its_default_only(tmp_path):
    cfg = SessionConfig(worlds=("small_office",), policies=("random",), detector="off", out=str(tmp_path / "o"))
    record = check_out(cfg, resume=False).record
    del record["session"]["detect_every"], record["session"]["sample_s"]  # as an older version wrote it
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "config.json").write_text(json.dumps(record))
    assert not check_out(cfg, resume=True).fresh
    with pytest.raises(InputError, match="sample_s.*was 1.0, now 2.0"):
        check_out(replace(cfg, sample_s=2.0), resume=True)
    with pytest.raises(InputError, match="detect_every.*was 0, now 5"):
        check_out(replace(cfg, detect_every=5), resume=True)


def test_text_tables_are_as_wide_as_their_widest_cell():
    out = columns(("metric", "final"), [("ori", "0.5"), ("labelled_share", "0.125")], right=(1,))
    assert out.splitlines() == ["metric          final",
                                "ori               0.5",
                                "labelled_share  0.125"]


def test_plot_command_redraws(session_dir, capsys):
    for p in (session_dir / "plots").glob("*.png"):
        p.unlink()
    assert main(["plot", str(session_dir)]) == 0
    assert (session_dir / "plots" / "small_office_opi.png").exists()


@pytest.mark.parametrize("toml, field", [
    ("seeds = 0\n", "seeds"),
    ("policies = ['teleport']\n", "policies"),
    ("colour = 'red'\n", "colour"),
    ("duration = 2.55\n", "duration"),
    ("detector = 'magic'\n", "detector"),
    ("metrics = ['ori', 'nope']\n", "metrics"),
    ("seeds = [\n", "file"),
    ("detect_every = 3\n", "detect_every"),  # not a divisor of decide_every (10)
    ("detect_every = -1\n", "detect_every"),
    ("detect_every = 5\ndetector = 'off'\n", "detect_every"),  # frames for no detector
    ("first_seed = -1\n", "first_seed"),
    ("first_seed = 2147483647\nseeds = 2\n", "first_seed"),  # its last seed past int32 keys
])
def test_bad_config_is_one_line_naming_file_and_field(tmp_path, capsys, toml, field):
    path = tmp_path / "session.toml"
    path.write_text(toml)
    assert main(["run", "--config", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and field in err and str(path) in err
    assert not (tmp_path / "o").exists()


def test_policies_pick_new_targets_and_frontier_ones_lie_inside():
    # The random walker's targets are checked against its own map in test_navigation.
    env = make("small_office")
    keys = jax.random.split(jax.random.key(0), 2)
    state = jax.jit(jax.vmap(env.reset))(keys)
    for name in ("frontier", "frontier_nearest", "random", "semantic_nbv"):
        policy = make_policy(name, env)
        target, _ = jax.jit(jax.vmap(policy.decide))(state, jax.vmap(policy.init)(keys), keys)
        for t in np.asarray(target):
            i, j = env.world.free_space.cell(t[:2])
            if name != "random":  # frontier targets lie in space the robot has seen free
                assert env.world.free_space.interior[i, j]
        # A new target: elsewhere, or (a frontier cell under the robot) here facing the unknown.
        assert not np.allclose(np.asarray(target), np.asarray(state.pose))


def test_example_notebook_runs_on_a_results_folder(session_dir, tmp_path):
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.read(os.path.join(os.path.dirname(__file__), "..", "experiments", "analysis.ipynb"), as_version=4)
    client = NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}})
    os.environ["ROSMEERY_RESULTS"] = str(session_dir)
    client.execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not any(o.get("output_type") == "error" for o in outputs)
    assert (tmp_path / "curves.png").exists()


def test_frontier_mapped_area_grows_and_exploration_ends():
    from rosmeery_jax.sim import occupancy

    env = make("small_office", start_yaw="spawn")
    policy = make_policy("frontier", env)
    keys = jax.random.split(jax.random.key(0), 1)
    state, pstate = jax.jit(lambda k: (jax.vmap(env.reset)(k), jax.vmap(policy.init)(k)))(keys)

    def ten_seconds(s, ps, k):  # 10 decisions, each followed by 10 steps of 0.1 s
        def decide(carry, _):
            s, ps, k = carry
            k, sub = jax.random.split(k)
            target, ps = policy.decide(s, ps, sub)
            s = jax.lax.fori_loop(0, 10, lambda _, s: env.step(s, target), s)
            return (s, ps, k), None
        return jax.lax.scan(decide, (s, ps, k), None, length=10)[0]

    # compiled once from the first arguments: a later call's (committed) arrays would compile it again
    chunk = jax.jit(jax.vmap(ten_seconds)).lower(state, pstate, keys).compile()
    grids = jax.jit(jax.vmap(env.occupancy))

    def free_cells(s):
        return int((np.asarray(grids(s)) == occupancy.FREE).sum())

    def known_cells(s):
        return int((np.asarray(grids(s)) != occupancy.UNKNOWN).sum())

    free, known, done, poses = [free_cells(state)], [known_cells(state)], [], []
    for _ in range(5):
        state, pstate, keys = chunk(state, pstate, keys)
        free.append(free_cells(state))
        known.append(known_cells(state))
        done.append(bool(pstate.done[0]))
        poses.append(np.asarray(state.pose[0]))
    # The known area is what grows: a cell at the edge of what the laser sees may flip
    # between free and occupied, or back to unknown (a hit after one miss leaves its
    # log-odds inside the threshold), so it may lose a few cells between checks.
    assert free[1] > 2 * free[0] and known[-1] > known[1]
    assert all(b >= 0.99 * a for a, b in zip(known, known[1:])), known
    assert done[-1] and not done[0]  # explored, then no frontier left
    # It has mapped most of what is reachable, and once done it stays put.
    assert free[-1] >= 0.8 * env.world.free_space.reachable.sum()
    first = done.index(True)
    assert all(np.allclose(p, poses[first], atol=0.05) for p in poses[first + 1:])


def test_an_exported_map_evaluates_to_the_sessions_own_scores(session_dir, tmp_path):
    out = tmp_path / "eval"
    ply = session_dir / "maps" / "small_office__random__seed1.ply"
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(out)]) == 0
    ours = pd.read_csv(out / "metrics.csv").set_index("metric").value
    df = tables.load(session_dir)
    run = df[(df.policy == "random") & (df.seed == 1)]  # other tests add runs to this folder
    final = run[run.time_s == run.time_s.max()].set_index("metric").value
    for metric in ("ori", "cori", "opi", "opi_strict"):
        assert ours[metric] == pytest.approx(final[metric], abs=1e-6), metric
    assert ours["ori"] > 0  # the robot saw something: the equality is not 0 == 0


def test_detector_frames_count_from_the_step_after_them_at_any_frame_period():
    """Frames are taken at the end of each frame period (a decision by default) and count
    from the step after: the rows of the engine's log and the frames each sample counts."""
    steps = np.array([0, 1, 5, 6, 10, 11, 20])
    default, fives = SessionConfig(), SessionConfig(detect_every=5)
    assert frames_before(default, steps).tolist() == [0, 0, 0, 0, 0, 1, 1]
    assert frames_before(fives, steps).tolist() == [0, 0, 0, 1, 1, 2, 3]
    assert log_every(default) == 10 and log_every(fives) == 5 and log_every(SessionConfig(detect_every=2)) == 2
    assert log_every(SessionConfig(detect_every=10)) == 10  # the default frame period, named
