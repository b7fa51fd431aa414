"""Human-driven exploration: recordings, their replay in batch, and the teleop page end to end
in headless Chromium (installed by ``scripts/setup.sh --test``)."""

from __future__ import annotations

import json
import math
import os
import shutil
import socket
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

from rosmeery_jax.apps.cli import main
from rosmeery_jax.policies.teleop_file import read

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
WORLD = "small_office"


def _header(**over) -> str:
    from rosmeery_jax.policies.teleop_file import world_hash
    from rosmeery_jax.world import load_world

    w = load_world(WORLD)
    h = {"format": "rosmeery-teleop", "version": 1, "world": WORLD, "world_sha256": world_hash(w), "seed": 0,
         "dt": 0.1, "start_pose": [float(v) for v in w.spawn], "env": {}, "detector": "off"}
    h.update(over)
    return json.dumps(h)


def _steps(n: int, v: float = 0.5, w: float = 0.2) -> str:
    return "".join(json.dumps({"k": k, "t": k / 10, "cmd": [v, w], "pose": [0, 0, 0]}) + "\n" for k in range(1, n + 1))


@pytest.mark.parametrize("content, field", [
    (lambda: _header(world="kitchen") + "\n" + _steps(3), "world"),
    (lambda: _header() + "\n" + _steps(3) + '{"k": 4, "t": 0.4, "cmd": [0.5', "line 5"),
    (lambda: _header() + "\n" + "garbage\n" + _steps(2), "line 2"),
    (lambda: '{"format": "something else"}\n', "format"),
    (lambda: _header() + "\n" + _steps(3).replace('"k": 2', '"k": 7'), "line 3: k"),
    (lambda: _header(dt=0.2) + "\n" + _steps(3), "line 1: dt"),  # another rate cannot be replayed
    (lambda: _header(start_pose="here") + "\n" + _steps(3), "line 1: start_pose"),
    (lambda: _header(env={"camera__cull": "many"}) + "\n" + _steps(3), "line 1: env.camera.cull"),
    (lambda: _header() + "\n" + _steps(3).replace("0.5,", "1e300,", 1), "line 2"),
])
def test_bad_recordings_are_one_line_errors(tmp_path, capsys, content, field):
    path = tmp_path / "rec.jsonl"
    path.write_text(content())
    code = main(["run", "--worlds", WORLD, "--policies", f"replay:{path}", "--duration", "2", "--detector", "off",
                 "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and field in err and "rec.jsonl" in err
    assert not (tmp_path / "o").exists()


def test_replay_of_several_recordings_is_batched_with_mean_and_spread(tmp_path):
    a, b = tmp_path / "a.jsonl", tmp_path / "b.jsonl"
    a.write_text(_header() + "\n" + _steps(25, 0.6, 0.0))
    b.write_text(_header() + "\n" + _steps(12, 0.3, 0.5) + '{"end": true, "steps": 12}\n')
    assert read(b).ended and len(read(a).commands) == 25
    out = tmp_path / "o"
    # comma-separated files after replay: stay one entry; the other policy runs beside it
    assert main(["run", "--worlds", WORLD, "--policies", f"replay:{a},{b},random", "--duration", "3",
                 "--seeds", "1", "--detector", "off", "--out", str(out), "--quiet"]) == 0
    df = pd.read_csv(out / "metrics.csv")
    assert set(df.policy) == {"replay", "random"}
    assert sorted(df[df.policy == "replay"].seed.unique()) == [0, 1]
    traj = pd.read_csv(out / "trajectories.csv")
    end = traj[(traj.policy == "replay") & (traj.time_s == 3.0)].set_index("seed")
    assert end.loc[0, "x"] > 1.0  # drove 2.5 s at 0.6 m/s straight ahead (yaw 0 at the spawn)
    assert abs(end.loc[1, "yaw"]) > 0.3  # turned while its commands lasted, then stood still
    assert (out / "plots" / f"{WORLD}_ori.png").exists()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _hold(page, key: str, until: str) -> None:
    """Hold ``key`` until the page's state meets ``until`` (JavaScript over ``s``, the state,
    and ``s0``, the state when the key went down): the robot's own progress, so a busy
    machine, whose page may send the keys late, drives it as far as an idle one."""
    page.evaluate("window.s0 = window.lastState")
    page.keyboard.down(key)
    page.wait_for_function(f"(s => {{ const s0 = window.s0; return {until}; }})(window.lastState)", timeout=120_000)
    page.keyboard.up(key)


@pytest.mark.skipif(CHROMIUM is None, reason="Chromium not installed (scripts/setup.sh --test installs it)")
def test_drive_the_page_in_chromium_then_replay_the_recording(tmp_path):
    from playwright.sync_api import sync_playwright

    port, record = _free_port(), tmp_path / "drive.jsonl"
    server = subprocess.Popen([sys.executable, "-m", "rosmeery_jax", "teleop", "--world", WORLD, "--port", str(port),
                               "--record", str(record), "--detector", "off", "--view", "full"],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=os.environ.copy())
    try:
        deadline = time.time() + 300
        for line in server.stdout:  # compiles first; prints the address when serving
            if "teleop: open" in line or time.time() > deadline:
                break
        assert server.poll() is None, "teleop server exited"
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=[
                "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync"])
            page = browser.new_page(viewport={"width": 1400, "height": 800})
            page.goto(f"http://127.0.0.1:{port}/")
            page.wait_for_function("window.lastState && document.getElementById('map').naturalWidth > 0")
            start = page.evaluate("window.lastState")
            map0, rgb0 = page.locator("#map").screenshot(), page.locator("#rgb").screenshot()
            _hold(page, "ArrowUp", "Math.hypot(s.pose[0] - s0.pose[0], s.pose[1] - s0.pose[1]) > 0.6")
            _hold(page, "ArrowLeft", "Math.abs(s.pose[2] - s0.pose[2]) > 0.4")
            _hold(page, "ArrowUp", "s.step >= s0.step + 10")
            page.wait_for_timeout(600)
            moved = page.evaluate("window.lastState")
            map1, rgb1 = page.locator("#map").screenshot(), page.locator("#rgb").screenshot()
            page.click("#stop")
            page.wait_for_function("window.lastState && !window.lastState.running")
            final = page.evaluate("window.lastState")
            browser.close()
        server.wait(timeout=30)
    finally:
        if server.poll() is None:
            server.kill()
    assert moved["step"] > start["step"]
    assert math.dist(moved["pose"][:2], start["pose"][:2]) > 0.5
    assert abs(moved["pose"][2] - start["pose"][2]) > 0.3
    assert map1 != map0 and rgb1 != rgb0  # the map and the camera image updated

    rec = read(record)
    assert rec.ended and len(rec.commands) == final["step"]
    assert np.abs(rec.commands).max() > 0
    seconds = int(final["t"])
    out = tmp_path / "replayed"
    assert main(["run", "--worlds", WORLD, "--policies", f"replay:{record}", "--duration", str(seconds + 1),
                 "--detector", "off", "--out", str(out), "--quiet"]) == 0
    traj = pd.read_csv(out / "trajectories.csv").set_index("time_s")
    for t in range(1, seconds + 1):  # the batched replay retraces the driven path
        assert np.allclose(traj.loc[float(t), ["x", "y"]], rec.poses[10 * t - 1, :2], atol=2e-3), t
    df = pd.read_csv(out / "metrics.csv")
    live = {round(row[0], 3): row[1:] for row in final["history"]}
    for k, name in enumerate(final["metric_names"]):
        replayed = df[(df.metric == name) & (df.time_s == float(seconds))].value.iloc[0]
        assert replayed == pytest.approx(live[float(seconds)][k], abs=1e-3), name


class _StubApp:
    """What the HTTP handler needs of a Teleop, without compiling a world."""

    def __init__(self):
        from rosmeery_jax.sim.robot import RobotConfig

        self.robot, self.cmd, self.running, self.frame = RobotConfig(), None, True, None

    def command(self, body):
        from rosmeery_jax.apps.teleop.server import parse_command

        self.cmd = parse_command(body, self.robot)

    def state_json(self):
        return {}


def _post(port, body: bytes, headers: dict) -> int:
    import http.client

    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    conn.request("POST", "/command", body=body, headers=headers)
    return conn.getresponse().status


def _get(port, path: str, headers: dict) -> int:
    import http.client

    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    conn.request("GET", path, headers=headers)
    return conn.getresponse().status


def test_commands_are_validated_and_only_the_page_may_drive():
    import threading
    from http.server import ThreadingHTTPServer

    from rosmeery_jax.apps.teleop.server import _handler

    app = _StubApp()
    server = ThreadingHTTPServer(("127.0.0.1", 0), _handler(app))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    port = server.server_address[1]
    own = {"Content-Type": "application/json", "Origin": f"http://127.0.0.1:{port}"}
    try:
        for body in (b'{"v": NaN, "w": 0}', b'{"v": Infinity}', b'{"v": "fast"}', b'{"keys": "up"}', b"[1, 2]",
                     b"not json", b'{"v": 1' + b"0" * 400 + b"}",  # an int float cannot hold: was a TypeError
                     b"[" * 30000 + b"]" * 30000):  # nested past Python's recursion limit: was a RecursionError
            assert _post(port, body, own) == 400, body[:20]
            assert app.cmd is None, body[:20]  # nothing moved
        # a negative length read until the client hung up (a timeout here); too long is refused unread
        for length in ("-1", "70000"):
            assert _post(port, b'{"v": 1}', {**own, "Content-Length": length}) == 400, length
        # another site's page: text/plain (a "simple" request), or a foreign Origin
        assert _post(port, b'{"v": 1, "w": 0}', {"Content-Type": "text/plain"}) == 415
        assert _post(port, b'{"v": 1, "w": 0}', {**own, "Origin": "http://evil.example"}) == 403
        # DNS rebinding: another site's name resolved to this machine, Origin matching its Host
        rebound = {**own, "Host": f"evil.example:{port}", "Origin": f"http://evil.example:{port}"}
        assert _post(port, b'{"v": 1, "w": 0}', rebound) == 403
        assert _post(port, b'{"v": 1, "w": 0}', {**own, "Host": "127.0.0.1:1"}) == 403  # another port
        assert _get(port, "/state", {"Host": f"evil.example:{port}"}) == 403
        assert _get(port, "/state", {"Host": f"localhost:{port}"}) == 200
        assert app.cmd is None
        assert _post(port, b'{"v": 1e308, "w": -1e308}', own) == 200
        assert app.cmd.tolist() == [app.robot.max_speed, -app.robot.max_turn_rate]  # clipped to the limits
    finally:
        server.shutdown()


def test_teleop_refuses_an_existing_recording_and_a_busy_port_before_compiling(tmp_path, capsys):
    record = tmp_path / "old.jsonl"
    record.write_text("precious\n")
    assert main(["teleop", "--world", WORLD, "--record", str(record), "--port", str(_free_port())]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "old.jsonl" in err and "never overwritten" in err
    assert record.read_text() == "precious\n"
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        new = tmp_path / "new.jsonl"
        assert main(["teleop", "--world", WORLD, "--record", str(new), "--port", str(port)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--port" in err and not new.exists()


def test_blind_view_shows_only_what_the_papers_driver_saw():
    from rosmeery_jax.apps.teleop.server import Teleop

    app = Teleop(WORLD, record=None, view="blind")
    state = app.state_json()
    assert not {"metrics", "labels", "history"} & set(state) and state["view"] == "blind"
    app.view = "full"
    assert {"metrics", "labels", "history"} <= set(app.state_json())
