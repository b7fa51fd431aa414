"""``replay``: drives recorded velocity commands (human-driven sessions, :mod:`rosmeery_jax.teleop`).

Unlike the other policies it returns one command per control step: ``decide`` hands the
next ``steps_per_decision`` recorded commands (v, w) to the session, which applies them in
velocity mode from the recording's start pose. Steps past a recording's end get (0, 0): the
robot stands still and its curves flatten. Each recording is one batch entry (its ``seed``
column in the results is the recording's index).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.policies.base import Policy


class ReplayPolicy(Policy):
    name = "replay"
    action_mode = "velocity"
    per_step = True

    def __init__(self, env, recordings, steps_per_decision: int, total_steps: int):
        super().__init__(env)
        self.recordings, self.k = list(recordings), steps_per_decision
        cmds = np.zeros((len(self.recordings), total_steps, 2), np.float32)
        for i, rec in enumerate(self.recordings):
            n = min(total_steps, len(rec.commands))
            cmds[i, :n] = rec.commands[:n]
        self.commands = cmds

    def init_batch(self):
        """The batched policy state: commands (B, T, 2) and a cursor (B,)."""
        return jnp.asarray(self.commands), jnp.zeros(len(self.recordings), jnp.int32)

    def decide(self, state, pstate, key):
        """One env: (actions (steps_per_decision, 2), pstate)."""
        cmds, cursor = pstate
        acts = jax.lax.dynamic_slice(cmds, (cursor, 0), (self.k, 2))
        return acts, (cmds, cursor + self.k)
