"""``learned``: the explorer trained with PPO (:mod:`rosmeery_jax.rl.ppo`) on generated worlds.

``learned`` runs the policy shipped in the package (``rosmeery_jax/policies/learned_policy.msgpack``,
trained by ``rosmeery train --config experiments/learned/ppo.toml``); ``learned:PATH`` runs a
``policy.msgpack`` written by ``rosmeery train``.

Each decision it builds the observation of :mod:`rosmeery_jax.rl.env` from the robot's own maps,
samples a goal cell from the network's softmax (as in training) and sends the navigator to
that cell's pose until the next decision. It was trained deciding every 10 control steps
(1 s), the session's default ``decide_every``. It runs in the session's env: env settings
recorded in the policy file are not applied.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp

from rosmeery_jax.policies.base import Policy
from rosmeery_jax.rl.env import crop_offsets, flat_obs, goal, goal_offsets, observe
from rosmeery_jax.rl.network import ActorCritic, load_policy

PREFIX = "learned:"
SHIPPED = Path(__file__).resolve().parent / "learned_policy.msgpack"


def policy_file(spec: str) -> Path:
    """The policy file of a ``learned`` or ``learned:PATH`` entry."""
    return Path(spec[len(PREFIX):]) if spec.startswith(PREFIX) else SHIPPED


def label(spec: str) -> str:
    """The entry's name in results: ``learned``, or ``learned_<name>`` for ``learned:PATH``
    (``<name>`` the file's stem, or its folder's name for ``.../policy.msgpack``)."""
    if not spec.startswith(PREFIX):
        return "learned"
    path = policy_file(spec)
    name = path.parent.name if path.stem == "policy" and path.parent.name else path.stem
    return "learned_" + "".join(c if c.isalnum() or c in "-_" else "_" for c in name)


class LearnedPolicy(Policy):
    def __init__(self, env, spec: str = "learned"):
        super().__init__(env)
        self.name = label(spec)
        rl, _, params = load_policy(policy_file(spec))
        self.params = jax.tree.map(jnp.asarray, params)
        self.net = ActorCritic(rl.actions, rl.crop)
        self.offsets, self.crop_xy = goal_offsets(rl), crop_offsets(rl)

    def decide(self, state, pstate, key):
        logits, _ = self.net.apply(self.params, flat_obs(observe(self.env, state, self.crop_xy)))
        return goal(state.pose, jax.random.categorical(key, logits), self.offsets), pstate
