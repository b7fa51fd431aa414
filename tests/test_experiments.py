"""The experiment configurations the docs quote: each validates as a new user would run it,
from the repository root, its plugin explorers built and traced for one decision (the
check a session makes also compiles and runs it: tests/test_plugins.py covers that, and
here it would compile nine gradient_nbv variants, a minute of the suite)."""

from __future__ import annotations

from pathlib import Path

import jax
import pytest

from rosmeery_jax.policies import plugin
from rosmeery_jax.rl import ppo
from rosmeery_jax.session import config
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

    monkeypatch.setattr(config, "check_plugin", trace_only)
    cfg = load_config(path)
    assert cfg.out.startswith("results/")
    assert all(Path(p.split(":")[0]).is_file() for p in cfg.policies if ".py:" in p)
    assert traced == [p for p in cfg.policies if ".py:" in p]  # every plugin explorer traced


def test_the_training_config_validates(monkeypatch):
    monkeypatch.chdir(ROOT)
    cfg = ppo.load_config("experiments/learned/ppo.toml")
    assert not any(w.startswith(("kitchen", "laboratory", "small_office", "large_office")) for w in cfg.worlds)
