"""Recorded human-driven sessions: the file format, its writer and its reader.

A recording is JSON Lines (``.jsonl``), one object per line, each line flushed to disk as
soon as it is written, so a crash or a closed tab loses nothing already driven:

line 1, the header::

    {"format": "rosmeery-teleop", "version": 1, "world": "small_office",
     "world_sha256": "<hash of the world file>", "seed": 0, "dt": 0.1,
     "start_pose": [x, y, yaw], "env": {EnvConfig overrides}, "detector": "off",
     "started_utc": "2026-11-21T10:00:00Z"}

then one line per 0.1 s control step, in order, ``k`` = 1, 2, ...::

    {"k": 1, "t": 0.1, "cmd": [v, w], "pose": [x, y, yaw]}

``cmd`` is the velocity command (m/s, rad/s) applied during the step and ``pose`` the
robot's pose after it. A last line ``{"end": true, "steps": K}`` marks a session stopped
from the page; without it the recording is still valid up to its last full line.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from rosmeery_jax.core.errors import InputError

FORMAT, VERSION = "rosmeery-teleop", 1
MAX_VALUE = 1e6  # bigger commands or coordinates are corrupt (and would overflow float32)
CONTROL_DT = 0.1  # s: the env's control period; a recording made at another rate is refused


def world_hash(world) -> str:
    return hashlib.sha256(Path(world.path).read_bytes()).hexdigest()


class Recorder:
    """Appends one line per step; every line is flushed and synced."""

    def __init__(self, path: str | Path, world, start_pose, env_overrides: dict, detector: str, seed: int = 0,
                 dt: float = 0.1):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:  # "x": a recording is never overwritten
            self._fh = open(self.path, "x", encoding="utf-8")
        except FileExistsError:
            raise InputError(str(self.path), "file", "exists already: recordings are never overwritten; "
                             "choose another --record") from None
        self._write({"format": FORMAT, "version": VERSION, "world": world.name, "world_sha256": world_hash(world),
                     "seed": seed, "dt": dt, "start_pose": [float(v) for v in start_pose], "env": env_overrides,
                     "detector": detector,
                     "started_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")})
        self.steps = 0

    def _write(self, obj: dict) -> None:
        self._fh.write(json.dumps(obj, separators=(",", ":")) + "\n")
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def step(self, t: float, cmd, pose) -> None:
        self.steps += 1
        self._write({"k": self.steps, "t": round(float(t), 6), "cmd": [float(c) for c in cmd],
                     "pose": [float(p) for p in pose]})

    def close(self) -> None:
        if not self._fh.closed:
            self._write({"end": True, "steps": self.steps})
            self._fh.close()


@dataclass(frozen=True)
class Recording:
    path: Path
    header: dict
    commands: np.ndarray  # (K, 2) v, w per step
    poses: np.ndarray  # (K, 3) pose after each step
    ended: bool

    @property
    def world(self) -> str:
        return self.header["world"]

    @property
    def duration(self) -> float:
        return len(self.commands) * self.header["dt"]


def read(path: str | Path) -> Recording:
    """Parse and check a recording; any problem is one :class:`InputError` naming the line."""
    path = Path(path)
    src = str(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise InputError(src, "file", "not found") from None
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(src, "file", f"unreadable ({type(err).__name__})") from None
    if not lines:
        raise InputError(src, "line 1", "empty file: no header")
    rows = []
    for i, line in enumerate(lines, 1):
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            what = "truncated or corrupt line" if i == len(lines) else "corrupt line"
            raise InputError(src, f"line {i}", f"{what}: not JSON") from None
        if not isinstance(rows[-1], dict):
            raise InputError(src, f"line {i}", "not a JSON object")
    header = rows[0]
    if header.get("format") != FORMAT:
        raise InputError(src, "line 1: format", f"not a {FORMAT} recording")
    if header.get("version") != VERSION:
        raise InputError(src, "line 1: version", f"{header.get('version')!r} is not supported (this reads {VERSION})")
    _check_header(src, header)
    ended = bool(rows[-1].get("end")) if len(rows) > 1 else False
    steps = rows[1:-1] if ended else rows[1:]
    cmds, poses = [], []
    for i, r in enumerate(steps, 2):
        try:
            k, cmd, pose = r["k"], [float(c) for c in r["cmd"]], [float(p) for p in r["pose"]]
        except (KeyError, TypeError, ValueError):
            raise InputError(src, f"line {i}", "a step needs k, cmd [v, w] and pose [x, y, yaw]") from None
        if k != i - 1:
            raise InputError(src, f"line {i}: k", f"step {k} where {i - 1} was expected (lines missing?)")
        if len(cmd) != 2 or len(pose) != 3 or not np.all(np.abs(cmd + pose) <= MAX_VALUE):
            raise InputError(src, f"line {i}", f"cmd must be 2 and pose 3 finite numbers (|x| <= {MAX_VALUE:g})")
        cmds.append(cmd)
        poses.append(pose)
    if ended and rows[-1].get("steps") != len(steps):
        raise InputError(src, f"line {len(rows)}: steps", f"says {rows[-1].get('steps')}, file has {len(steps)}")
    return Recording(path, header, np.array(cmds, np.float32).reshape(-1, 2),
                     np.array(poses, np.float32).reshape(-1, 3), ended)


def _check_header(src: str, header: dict) -> None:
    """Types and values of the header fields a replay relies on."""
    for key in ("world", "dt", "start_pose"):
        if key not in header:
            raise InputError(src, f"line 1: {key}", "missing")
    checks = {
        "world": isinstance(header["world"], str),
        "dt": isinstance(header["dt"], (int, float)) and not isinstance(header["dt"], bool)
        and abs(header["dt"] - CONTROL_DT) < 1e-9,
        "start_pose": isinstance(header["start_pose"], list) and len(header["start_pose"]) == 3
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
                for v in header["start_pose"]),
        "env": isinstance(header.get("env", {}), dict),
        "seed": isinstance(header.get("seed", 0), int) and not isinstance(header.get("seed", 0), bool),
        "world_sha256": isinstance(header.get("world_sha256", ""), str),
    }
    wants = {"world": "a world name", "dt": f"{CONTROL_DT} (the control period; other rates cannot be replayed)",
             "start_pose": "[x, y, yaw], three finite numbers", "env": "a table of env overrides",
             "seed": "a whole number", "world_sha256": "a hex string"}
    for key, ok in checks.items():
        if not ok:
            raise InputError(src, f"line 1: {key}", f"{header.get(key)!r} must be {wants[key]}")


def check_world(rec: Recording, world) -> None:
    """One clear error when a recording was made in another world (or another version of it)."""
    if rec.world != world.name:
        raise InputError(str(rec.path), "world", f"recorded in {rec.world!r}, not {world.name!r}")
    if rec.header.get("world_sha256") not in (None, world_hash(world)):
        raise InputError(str(rec.path), "world_sha256", f"{world.name!r} has changed since this was recorded")
