"""``rosmeery teleop``: drive the robot yourself from a local web page, recorded as you go.

One simulation thread steps a single env in velocity mode at 10 Hz of wall-clock time
(the same jitted ``RobotEnv.step`` as the batched sessions, 0.1 s simulated per step), applies
the command the page sent last (zero once it is older than ``COMMAND_TIMEOUT_S``: a closed
tab stops the robot), appends every step to the recording, and every ``detect_every``
steps runs the detector on the camera frame, as a session does after each decision.

The page (``static/``, plain HTML + JS, no external assets) shows what the robot has. In
the ``blind`` view (the default; what the paper's human driver saw) that is its own
occupancy map with its pose and the RGB and depth images; the ``full`` view adds the labels
it holds and the live metric values and curves (for demos: a driver who watches the score
is not the paper's human baseline).

Commands are checked: the body must be JSON (``Content-Type: application/json``) from the
page's own origin (a POST from another site's page is refused), ``v`` and ``w`` finite
numbers, clipped to the robot's limits; anything else gets 400/403/415 and moves nothing. The standard library's ``http.server`` serves it, bound to
127.0.0.1 by default. Endpoints: ``GET /`` the page, ``GET /state`` JSON,
``GET /map.png`` / ``/rgb.png`` / ``/depth.png``, ``POST /command`` ``{"v", "w"}`` or
``{"keys": [...]}``, ``POST /stop`` ends the session (the recording gets its end line).
"""

from __future__ import annotations

import ipaddress
import json
import math
import threading
import time
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax import metrics
from rosmeery_jax.apps.teleop import views
from rosmeery_jax.core import xla
from rosmeery_jax.detector.detections import make_detector, pad
from rosmeery_jax.env import make
from rosmeery_jax.policies.teleop_file import Recorder

STATIC = Path(__file__).parent / "static"
COMMAND_TIMEOUT_S = 0.5
MAX_BODY = 65536  # bytes of a command's JSON
CURVE_POINTS = 600  # metric history sent to the page (60 s at 10 Hz)


@dataclass
class PageSnapshot:
    """What the page sees; replaced whole by the simulation thread (read without locks)."""

    step: int
    t: float
    pose: list
    cmd: list
    map_png: bytes
    rgb_png: bytes
    depth_png: bytes
    labels: list
    metrics: dict


