"""``learned``: the explorer trained with PPO (:mod:`rosmeery_jax.rl.ppo`) on generated worlds.

``learned`` runs the policy shipped in the package (``rosmeery_jax/policies/learned_policy.msgpack``,
trained by ``rosmeery train --config experiments/learned/ppo.toml``); ``learned:PATH`` runs a
``policy.msgpack`` written by ``rosmeery train``.

It chooses as in training (:mod:`rosmeery_jax.rl.env`): when the navigator is done with
its target (reached, or gave up) or the policy's ``decide_every`` control steps have passed
since its last choice, it offers the network the candidates of
:mod:`rosmeery_jax.rl.candidates` (the current target, and targets drawn over the cells the
robot can reach on its own map) and sends the navigator to the one it scores highest;
otherwise it keeps the target. Two things differ from training, where exploring matters:
it takes the most likely candidate instead of sampling one, from ``CANDIDATES`` draws
instead of the training offer's (the network scores each candidate alone, so any number
fits). Both were chosen on the paper worlds (docs/learned.md). The session asks every
``decide_every`` of its own (default 1 s), so a done target waits at most that long, as
for the baselines. It runs in the session's env: env settings recorded in the policy file
are not applied.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp

from rosmeery_jax.core import specs
from rosmeery_jax.policies.base import Policy
from rosmeery_jax.rl.candidates import driving, offer
from rosmeery_jax.rl.network import ActorCritic, load_policy
from rosmeery_jax.rl.task import flat_obs

CANDIDATES = 32  # targets drawn at each session decision (training offers the policy file's rl.candidates)
SHIPPED = Path(__file__).resolve().parent / "learned_policy.msgpack"


def policy_file(spec: str) -> Path:
    """The policy file of a ``learned`` or ``learned:PATH`` entry."""
    parsed = specs.parse(spec)
    return Path(parsed.body) if parsed.kind == "learned" else SHIPPED


def label(spec: str) -> str:
    """The entry's name in results: ``learned``, or ``learned_<name>`` for ``learned:PATH``
    (``<name>`` the file's stem, or its folder's name for ``.../policy.msgpack``)."""
    if specs.kind(spec) != "learned":
        return "learned"
    path = policy_file(spec)
    name = path.parent.name if path.stem == "policy" and path.parent.name else path.stem
    return "learned_" + "".join(c if c.isalnum() or c in "-_" else "_" for c in name)


class Choice(NamedTuple):
    """The policy's state: target (3,) and chosen_at int32 (the control step of its last choice)."""

    target: jax.Array
    chosen_at: jax.Array


class LearnedPolicy(Policy):
    def __init__(self, env, spec: str = "learned"):
        super().__init__(env)
        self.name = label(spec)
        self.rl, _, params = load_policy(policy_file(spec))
        self.params = jax.tree.map(jnp.asarray, params)
        self.net = ActorCritic()

    def init(self, key):
        return Choice(jnp.zeros(3, jnp.float32), jnp.int32(0))

    def decide(self, state, ps: Choice, key):
        on_offer = self.candidates(state, ps, key)
        picked = on_offer.targets[jnp.argmax(self.logits(state, on_offer))]  # the most likely: no exploring in sessions
        due = ~driving(state) | (state.t - ps.chosen_at >= self.rl.decide_every)
        target = jnp.where(due, picked, ps.target)
        return target, Choice(target, jnp.where(due, state.t, ps.chosen_at))

    def candidates(self, state, ps: Choice, key):
        """The ``Offer`` of this decision: the kept target and ``CANDIDATES`` draws."""
        return offer(self.env, state, ps.target, key, CANDIDATES, self.rl.radius)

    def logits(self, state, on_offer) -> jax.Array:
        """(K + 1,) the network's score of each candidate of ``on_offer`` (an ``Offer``)."""
        return self.net.apply(self.params, flat_obs(on_offer))[0]
