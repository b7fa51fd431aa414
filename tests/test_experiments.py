"""The experiment configurations the docs quote: each validates as a new user would run it,
from the repository root, its plugin explorers built and traced for one decision (the
check a session makes also compiles and runs it: tests/test_plugins.py covers that, and
here it would compile nine gradient_nbv variants, a minute of the suite); and the kept
plans' bookkeeping."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

from rosmeery_jax import policies
from rosmeery_jax.policies import plugin
from rosmeery_jax.rl import ppo
from rosmeery_jax.session.config import load_config

ROOT = Path(__file__).resolve().parents[1]
SESSIONS = sorted(p.relative_to(ROOT) for p in (ROOT / "experiments").rglob("*.toml") if p.name != "ppo.toml")


def test_every_session_config_is_found():
    names = {p.name for p in SESSIONS}
    assert {"session.toml", "confident.toml", "evaluate.toml", "gradient_variants.toml", "view_oracle.toml",
            "object_views.toml", "known_targets.toml"} <= names


@pytest.mark.parametrize("path", SESSIONS, ids=str)
def test_an_experiment_config_validates(path, monkeypatch):
    monkeypatch.chdir(ROOT)  # plugin paths in the configs are relative to the repository root
    traced = []

    def trace_only(spec, env, state):
        policy = plugin.plugin_class(spec)(env)
        key = jax.random.key(0)
        target, _ = jax.eval_shape(policy.decide, state, policy.init(key), key)
        assert target.shape == (3,), spec
        traced.append(spec)

    monkeypatch.setattr(policies, "check_plugin", trace_only)
    cfg = load_config(path)
    assert cfg.out.startswith("results/")
    assert all(Path(p.split(":")[0]).is_file() for p in cfg.policies if ".py:" in p)
    assert traced == [p for p in cfg.policies if ".py:" in p]  # every plugin explorer traced


def test_the_training_config_validates(monkeypatch):
    monkeypatch.chdir(ROOT)
    cfg = ppo.load_train_config("experiments/learned/ppo.toml")
    assert not any(w.startswith(("kitchen", "laboratory", "small_office", "large_office")) for w in cfg.worlds)


def test_a_kept_plan_drives_its_legs_in_order_then_chooses_again(monkeypatch):
    """view_oracle_ori_2step_kept's bookkeeping, with three legs and plans stubbed: the best
    plan but the kept target's (slot 0) is driven leg by leg, each leg taken only when the
    navigator is done with the last, and a new plan chosen only when all are driven."""
    monkeypatch.chdir(ROOT)
    kept = plugin.plugin_class("experiments/learned/view_oracle.py:KeptPlans")
    calls = []

    class ThreeLegs(kept):
        legs = 3

        def plans(self, state, ps, key):
            calls.append(None)
            legs = jnp.arange(4 * 3 * 3, dtype=jnp.float32).reshape(4, 3, 3) + 100 * len(calls)
            return legs, jnp.array([9.0, 1.0, 5.0, 2.0])  # slot 0 best, but done with; then slot 2

    driving = [False]
    monkeypatch.setitem(kept.decide.__globals__, "driving", lambda state: jnp.bool_(driving[0]))
    policy, targets = ThreeLegs(None), []
    ps = policy.init(jax.random.key(0))
    for drive in (False, True, False, True, False, False):
        driving[0] = drive
        target, ps = policy.decide(None, ps, None)
        targets.append(int(target[0]))
    # the first plan is slot 2's three legs (x = 118, 121, 124); the sixth decision, with all
    # driven, takes slot 2 of the sixth call's plans
    assert targets == [118, 118, 121, 121, 124, 618]
