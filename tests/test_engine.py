"""The session engine: worlds as padded data, one compile per session, results that do not
depend on the batch, the padding or the chunking."""

from __future__ import annotations

import json
import threading

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from conftest import optimized, room_xml

from rosmeery_jax.apps.cli import compilation_cache, main
from rosmeery_jax.env import make
from rosmeery_jax.env.world_data import NEVER, Sizes, stack
from rosmeery_jax.mapping.perceived import PerceivedMapper
from rosmeery_jax.results import tables
from rosmeery_jax.session import worker
from rosmeery_jax.sim.knowledge import ObjectLog

BODIES = """
<body name="table_1" pos="1.0 0.6 0"><geom type="box" pos="0 0 0.72" size="0.5 0.3 0.03"/>
  <geom type="box" pos="0.45 0.25 0.35" size="0.03 0.03 0.35"/><geom type="box" pos="-0.45 -0.25 0.35" size="0.03 0.03 0.35"/></body>
<body name="chair_1" pos="-1.0 -1.0 0"><geom type="box" pos="0 0 0.25" size="0.22 0.22 0.25"/></body>
<body name="fridge_1" pos="-1.5 1.4 0"><geom type="box" pos="0 0 0.8" size="0.3 0.3 0.8"/></body>
"""
CATEGORIES = {"table_1": "desk", "chair_1": "chair", "fridge_1": "refrigerator"}
ONE_VIEW = """
from rosmeery_jax.mapping.perceived import PerceivedConfig, PerceivedMapper


class OneView(PerceivedMapper):
    name = "one_view"

    def __init__(self, camera, categories=()):
        super().__init__(camera, categories, PerceivedConfig(min_views=1, min_conf=0.0))
"""
# A larger room that pads the one above in every size: more boxes (and more of them crossing
# the laser's plane) than one chunk of 16, more collision proxies, objects, samples and cells.
HALL_BODIES = "\n".join(
    [f'<body name="desk_{i}" pos="{x} 1.6 0"><geom type="box" pos="0 0 0.72" size="0.5 0.3 0.03"/>'
     f'<geom type="box" pos="0.45 0.25 0.35" size="0.03 0.03 0.35"/>'
     f'<geom type="box" pos="-0.45 -0.25 0.35" size="0.03 0.03 0.35"/></body>' for i, x in enumerate((-1.8, 0.0, 1.8))]
    + [f'<body name="chair_{i}" pos="{x} -1.8 0"><geom type="box" pos="0 0 0.25" size="0.22 0.22 0.25"/></body>'
       for i, x in enumerate((-2.2, -1.1, 0.0, 1.1, 2.2))]
    + ['<body name="fridge_1" pos="2.4 0.0 0"><geom type="box" pos="0 0 0.8" size="0.3 0.3 0.8"/></body>',
       '<body name="couch_1" pos="-2.3 0.0 0"><geom type="box" pos="0 0 0.3" size="0.35 0.8 0.3"/></body>'])
HALL_CATEGORIES = {**{f"desk_{i}": "desk" for i in range(3)}, **{f"chair_{i}": "chair" for i in range(5)},
                   "fridge_1": "refrigerator", "couch_1": "couch"}
KEY = ["world", "policy", "mapper", "seed", "metric", "time_s"]


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    path = tmp_path_factory.mktemp("world") / "room.xml"
    path.write_text(room_xml(BODIES, CATEGORIES, spawn=(0.3, -0.4, 0.0), half=2.2))
    return str(path)


@pytest.fixture(scope="module")
def hall(tmp_path_factory):
    path = tmp_path_factory.mktemp("world") / "hall.xml"
    path.write_text(room_xml(HALL_BODIES, HALL_CATEGORIES, spawn=(0.0, 0.0, 0.0), half=3.0))
    return str(path)


def _run(out, worlds, policies, seeds, *extra) -> pd.DataFrame:
    """A 10 s session."""
    args = ["run", "--worlds", worlds, "--policies", policies, "--seeds", str(seeds), "--duration", "10",
            "--quiet", "--out", str(out), *extra]
    assert main(args) == 0
    return tables.load(out)


def _rows(df, world, policy, seeds) -> pd.DataFrame:
    part = df[(df.world == world) & (df.policy == policy) & (df.seed < seeds)]
    return part.sort_values(KEY).reset_index(drop=True)


