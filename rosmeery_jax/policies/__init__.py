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

from rosmeery_jax.core import specs
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.env import EnvConfig, RobotEnv
from rosmeery_jax.policies.base import Policy
from rosmeery_jax.policies.frontier import FrontierPolicy
from rosmeery_jax.policies.gradient_nbv import GradientNBVPolicy
from rosmeery_jax.policies.learned import LearnedPolicy, policy_file
from rosmeery_jax.policies.learned import label as learned_label
from rosmeery_jax.policies.plugin import check_plugin, plugin_class
from rosmeery_jax.policies.random_walk import RandomPolicy
from rosmeery_jax.policies.semantic_nbv import SemanticNBVPolicy
from rosmeery_jax.policies.teleop_replay import ReplayPolicy, recordings_by_world
from rosmeery_jax.rl.network import load_policy

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
    kind = specs.kind(spec)
    if kind == "replay":
        return ReplayPolicy
    if kind == "learned":
        return LearnedPolicy
    if kind == "plugin":
        return plugin_class(spec)
    if spec not in POLICIES:
        raise InputError("config", "policies", f"unknown policy {spec!r} (built in: {', '.join(POLICIES)}, "
                         f"{specs.LEARNED}FILE, {specs.REPLAY}FILE[+FILE...], or a plugin FILE.py:Name)")
    return Policy


def policy_label(spec: str) -> str:
    """The name a policy entry has in results: ``replay:FILES`` -> ``replay``,
    ``learned:PATH`` -> ``learned_<name>``, a plugin -> its class's ``name``."""
    kind = specs.kind(spec)
    if kind == "learned":
        return learned_label(spec)
    if kind == "plugin":
        return plugin_class(spec).name
    return "replay" if kind == "replay" else spec


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


def check_entry(spec: str, worlds: set[str], stage) -> None:
    """A policy entry before a session runs (one InputError naming it): a plugin makes a
    first decision on ``stage()`` (env, state); a learned policy's file loads; a replay's
    recordings are of one of the session's ``worlds`` (names) and share env settings per
    world."""
    kind = specs.kind(spec)
    if kind == "plugin":
        check_plugin(spec, *stage())
    if policy_class(spec) is LearnedPolicy:
        load_policy(policy_file(spec))  # one line naming the file if it is not a policy file
    if kind != "replay":
        return
    recorded = recordings_by_world(spec)
    if not set(recorded) & worlds:
        raise InputError("config", "policies", f"no recording in {spec!r} is of a session world "
                         f"(recorded in: {', '.join(sorted(recorded))})")
    for recs in recorded.values():  # one batch per world: one set of env settings
        for rec in recs:
            EnvConfig.from_table(rec.header.get("env", {}), f"{rec.path}: line 1")
            if rec.header.get("env", {}) != recs[0].header.get("env", {}):
                raise InputError(str(rec.path), "line 1: env", f"differs from {recs[0].path}'s: recordings "
                                 "replayed together need the same env settings")


__all__ = ["POLICIES", "check_entry", "LearnedPolicy", "Policy", "make_policy", "policy_class", "policy_label"]