class Teleop:
    def __init__(self, world: str, record: str | Path | None = None, detector: str = "off", seed: int = 0,
                 conf_threshold: float = 0.25, weights: str | None = None, detect_every: int = 10,
                 metric_names=None, view: str = "blind"):
        self.overrides = {"action_mode": "velocity", "start_yaw": "spawn",
                          **({"labels": "detections"} if detector != "off" else {})}
        self.env = env = make(world, **self.overrides)
        self.view = view
        self.metric_names = metrics.resolve(metric_names or metrics.DEFAULT_METRICS)
        self.detector_name, self.detect_every = detector, detect_every
        self.detector = None
        if detector != "off":
            self.detector = make_detector(detector, env.world, conf_threshold, weights)
        self._step = xla.jit(env.step)
        self._log = xla.jit(env.log)
        self._rgb = xla.jit(env.camera_rgb)
        self._attach = xla.jit(env.attach)
        self._occ = xla.jit(env.occupancy)
        self.state = xla.jit(env.reset)(jax.random.key(seed))
        # Compile the step now (its result is discarded) so the page opens on a live robot.
        jax.block_until_ready(self._step(self.state, jax.numpy.zeros(2, jax.numpy.float32)))
        self.recorder = None
        if record:
            self.recorder = Recorder(record, env.world, np.asarray(self.state.pose), self.overrides, detector, seed,
                                     env.dt)
        self.cmd = np.zeros(2, np.float32)
        self.cmd_time = 0.0
        self.history: list = []
        self.trail: list = [np.asarray(self.state.pose)[:2].tolist()]
        self.lock = threading.Lock()  # one tick or stop at a time
        self.running = True
        self.stop_asked, self.stop_answered = threading.Event(), threading.Event()  # the page's /stop
        self.error = None
        self.frames = 0
        self.frame = self._snapshot(np.zeros(2))

    # --- commands from the page ---
    def command(self, body) -> None:
        """Set the velocity command from ``{"keys": [...]}`` or ``{"v": .., "w": ..}``;
        ValueError (nothing changes) for anything else."""
        self.cmd = parse_command(body, self.env.config.robot)
        self.cmd_time = time.monotonic()

    # --- the 10 Hz loop ---
    def run(self) -> None:
        period = self.env.dt
        next_tick = time.monotonic()
        try:
            while self.running:
                next_tick += period
                self.tick()
                time.sleep(max(0.0, next_tick - time.monotonic()))
        except Exception as err:  # noqa: BLE001 - end the session visibly, never a frozen page
            self.error = f"simulation stopped: {type(err).__name__}: {err}"
            self.stop()

    def tick(self) -> None:
        with self.lock:
            if self.running:
                self._tick()

    def _tick(self) -> None:
        fresh = time.monotonic() - self.cmd_time <= COMMAND_TIMEOUT_S
        cmd = self.cmd if fresh else np.zeros(2, np.float32)
        self.state = self._step(self.state, jnp.asarray(cmd))
        step = int(self.state.t)
        frame = tuple(np.asarray(a) for a in self._rgb(self.state))  # one render: detector and page
        if self.detector is not None and step % self.detect_every == 0:
            self._detect(*frame)
        if self.recorder is not None:
            self.recorder.step(step * self.env.dt, cmd, np.asarray(self.state.pose))
        self.frame = self._snapshot(cmd, frame[0])

    def _detect(self, img: np.ndarray, lab: np.ndarray) -> None:
        found = self.detector(img[None], lab[None].astype(np.int32), np.array([[0, self.frames]]))
        self.frames += 1
        obj, label, conf, _ = pad(found, 1, 32)
        self.state = self._attach(self.state, jnp.asarray(obj[0]), jnp.asarray(label[0]), jnp.asarray(conf[0]))

    def stop(self) -> None:
        with self.lock:
            self.running = False
            if self.recorder is not None:
                self.recorder.close()

    # --- what the page shows ---
    def _snapshot(self, cmd, img: np.ndarray | None = None) -> "PageSnapshot":
        s, env = self.state, self.env
        log = self._log(s)
        values = {k: float(np.asarray(v)[0]) for k, v in
                  metrics.compute(type(log)(*(np.asarray(a)[None] for a in log)), env.sk.truth,
                                  self.metric_names).items()}
        t = float(int(s.t) * env.dt)
        self.history.append([t, *values.values()])
        self.trail.append(np.asarray(s.pose)[:2].tolist())
        del self.trail[:-2000]
        del self.history[:-CURVE_POINTS]
        know = env.labelled_knowledge(s)
        names = env.world.taxonomy.names
        labels = [{"object": env.world.truth.names[n], "label": names[int(k)], "confidence": round(float(c), 3)}
                  for n, (k, c) in enumerate(zip(np.asarray(know.label), np.asarray(know.confidence))) if k >= 0]
        labels.sort(key=lambda d: -d["confidence"])
        if img is None:
            img = np.asarray(self._rgb(s)[0])
        return PageSnapshot(int(s.t), t, [float(v) for v in np.asarray(s.pose)], [float(c) for c in cmd],
                     views.map_png(env, np.asarray(self._occ(s)), np.asarray(s.pose), self.trail),
                     views.rgb_png(np.asarray(img)), views.depth_png(np.asarray(s.depth), env.config.camera.max_range),
                     labels, values)

    def state_json(self) -> dict:
        f = self.frame
        out = {"world": self.env.world.name, "title": self.env.world.title, "step": f.step, "t": f.t,
               "pose": f.pose, "cmd": f.cmd, "view": self.view, "objects": self.env.world.truth.num_objects,
               "running": self.running, "error": self.error,
               "recording": str(self.recorder.path) if self.recorder else None}
        if self.view == "full":
            out.update(labels=f.labels, metrics=f.metrics, metric_names=list(self.metric_names),
                       history=self.history[-CURVE_POINTS:])
        return out

    def final_metrics(self) -> dict:
        """The metric values at the last step (for the terminal, whatever the view)."""
        return self.frame.metrics


VIEWS = ("blind", "full")


def parse_command(body, robot) -> np.ndarray:
    """(2,) float32 (v, w) within the robot's limits; ValueError for a malformed body."""
    if not isinstance(body, dict):
        raise ValueError("body must be a JSON object")
    if "keys" in body:
        keys = body["keys"]
        if not isinstance(keys, list) or not all(isinstance(k, str) for k in keys):
            raise ValueError("keys must be a list of key names")
        keys = set(keys)
        fwd = int(bool({"ArrowUp", "w", "W"} & keys)) - int(bool({"ArrowDown", "s", "S"} & keys))
        turn = int(bool({"ArrowLeft", "a", "A"} & keys)) - int(bool({"ArrowRight", "d", "D"} & keys))
        return np.array([fwd * robot.max_speed, turn * robot.max_turn_rate], np.float32)
    v, w = (_finite(name, body.get(name, 0.0)) for name in ("v", "w"))
    return np.array([np.clip(v, -robot.max_speed, robot.max_speed),
                     np.clip(w, -robot.max_turn_rate, robot.max_turn_rate)], np.float32)