def test_a_run_alone_equals_the_same_run_in_a_padded_mixed_batch(room, hall, tmp_path):
    """A world padded to a larger one (in every size), beside other worlds, policies and
    seeds, with the detector's labels reaching semantic_nbv on the schedule: bitwise the
    same as alone, for the built-in knowledge and the perceived mapper alike (mapping from an
    instance's first detection: 10 s gives few detections, and a second one of the same
    object may not come). The random walker draws the same targets over the padded grid as
    over its own."""
    plugin = tmp_path / "one_view.py"
    plugin.write_text(ONE_VIEW)
    small, large = (Sizes.of(env.world, env.config) for env in (make(room), make(hall)))
    grown = ("boxes", "laser_boxes", "proxies", "samples", "objects", "reachable")
    assert all(getattr(small, f) < getattr(large, f) for f in grown), (small, large)
    assert all(a < b for a, b in zip(small.grid, large.grid)) and small.categories == large.categories
    # labels of 0-2 s reach the robots at 4 s (the period after next), well within the 10 s run
    both = ("--detector", "oracle", "--detector-period-s", "2", "--mapper", f"oracle,{plugin}:OneView")
    alone = _run(tmp_path / "alone", room, "random,semantic_nbv", 2, *both)
    mixed = _run(tmp_path / "mixed", f"{room},{hall}", "random,semantic_nbv", 3, *both)
    for policy in ("random", "semantic_nbv"):
        a, b = _rows(alone, "room", policy, 2), _rows(mixed, "room", policy, 2)
        assert len(a) and len(a) == len(b)
        assert (a.value.to_numpy() == b.value.to_numpy()).all(), policy
        ta, tb = (pd.read_csv(d / "runs" / f"room__{policy}.trajectory.csv") for d in (tmp_path / "alone",
                                                                                        tmp_path / "mixed"))
        tb = tb[tb.seed < 2].reset_index(drop=True)
        assert np.array_equal(ta[["x", "y", "yaw"]].to_numpy(), tb[["x", "y", "yaw"]].to_numpy()), policy
        assert np.ptp(ta.x) > 0.3  # the robot moved
    a = _rows(alone, "room", "semantic_nbv", 2)  # the rest checks semantic_nbv's rows
    assert a.value[a.metric == "opi"].max() > 0  # labels arrived: the comparison has something to compare
    assert set(a.mapper) == {"oracle", "one_view"}
    final = a[(a.metric == "ori") & (a.time_s == a.time_s.max())].set_index(["mapper", "seed"]).value
    assert (final["one_view"] > 0).all() and (final["one_view"] < final["oracle"]).all()
    ev = tmp_path / "evaluated"  # the perceived map written at the end scores as its curve ends
    ply = tmp_path / "alone" / "maps" / "room__semantic_nbv__seed0__one_view.ply"
    assert main(["evaluate", "--world", room, "--map", str(ply), "--out", str(ev)]) == 0
    summary = json.loads((ev / "summary.json").read_text())
    last = a[(a.mapper == "one_view") & (a.seed == 0) & (a.time_s == a.time_s.max())].set_index("metric").value
    for m in ("ori", "cori", "opi", "opi_strict"):
        assert summary[m] == pytest.approx(last[m], abs=1e-6)
    timing = json.loads((tmp_path / "mixed" / "timing.json").read_text())
    assert timing["compiles"] == 1 and timing["xla_compiles"] >= 1 and timing["frames"] == 2 * 3 * 2 * 10
    assert set(mixed.world) == {"room", "hall"} and set(mixed.policy) == {"random", "semantic_nbv"}


def test_one_policy_over_padded_worlds_runs_as_it_does_beside_another_policy(tmp_path):
    """The four paper worlds in one padded bank, frontier alone and beside random: the same
    runs, bitwise. (When a lone policy's decision was compiled inline, not as a branch, XLA
    rounded this bank's steps differently: 3.5e-7 m apart after 1 s in 6 of 20 runs.)"""
    worlds = "kitchen,laboratory,small_office,large_office"
    with optimized():  # compiled as a user's session is: the suite's quick pipeline rounds alike either way
        alone = _run(tmp_path / "alone", worlds, "frontier", 5, "--detector", "off", "--duration", "2")
        beside = _run(tmp_path / "beside", worlds, "frontier,random", 5, "--detector", "off", "--duration", "2")
    for out in (alone, beside):
        assert out.time_s.max() == 2.0
    a = alone.sort_values(KEY).reset_index(drop=True)
    b = beside[beside.policy == "frontier"].sort_values(KEY).reset_index(drop=True)
    assert len(a) and (a.value.to_numpy() == b.value.to_numpy()).all()
    ta, tb = (pd.read_csv(d / "trajectories.csv") for d in (tmp_path / "alone", tmp_path / "beside"))
    tb = tb[tb.policy == "frontier"].reset_index(drop=True)
    assert len(ta) == 4 * 5 * 3 and np.array_equal(ta[["x", "y", "yaw"]].to_numpy(), tb[["x", "y", "yaw"]].to_numpy())
    assert np.ptp(ta.x) > 0.3  # the robots moved


