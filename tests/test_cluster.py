"""Sessions on a Ray cluster: a local two-worker cluster on loopback, results identical to a
local run though a worker is killed mid-run: nothing lost or duplicated."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from conftest import room_xml, suite_xla_flags

from rosmeery_jax.apps.cli import main
from rosmeery_jax.session.batch import BLOCK

BODIES = """
<body name="chair_1" pos="-1.0 -1.0 0"><geom type="box" pos="0 0 0.25" size="0.22 0.22 0.25"/></body>
<body name="desk_1" pos="1.0 0.6 0"><geom type="box" pos="0 0 0.4" size="0.5 0.3 0.4"/></body>
"""
RAY = str(Path(sys.executable).with_name("ray"))


def _session(worlds: list[str], out: Path, *extra: str) -> list[str]:
    return ["run", "--worlds", ",".join(worlds), "--policies", "frontier", "--seeds", "2", "--duration", "10",
            "--detector", "off", "--quiet", "--out", str(out), *extra]


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> list[str]:
    """Two rooms of one size (other spawns): a shard of either compiles the program a local
    run of one room compiled, so the cluster's workers find it in the suite's cache."""
    folder = tmp_path_factory.mktemp("world")
    for name, spawn in (("room", (0.3, -0.4, 0.0)), ("room_b", (-0.6, 0.5, 1.0))):
        (folder / f"{name}.xml").write_text(room_xml(BODIES, {"chair_1": "chair", "desk_1": "desk"}, spawn=spawn,
                                                      half=2.2))
    return [str(folder / "room.xml"), str(folder / "room_b.xml")]


@pytest.fixture(scope="module", autouse=True)
def own_home(tmp_path_factory):
    """Ray reads and writes its token under the home folder: these tests use one of their
    own, so they neither depend on nor change the user's."""
    home = tmp_path_factory.mktemp("home")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HOME", str(home))
        for name in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH"):
            mp.delenv(name, raising=False)
        yield home


def _head(env: dict | None = None) -> str:
    """Start a Ray head on 127.0.0.1 with 2 CPUs (at most two shards at once); its address."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", **(env or {})}  # workers inherit the suite's JAX cache
    subprocess.run([RAY, "start", "--head", "--node-ip-address=127.0.0.1", f"--port={port}", "--num-cpus=2",
                    "--include-dashboard=false", "--disable-usage-stats"], check=True, env=env, capture_output=True)
    return f"127.0.0.1:{port}"


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A Ray head without authentication (no token in the home folder)."""
    yield _head()
    import ray

    ray.shutdown()
    subprocess.run([RAY, "stop", "--force"], capture_output=True)


@pytest.fixture(scope="module")
def local(world, tmp_path_factory):
    """Each room run alone on this machine (what a shard runs), one results folder per room."""
    root = tmp_path_factory.mktemp("local")
    for w in world:
        assert main(_session([w], root / Path(w).stem)) == 0
    return [root / Path(w).stem for w in world]


def _same_results(local: list[Path], b: Path) -> None:
    """The tables and maps of folder ``b`` are those of the ``local`` folders together."""
    for table in ("metrics.csv", "objects.csv", "trajectories.csv"):
        x, y = pd.concat([pd.read_csv(a / table) for a in local]), pd.read_csv(b / table)
        assert not y.duplicated().any()
        key = [c for c in x.columns if c != "value"]
        pd.testing.assert_frame_equal(x.sort_values(key).reset_index(drop=True), y.sort_values(key).reset_index(drop=True))
    maps = {p.name: p for a in local for p in (a / "maps").iterdir()}
    assert sorted(maps) == sorted(p.name for p in (b / "maps").iterdir()) and len(maps) == 2 * 2 * 2
    for name, path in maps.items():
        assert path.read_bytes() == (b / "maps" / name).read_bytes()


def _kill_a_shard(killed: list, done) -> None:
    """Wait for a shard process of the session and SIGKILL it once it has started (its pid
    goes into ``killed``); give up once the session is ``done`` (an Event). On a loaded
    machine the first shard may start minutes after the session."""
    while not done.is_set():
        ps = subprocess.run(["ps", "-eo", "pid=,args="], capture_output=True, text=True).stdout
        shards = [int(line.split()[0]) for line in ps.splitlines() if "ray::run_shard" in line]
        if shards:
            time.sleep(1.0)  # mid-run: the shard has started its session
            os.kill(shards[0], signal.SIGKILL)
            killed.append(shards[0])
            return
        time.sleep(0.2)


