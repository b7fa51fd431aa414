"""Exploration policies: pure, vmappable functions from the env state to a target pose.

A policy is built for one env (``make_policy(name, env, **options)``) and has
``init(key) -> pstate`` and ``decide(state, pstate, key) -> (target (3,), pstate)`` for one
env; the session runner vmaps them over seeds and calls ``decide`` once every
``decide_every`` control steps (default 10 = 1 s), so the batch does not pay for a decision
every step. Between decisions the navigator keeps driving to the last target.

Built in: ``random`` (the paper's random walker), ``frontier`` (biggest frontier, the
paper's; ``frontier_nearest`` for the nearest), ``semantic_nbv`` (views around the objects
the robot has labelled, scored by expected new surface per metre).
"""

from __future__ import annotations

from rosmeery_jax.errors import InputError
from rosmeery_jax.policies.base import Policy
from rosmeery_jax.policies.frontier import FrontierPolicy
from rosmeery_jax.policies.random_walk import RandomPolicy
from rosmeery_jax.policies.semantic_nbv import SemanticNBVPolicy

POLICIES = {
    "random": lambda env, **kw: RandomPolicy(env, **kw),
    "frontier": lambda env, **kw: FrontierPolicy(env, choose="biggest", **kw),
    "frontier_nearest": lambda env, **kw: FrontierPolicy(env, choose="nearest", **kw),
    "semantic_nbv": lambda env, **kw: SemanticNBVPolicy(env, **kw),
}


def make_policy(name: str, env, **options) -> Policy:
    if name not in POLICIES:
        raise InputError("config", "policies", f"unknown policy {name!r} (built in: {', '.join(POLICIES)})")
    return POLICIES[name](env, **options)


__all__ = ["POLICIES", "Policy", "make_policy"]