def test_results_do_not_depend_on_chunk_s(room, tmp_path):
    a = _run(tmp_path / "a", room, "frontier", 2, "--detector", "off", "--chunk-s", "10")
    b = _run(tmp_path / "b", room, "frontier", 2, "--detector", "off", "--chunk-s", "3")
    pd.testing.assert_frame_equal(a.sort_values(KEY).reset_index(drop=True), b.sort_values(KEY).reset_index(drop=True))
    # Rows every step: the engine logs every step instead of every 10. The whole seconds are
    # the same experiment (trajectories bitwise; metric values up to float32 rounding of a
    # mean over objects computed over a different number of rows).
    toml = tmp_path / "every_step.toml"
    toml.write_text("sample_s = 0.1\n")
    c = _run(tmp_path / "c", room, "frontier", 2, "--detector", "off", "--config", str(toml))
    assert sorted(set(c.time_s))[:3] == [0.0, 0.1, 0.2]
    whole = c[np.isclose(c.time_s % 1.0, 0.0)].sort_values(KEY).reset_index(drop=True)
    ref = a.sort_values(KEY).reset_index(drop=True)
    assert len(whole) == len(ref) and (whole[KEY[:-1]] == ref[KEY[:-1]]).all().all()
    assert np.abs(whole.value.to_numpy() - ref.value.to_numpy()).max() < 1e-6
    ta, tc = (pd.read_csv(d / "runs" / "room__frontier.trajectory.csv") for d in (tmp_path / "a", tmp_path / "c"))
    assert np.array_equal(ta[["x", "y", "yaw"]].to_numpy(),
                          tc[np.isclose(tc.time_s % 1.0, 0.0)][["x", "y", "yaw"]].to_numpy())
    assert np.ptp(ta.x) > 0.3  # the robots moved in their 10 s: the comparison has something to compare
    # Every step's pose replayed (`rosmeery replay --run`) gives the session's ORI curve, bitwise.
    assert main(["replay", "--world", room, "--poses", str(tmp_path / "c" / "trajectories.csv"), "--run",
                 "frontier:1", "--metrics", "ori", "--out", str(tmp_path / "replayed")]) == 0
    replayed = pd.read_csv(tmp_path / "replayed" / "metrics.csv")
    session = c[(c.seed == 1) & (c.metric == "ori") & (c.mapper == "oracle")].sort_values("time_s")
    np.testing.assert_allclose(replayed.time_s.to_numpy(), session.time_s.to_numpy(), atol=1e-6)  # files round
    assert np.array_equal(replayed.value.to_numpy(), session.value.to_numpy())