def test_a_session_on_a_two_worker_cluster_equals_the_local_run_though_a_worker_is_killed(world, cluster, local,
                                                                                         tmp_path):
    """Two shards on a two-worker cluster; one worker is killed mid-run, its shard retried:
    the tables and maps are those of the local runs, nothing lost or duplicated."""
    import json
    import threading

    out, killed, done = tmp_path / "cluster", [], threading.Event()
    killer = threading.Thread(target=_kill_a_shard, args=(killed, done))
    killer.start()
    try:
        assert main(_session(world, out, "--cluster", cluster)) == 0
    finally:
        done.set()
        killer.join()
    assert killed, "no shard process seen to kill"
    _same_results(local, out)
    timing = json.loads((out / "timing.json").read_text())
    assert timing["shards"] == 2 and timing["cluster"] == cluster and timing["env_steps"] == 2 * 2 * 100
    assert main(_session(world, out, "--cluster", cluster, "--resume")) == 0  # nothing left to do
    _same_results(local, out)


def test_a_shards_input_error_is_its_own_line_on_the_driver(cluster, tmp_path):
    """Ray wraps a task's error in its own, with the worker's traceback: the command shows
    the task's line (it was 68 lines), and InputError must survive the trip."""
    from types import SimpleNamespace

    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.session.cluster import simulate_on_cluster

    def failing_shard(cfg, world, policy, cache):  # local: pickled by value for the worker
        """A shard whose run fails on the worker with bad input (a plugin failing mid-run)."""
        raise InputError("config", "metrics", f"plugin 'm.py:late' failed in its curve of 5 steps ({policy})")

    bar = SimpleNamespace(update=lambda n: None)
    with pytest.raises(InputError) as raised:
        simulate_on_cluster(SimpleNamespace(duration=1.0), [("room", "random")], tmp_path, cluster, bar, True,
                            failing_shard)
    assert type(raised.value) is InputError
    assert str(raised.value) == "config: metrics: plugin 'm.py:late' failed in its curve of 5 steps (random)"
    assert not any(tmp_path.iterdir())


def test_without_ray_the_flag_names_the_extra(world, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    out = tmp_path / "o"
    assert main(_session(world, out, "--cluster", "auto")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'rosmeery-jax[cluster]'" in err[0] and not out.exists()


def test_devices_split_the_batch_over_host_devices_and_change_nothing(world, local, tmp_path):
    """Two host devices made from the CPU's cores (a fresh process: XLA reads the flag at start)."""
    out = tmp_path / "devices"
    cmd = [str(Path(sys.executable).with_name("rosmeery")), *_session(world, out, "--devices", "2")]
    done = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "XLA_FLAGS": suite_xla_flags()},
                          timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    _same_results(local, out)
    import json

    group = json.loads((out / "timing.json").read_text())["groups"][0]
    assert group["devices"] == 2 and group["padded_envs"] == 2 * BLOCK


def test_padding_blocks_give_each_device_a_whole_share(world):
    from rosmeery_jax.session import SessionConfig
    from rosmeery_jax.session.batch import build_groups

    for policies, devices, blocks in ((["frontier"], 2, 2), (["frontier", "random"], 3, 3), (["frontier"], 1, 1)):
        cfg = SessionConfig(seeds=3, duration=10.0, detector="off", devices=devices)
        group = build_groups([(world[0], p) for p in policies], cfg)[0]
        assert len(group.blocks) == blocks and group.size == blocks * BLOCK
        assert group.real.sum() == 3 * len(policies)  # padding envs are never real
        assert [tuple(b) for b in group.blocks[:len(policies)]] == [(q, 0) for q in range(len(policies))]


def test_by_default_a_group_uses_every_device_but_never_more_than_its_blocks(world, monkeypatch):
    import jax

    from rosmeery_jax.session import SessionConfig
    from rosmeery_jax.session.batch import build_groups

    one = jax.devices()[:1]
    monkeypatch.setattr(jax, "devices", lambda *a: one * 3)  # three devices, as far as counting goes
    # (policies, seeds) -> (devices used, blocks): seeds <= 5 fill one block per run
    for policies, seeds, used, blocks in ((["frontier"], 3, 1, 1), (["frontier", "random"], 3, 2, 2),
                                          (["frontier", "random"], 7, 3, 6)):
        group = build_groups([(world[0], p) for p in policies], SessionConfig(seeds=seeds, duration=10.0, detector="off"))[0]
        assert (group.devices, len(group.blocks)) == (used, blocks)
        assert group.real.sum() == seeds * len(policies)


@pytest.mark.parametrize("devices", ["64", "1000"])
def test_more_devices_than_blocks_is_one_clear_line_at_once(world, tmp_path, capsys, monkeypatch, devices):
    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))  # restored afterwards: main may set it
    out = tmp_path / "o"
    t0 = time.monotonic()
    assert main(_session(world, out, "--devices", devices)) == 2
    assert time.monotonic() - t0 < 30  # refused by the count, before any device is made
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"devices: {devices}" in err[0] and "2 blocks" in err[0] and not out.exists()


