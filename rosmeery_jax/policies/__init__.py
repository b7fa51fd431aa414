"""Exploration policies: pure, vmappable functions from the env state to a target pose.

A policy is built for one env (``make_policy(spec, env, ...)``) and has
``init(key) -> pstate`` and ``decide(state, pstate, key) -> (target (3,), pstate)`` for one
env; the session runner vmaps them over seeds and calls ``decide`` once every
``decide_every`` control steps (default 10 = 1 s), so the batch does not pay for a decision
every step. Between decisions the navigator keeps driving to the last target.

Built in: ``random`` (the paper's random walker), ``frontier`` (biggest frontier, the
paper's; ``frontier_nearest`` for the nearest), ``semantic_nbv`` (views around the objects
the robot has labelled, scored by expected new surface per metre), ``gradient_nbv`` (views
refined by gradient ascent on expected soft coverage of the robot's own map), ``learned`` (the PPO-
trained explorer shipped in the package; ``learned:PATH`` for a policy file of
``rosmeery train``) and ``replay:FILES`` (recorded human-driven sessions).
"""

from __future__ import annotations

from rosmeery_jax.core import plugins
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.env import RobotEnv
from rosmeery_jax.policies import learned
from rosmeery_jax.policies.base import Policy
from rosmeery_jax.policies.frontier import FrontierPolicy
from rosmeery_jax.policies.gradient_nbv import GradientNBVPolicy
from rosmeery_jax.policies.learned import LearnedPolicy
from rosmeery_jax.policies.plugin import plugin_class
from rosmeery_jax.policies.random_walk import RandomPolicy
from rosmeery_jax.policies.teleop_replay import PREFIX as REPLAY_PREFIX
from rosmeery_jax.policies.teleop_replay import ReplayPolicy
from rosmeery_jax.policies.semantic_nbv import SemanticNBVPolicy

POLICIES = {
    "random": lambda env, **kw: RandomPolicy(env, **kw),
    "frontier": lambda env, **kw: FrontierPolicy(env, choose="biggest", **kw),
    "frontier_nearest": lambda env, **kw: FrontierPolicy(env, choose="nearest", **kw),
    "semantic_nbv": lambda env, **kw: SemanticNBVPolicy(env, **kw),
    "gradient_nbv": lambda env, **kw: GradientNBVPolicy(env, **kw),
    "learned": lambda env, **kw: LearnedPolicy(env, **kw),
}


def policy_class(spec: str) -> type[Policy]:
    """The class a policy entry builds (for its ``env_overrides`` before an env exists)."""
    if spec.startswith(REPLAY_PREFIX):
        return ReplayPolicy
    if spec.startswith(learned.PREFIX):
        return LearnedPolicy
    if plugins.is_plugin(spec):
        return plugin_class(spec)
    if spec not in POLICIES:
        raise InputError("config", "policies", f"unknown policy {spec!r} (built in: {', '.join(POLICIES)}, "
                         f"{learned.PREFIX}FILE, {REPLAY_PREFIX}FILE[+FILE...], or a plugin FILE.py:Name)")
    return Policy


def policy_label(spec: str) -> str:
    """The name a policy entry has in results: ``replay:FILES`` -> ``replay``,
    ``learned:PATH`` -> ``learned_<name>``, a plugin -> its class's ``name``."""
    if spec.startswith(learned.PREFIX):
        return learned.label(spec)
    if plugins.is_plugin(spec) and not spec.startswith(REPLAY_PREFIX):
        return plugin_class(spec).name
    return "replay" if spec.startswith(REPLAY_PREFIX) else spec


def make_policy(spec: str, env, decide_every: int = 10, total_steps: int = 0, **options) -> Policy:
    """A policy entry for ``env``; ``decide_every`` and ``total_steps`` serve ``replay:``."""
    if not isinstance(env, RobotEnv):  # a world's name was taken, and failed at the first decision
        raise TypeError(f"make_policy: env must be a RobotEnv (rosmeery_jax.make(world)), not {type(env).__name__}")
    cls = policy_class(spec)
    if cls is ReplayPolicy:
        return ReplayPolicy(env, spec, decide_every, total_steps)
    if cls is LearnedPolicy:
        return LearnedPolicy(env, spec)
    if cls is not Policy:  # a plugin: labelled by its class's name, whatever its instance sets
        policy = cls(env, **options)
        policy.name = cls.name
        return policy
    return POLICIES[spec](env, **options)


__all__ = ["POLICIES", "LearnedPolicy", "Policy", "make_policy", "policy_class", "policy_label"]