def test_a_seed_is_the_same_run_whatever_the_first_seed(room, tmp_path, capsys):
    """Seeds 1-2 run alone (--first-seed 1) are seeds 1-2 of a session of seeds 0-2, bitwise,
    in every file that names a seed; a resume may not move the seeds; joined with seed 0
    alone (``rosmeery join``), they are the 0-2 session's files. (The chunking test's
    program: loaded from the compilation cache.)"""
    off = ("--detector", "off", "--chunk-s", "10")
    whole = _run(tmp_path / "whole", room, "frontier", 3, *off)
    part = _run(tmp_path / "part", room, "frontier", 2, *off, "--first-seed", "1")
    assert sorted(set(part.seed)) == [1, 2]
    assert part.sort_values(KEY).reset_index(drop=True).equals(
        whole[whole.seed >= 1].sort_values(KEY).reset_index(drop=True))
    assert not whole[whole.seed == 0].value.reset_index(drop=True).equals(
        whole[whole.seed == 1].value.reset_index(drop=True))  # seeds differ (headings), so the labels are checked
    for kind in ("trajectory", "navigation", "objects"):
        a, b = (pd.read_csv(tmp_path / d / "runs" / f"room__frontier.{kind}.csv") for d in ("whole", "part"))
        pd.testing.assert_frame_equal(a[a.seed >= 1].reset_index(drop=True), b)
    maps = sorted(p.name for p in (tmp_path / "part" / "maps").glob("*.ply"))
    assert maps == ["room__frontier__seed1.ply", "room__frontier__seed2.ply"]
    assert ((tmp_path / "part" / "maps" / maps[1]).read_bytes()
            == (tmp_path / "whole" / "maps" / maps[1]).read_bytes())
    capsys.readouterr()
    assert main(["run", "--worlds", room, "--policies", "frontier", "--seeds", "2", "--duration", "10", "--quiet",
                 *off, "--out", str(tmp_path / "part"), "--resume"]) == 2
    assert "first_seed" in capsys.readouterr().err
    # Seed 0 alone, joined with seeds 1-2 (given out of order): the files of the 0-2 session.
    _run(tmp_path / "zero", room, "frontier", 1, *off)
    assert main(["join", str(tmp_path / "part"), str(tmp_path / "zero"), "--out", str(tmp_path / "joined")]) == 0
    files = lambda d: sorted(str(p.relative_to(d)) for p in d.rglob("*") if p.is_file()  # noqa: E731
                             and not p.name.endswith((".png", "timing.json", "config.json")))
    whole_dir, joined = tmp_path / "whole", tmp_path / "joined"
    assert files(joined) == files(whole_dir) and len(files(whole_dir)) == 16  # 4 tables, 4 run files, 6 map files,
        # the run's record and the tables'
    for name in files(whole_dir):
        assert (joined / name).read_bytes() == (whole_dir / name).read_bytes(), name
    session = lambda d: {k: v for k, v in json.loads((d / "config.json").read_text())["session"].items()  # noqa: E731
                         if k != "out"}
    assert session(joined) == session(whole_dir)
    assert main(["run", "--worlds", room, "--policies", "frontier", "--seeds", "3", "--duration", "10", "--quiet",
                 *off, "--out", str(joined), "--resume"]) == 0  # one session's folder: nothing left to run
    assert [p["first_seed"] for p in json.loads((joined / "config.json").read_text())["joined"]] == [0, 1]
    assert sorted(p.name for p in (joined / "plots").glob("*.png")) == sorted(
        p.name for p in (whole_dir / "plots").glob("*.png"))


def test_the_envs_perceived_mappers_in_parallel_threads_give_the_files_of_one_thread(room, tmp_path, monkeypatch):
    """The worker feeds each env's built-in perceived mapper in a thread of a pool (one per
    core): with four threads, every file but the timing is the bytes of a one-thread pool,
    and the mappers were fed from more than one thread, none of them the worker's own."""
    fed_by: set = set()
    add = PerceivedMapper.add
    monkeypatch.setattr(PerceivedMapper, "add", lambda self, frame: fed_by.add(threading.get_ident()) or add(self, frame))
    outs = {}
    for n in (1, 4):
        monkeypatch.setattr(worker, "cores", lambda n=n: n)
        fed_by.clear()
        _run(outs.setdefault(n, tmp_path / f"threads{n}"), room, "random,frontier", 3, "--detector", "oracle",
             "--mapper", "oracle,perceived")
        assert len(fed_by) == 1 if n == 1 else len(fed_by) > 1, (n, len(fed_by))
        assert threading.get_ident() not in fed_by
    files = lambda d: sorted(str(p.relative_to(d)) for p in d.rglob("*") if p.is_file()  # noqa: E731
                             and not p.name.endswith((".png", "timing.json", "config.json")))
    assert files(outs[1]) == files(outs[4]) and sum(f.endswith("perceived.ply") for f in files(outs[1])) == 6
    for name in files(outs[1]):
        assert (outs[1] / name).read_bytes() == (outs[4] / name).read_bytes(), name
    assert json.loads((outs[4] / "timing.json").read_text())["mapper_cpu_s"] > 0


def test_padding_is_inert_and_worlds_stack():
    small = make("small_office")
    sizes = Sizes.union([small.sizes, Sizes.of(make("kitchen").world, small.config)])
    padded = make("small_office", sizes=sizes)
    kitchen = make("kitchen", sizes=sizes)
    both = stack([padded.data, kitchen.data])  # one structure: static fields agree
    assert both.rays.center.shape[0] == 2 and padded.grid.shape == kitchen.grid.shape == sizes.grid
    n, s = small.world.truth.num_objects, small.sizes.samples
    # Padding objects are never named and padding samples never seen, from any pose.
    k = padded.sk.init()._replace(seen=jnp.ones(sizes.samples, bool))
    named = padded.sk.label_observed(k).label
    assert (np.asarray(named)[:n] >= 0).all() and (np.asarray(named)[n:] == -1).all()
    assert (np.asarray(padded.data.ps_G)[n:] == NEVER).all()
    state = jax.jit(padded.reset)(jax.random.key(0))
    assert not np.asarray(state.knowledge.seen)[s:].any()
    # The padded grid's extra cells stay unknown (logodds 0) after a scan.
    h, w = small.grid.shape
    lo = np.asarray(state.logodds)
    assert (lo[h:] == 0).all() and (lo[:, w:] == 0).all() and (lo[:h, :w] != 0).any()