def test_devices_with_a_cluster_is_refused_before_anything_is_written(world, tmp_path):
    pytest.importorskip("ray")
    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.session import Session, SessionConfig

    cfg = SessionConfig(worlds=tuple(world), out=str(tmp_path / "o"), devices=2)  # not validated: no 2 devices here
    with pytest.raises(InputError, match="--devices.*not with --cluster"):
        Session(cfg, cluster="auto").run()
    assert not (tmp_path / "o").exists()


def test_an_unreachable_or_empty_cluster_address_is_one_line_within_the_timeout(world, tmp_path, capsys):
    pytest.importorskip("ray")
    for address, needle in (("127.0.0.1:1", "no Ray head answers"), ("", "is not ray, auto"),
                            ("nowhere", "is not ray, auto")):
        out = tmp_path / "o"
        t0 = time.monotonic()
        assert main(_session(world, out, "--cluster", address)) == 2
        assert time.monotonic() - t0 < 30
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and needle in err[0] and not out.exists(), err


JOIN = ("import sys; from rosmeery_jax.session.cluster import connect; ray = connect(sys.argv[1]); "
        "print('joined', ray.get(ray.remote(lambda: 41).remote()) + 1)")  # connect imports Ray itself


def _join(address: str, first: str = "") -> subprocess.CompletedProcess:
    """A fresh process, as a user's command, joins ``address`` and runs one task there
    (after the code ``first``)."""
    return subprocess.run([sys.executable, "-c", first + JOIN, address], capture_output=True, text=True,
                          timeout=300, env={**os.environ, "RAY_USAGE_STATS_ENABLED": "0"})


def test_a_token_head_is_joined_when_the_home_folder_holds_its_token(own_home, cluster):
    """The order that failed: a token in ~/.ray (as a local ray.init() leaves), a head that
    picks it up, then a join. The module's own head, without a token, is joined above."""
    (own_home / ".ray").mkdir(exist_ok=True)
    (own_home / ".ray" / "auth_token").write_text("0123456789abcdef" * 4)
    try:
        done = _join(_head())
        assert done.returncode == 0 and "joined 42" in done.stdout, done.stderr[-2000:]
    finally:
        (own_home / ".ray" / "auth_token").unlink()


def test_a_local_cluster_leaves_no_token_in_the_home_folder(own_home, cluster):
    """rosmeery's own local cluster authenticates with a token written nowhere, so a head
    started later without one is still joined."""
    done = _join("ray")
    assert done.returncode == 0 and "joined 42" in done.stdout, done.stderr[-2000:]
    assert not (own_home / ".ray" / "auth_token").exists()
    done = _join("ray", first="import ray; ")  # Ray imported before (a notebook): "Failed to start GCS"
    assert done.returncode == 0 and "joined 42" in done.stdout, done.stderr[-2000:]
    assert not (own_home / ".ray" / "auth_token").exists()
    done = _join(cluster)
    assert done.returncode == 0 and "joined 42" in done.stdout, done.stderr[-2000:]
