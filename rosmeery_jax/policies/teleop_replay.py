"""``replay:FILES``: drives recorded velocity commands (human-driven sessions, :mod:`rosmeery_jax.apps.teleop`).

FILES are recordings or glob patterns joined by ``+`` (``replay:a.jsonl+b.jsonl``,
``replay:recordings/*.jsonl``). In a world, the policy runs the recordings made in that
world, one per batch entry (its ``seed`` in the results is the recording's index), from
the recording's start pose, in velocity mode with the recording's env settings.

Unlike the other policies it returns one command per control step: ``decide`` hands the
next ``steps_per_decision`` recorded commands (v, w) to the session. Steps past a
recording's end get (0, 0): the robot stands still and its curves flatten.
"""

from __future__ import annotations

import glob
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.core import specs
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.policies.base import Policy
from rosmeery_jax.policies.teleop_file import check_world, read


def replay_files(spec: str) -> list[Path]:
    """The recordings of a ``replay:`` entry: files or glob patterns joined by ``+``."""
    files: list[Path] = []
    for part in specs.parse(spec).body.split("+"):
        part = part.strip()
        if not part:
            continue
        hits = sorted(map(Path, glob.glob(part, recursive=True))) if any(c in part for c in "*?[") else [Path(part)]  # absolute too
        if not hits:
            raise InputError("config", "policies", f"replay: no file matches {part!r}")
        files += hits
    return files


def recordings_by_world(spec: str) -> dict:
    """{world name: [Recording, ...]} of a ``replay:`` entry (each file read and checked)."""
    by_world: dict = {}
    for f in replay_files(spec):
        rec = read(f)
        by_world.setdefault(rec.world, []).append(rec)
    return by_world


class ReplayPolicy(Policy):
    name = "replay"
    per_step = True

    def __init__(self, env, spec: str, steps_per_decision: int, total_steps: int):
        super().__init__(env)
        self.recordings = recordings_by_world(spec).get(env.world.name, [])
        for rec in self.recordings:
            check_world(rec, env.world)
        self.k, self.total_steps = steps_per_decision, total_steps

    @classmethod
    def env_overrides(cls, spec: str, world: str) -> dict:
        """The settings the recordings made in ``world`` were driven with (validation checks
        that they agree), from the spawn, in velocity mode."""
        recs = recordings_by_world(spec).get(world, [])
        env = recs[0].header.get("env", {}) if recs else {}
        return {**env, "start_yaw": "spawn", "action_mode": "velocity"}

    def seeds(self, session: range) -> range:
        """Its recordings, numbered from 0 whatever the session's seeds."""
        return range(len(self.recordings))

    def init_batch(self, keys):
        """Commands (B, T, 2) (zeros past a recording's end and for padding entries) and a
        cursor (B,)."""
        cmds = np.zeros((keys.shape[0], self.total_steps, 2), np.float32)
        for i, rec in enumerate(self.recordings):
            n = min(self.total_steps, len(rec.commands))
            cmds[i, :n] = rec.commands[:n]
        return jnp.asarray(cmds), jnp.zeros(keys.shape[0], jnp.int32)

    def check_start(self, poses) -> None:
        for rec, pose in zip(self.recordings, np.asarray(poses)):
            if not np.allclose(pose, rec.header["start_pose"], atol=1e-4):
                raise InputError(str(rec.path), "start_pose", f"{rec.header['start_pose']} is not the world's "
                                 f"start pose {pose.tolist()}")

    def decide(self, state, pstate, key):
        """One env: (actions (steps_per_decision, 2), pstate)."""
        cmds, cursor = pstate
        acts = jax.lax.dynamic_slice(cmds, (cursor, 0), (self.k, 2))
        return acts, (cmds, cursor + self.k)