def test_a_pose_that_is_not_finite_stops_the_session_naming_the_first_run_seed_and_time():
    from types import SimpleNamespace

    from rosmeery_jax.core.errors import InputError

    world = lambda name: SimpleNamespace(world=SimpleNamespace(name=name))  # noqa: E731
    runs = [SimpleNamespace(spec="random", world=0, rows=np.array([0, 1])),
            SimpleNamespace(spec="mine.py:P", world=1, rows=np.array([2, 3]))]
    group = SimpleNamespace(real=np.array([True, True, True, True, False]), seed=np.array([0, 1, 0, 1, 0]),
                            runs=runs, envs=[world("kitchen"), world("lab")], env=SimpleNamespace(dt=0.1))
    poses = np.zeros((5, 10, 3))
    poses[4, 0] = np.nan  # a padding row: never read
    worker._check_poses(group, 30, poses)
    poses[3, 6:, 1] = np.nan
    poses[1, 8:, 2] = np.inf
    with pytest.raises(InputError, match=r"^config: policies: 'mine.py:P' drove seed 1 in lab to a pose that is "
                                         r"not finite at t = 3.7 s \(a velocity command"):
        worker._check_poses(group, 30, poses)  # the earliest: step 30 + 6 + 1


def test_relabel_counts_a_frame_from_the_step_after_it():
    steps, n = 6, 2  # two decisions of 3 steps: frames after step 3 and step 6
    logs = ObjectLog(*(np.zeros((1, steps, n), np.float32) for _ in range(6)))
    per_frame = tuple(np.array([[[1, 1], [2, 2]]], np.float32) for _ in range(5))  # (B, F, N)
    out = worker._relabel(logs, per_frame, 3)
    assert out.label[0, :, 0].tolist() == [0, 0, 0, 1, 1, 1]  # frame 1 of this chunk lands in the next
    assert out.ps[0].sum() == 0  # coverage untouched
    # Logged once per decision (after steps 3 and 6): frame 0 counts from step 4, so row 2 has it.
    rows = ObjectLog(*(np.zeros((1, 2, n), np.float32) for _ in range(6)))
    assert worker._relabel(rows, per_frame, 3, log_every=3).label[0, :, 0].tolist() == [0, 1]
    # In a later chunk, the steps before its first frame counts hold the labels after the
    # previous chunk's last frame, not the log's own (the robot's, a detector period behind)
    before = tuple(np.array([[7, 7]], np.float32) for _ in range(5))  # (B, N)
    assert worker._relabel(logs, per_frame, 3, before=before).label[0, :, 0].tolist() == [7, 7, 7, 1, 1, 1]


def test_held_labels_never_drop_out_of_the_metrics_between_chunks(tmp_path):
    """With the oracle detector a held label is only ever replaced, so OPI (predicates
    declared) never falls: at each chunk's first rows it fell to the robot's lagging labels
    before (0 at 11 s in every paper run)."""
    import pandas as pd

    from rosmeery_jax.apps.cli import main

    assert main(["run", "--worlds", "small_office", "--policies", "random", "--seeds", "2", "--detector", "oracle",
                 "--duration", "40", "--quiet", "--out", str(tmp_path / "o")]) == 0
    df = pd.read_csv(tmp_path / "o" / "metrics.csv")
    for seed, g in df[df.metric == "opi"].groupby("seed"):
        v = g.sort_values("time_s").value.to_numpy()
        assert (np.diff(v) >= -1e-9).all() and v[-1] > 0, (seed, v)


def test_compilation_cache_folder(monkeypatch, tmp_path):
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "jc"))
    assert compilation_cache(True) == str(tmp_path / "jc")
    assert jax.config.jax_compilation_cache_dir == str(tmp_path / "jc")
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert compilation_cache(True) == str(tmp_path / "xdg" / "rosmeery-jax" / "jax")
    assert compilation_cache(False) is None and not jax.config.jax_enable_compilation_cache
    jax.config.update("jax_enable_compilation_cache", True)