def _finite(name: str, x) -> float:
    """``x`` as a float, or ValueError unless it is a finite JSON number (an integer of
    400 digits is a number float cannot hold)."""
    try:
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            raise ValueError
        return float(x)
    except (ValueError, OverflowError):
        raise ValueError(f"{name} must be a finite number") from None


def _handler(app: Teleop):
    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args):  # quiet: the terminal shows the session summary instead
            pass

        def _send(self, body: bytes, ctype: str, code: int = 200) -> None:
            self.send_response(code)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def _host_allowed(self) -> bool:
            """A DNS-rebinding page reaches this server under its own host name: only a
            loopback name or an IP literal, with this server's port, may name it."""
            name, _, port = self.headers.get("Host", "").rpartition(":")
            if port != str(self.server.server_address[1]):
                return False
            name = name.strip("[]")
            if name == "localhost":
                return True
            try:
                ipaddress.ip_address(name)
            except ValueError:
                return False
            return True

        def do_GET(self):
            if not self._host_allowed():
                return self._error(403, "Host not allowed")
            path = self.path.split("?")[0]
            f = app.frame
            if path in ("/", "/index.html"):
                return self._send((STATIC / "index.html").read_bytes(), "text/html; charset=utf-8")
            if path == "/app.js":
                return self._send((STATIC / "app.js").read_bytes(), "text/javascript; charset=utf-8")
            if path == "/favicon.ico":
                return self._send(b"", "image/x-icon", 204)
            if path == "/state":
                return self._send(json.dumps(app.state_json()).encode(), "application/json")
            images = {"/map.png": f.map_png, "/rgb.png": f.rgb_png, "/depth.png": f.depth_png}
            if path in images:
                return self._send(images[path], "image/png")
            self._send(b"not found", "text/plain", 404)

        def _error(self, code: int, message: str) -> None:
            self._send(json.dumps({"error": message}).encode(), "application/json", code)

        def do_POST(self):
            if not self._host_allowed():
                return self._error(403, "Host not allowed")
            path = self.path.split("?")[0]
            # Only the page itself may drive: a browser sends Origin with a cross-site POST,
            # and a "simple" cross-site request cannot carry application/json.
            origin = self.headers.get("Origin")
            if origin is not None and origin != f"http://{self.headers.get('Host', '')}":
                return self._error(403, "cross-origin request refused")
            if self.headers.get("Content-Type", "").split(";")[0].strip() != "application/json":
                return self._error(415, "Content-Type must be application/json")
            try:
                length = int(self.headers.get("Content-Length", 0) or 0)
                if not 0 <= length <= MAX_BODY:  # a negative length would read until the client hangs up
                    raise ValueError
                body = json.loads(self.rfile.read(length) or b"{}")
            except (ValueError, RecursionError):  # RecursionError: arrays nested thousands deep
                return self._error(400, f"body is not JSON of at most {MAX_BODY} bytes")
            if path == "/command":
                try:
                    app.command(body)
                except ValueError as err:
                    return self._error(400, str(err))
                return self._send(b"{}", "application/json")
            if path == "/stop":
                app.stop_asked.set()
                app.stop()
                try:
                    return self._send(json.dumps(app.state_json()).encode(), "application/json")
                finally:
                    app.stop_answered.set()
            self._send(b"not found", "text/plain", 404)

    return Handler


def serve(app: Teleop, host: str = "127.0.0.1", port: int = 8765, ready=None) -> None:
    """Serve the page and run the simulation until /stop or Ctrl-C."""
    server = ThreadingHTTPServer((host, port), _handler(app))
    server.daemon_threads = True
    sim = threading.Thread(target=app.run, daemon=True)
    sim.start()
    web = threading.Thread(target=server.serve_forever, daemon=True)
    web.start()
    if ready:
        ready(server.server_address)
    try:
        while app.running:
            time.sleep(0.1)
    except KeyboardInterrupt:
        app.stop()
    finally:
        time.sleep(0.3)  # let the page fetch the final state
        if app.stop_asked.is_set():  # and answer its /stop, however busy the machine
            app.stop_answered.wait(timeout=10.0)
        server.shutdown()
        sim.join(timeout=2)
