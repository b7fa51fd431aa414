"""The package's architecture: layers that import one way, no cycles, torch out of the JAX
core, gymnax out of sessions (import-linter's contracts in pyproject.toml), and the public API."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import rosmeery_jax

ROOT = Path(__file__).resolve().parents[1]
LINT = Path(sys.executable).with_name("lint-imports")


def _lint(tree: Path) -> subprocess.CompletedProcess:
    """import-linter on the package under ``tree`` (its own pyproject.toml and sources)."""
    env = {"PYTHONPATH": str(tree), "PATH": "/usr/bin:/bin", "HOME": str(tree)}
    return subprocess.run([str(LINT), "--no-cache"], cwd=tree, capture_output=True, text=True, env=env, timeout=300)


@pytest.fixture(scope="module")
def copy(tmp_path_factory) -> Path:
    tree = tmp_path_factory.mktemp("tree")
    shutil.copytree(ROOT / "rosmeery_jax", tree / "rosmeery_jax", ignore=shutil.ignore_patterns("__pycache__", "*.pt",
                                                                                               "*.msgpack"))
    shutil.copy(ROOT / "pyproject.toml", tree / "pyproject.toml")
    return tree


def test_the_import_contracts_hold(copy):
    out = _lint(copy)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    assert "4 kept, 0 broken" in out.stdout


@pytest.mark.parametrize("module, line, broken", [
    # a lower layer reaching up: the world loader importing the command line
    ("world/load.py", "from rosmeery_jax.apps import cli  # noqa", "Layers point one way"),
    # a cycle between two sibling modules of one layer
    ("session/engine.py", "from rosmeery_jax.session import runner  # noqa", "No import cycles"),
    # torch in the JAX core
    ("env/environment.py", "import torch  # noqa", "torch stays out"),
    # a session's module reaching gymnax through the gymnax env
    ("gym.py", "from rosmeery_jax.rl import env  # noqa", "gymnax stays out"),
])
def test_a_deliberate_back_import_breaks_a_contract(copy, tmp_path, module, line, broken):
    tree = tmp_path / "tree"
    shutil.copytree(copy, tree)
    path = tree / "rosmeery_jax" / module
    path.write_text(path.read_text() + f"\n{line}\n")
    out = _lint(tree)
    assert out.returncode != 0
    assert f"{broken}" in out.stdout and "BROKEN" in out.stdout


def test_the_public_api_resolves_every_name():
    for name in rosmeery_jax.__all__:
        assert getattr(rosmeery_jax, name) is not None, name
    assert "Session" in dir(rosmeery_jax)
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        rosmeery_jax.nope  # noqa: B018


def test_the_api_page_lists_every_public_name():
    page = (ROOT / "docs" / "api.md").read_text()
    missing = [n for n in rosmeery_jax.__all__ if not re.search(rf"`{n}[`(]", page)]
    assert not missing, f"docs/api.md does not list {missing}"


def test_no_two_modules_or_public_classes_share_a_name():
    """One name, one concept: modules (a layer's config.py aside) and public classes are
    named once in the package."""
    import ast
    from collections import defaultdict

    modules, classes = defaultdict(list), defaultdict(list)
    for path in (ROOT / "rosmeery_jax").rglob("*.py"):
        if path.name not in ("__init__.py", "__main__.py", "config.py"):
            modules[path.stem].append(path)
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                classes[node.name].append(path)
    assert {k: v for k, v in modules.items() if len(v) > 1} == {}
    assert {k: v for k, v in classes.items() if len(v) > 1} == {}


@pytest.mark.parametrize("face", ["session/program.py", "rl/env.py", "gym.py"])
def test_the_env_faces_step_robots_only_through_the_decision_core(face):
    """The session's chunk function, the gymnax env and the Gymnasium envs loop over no
    control steps of their own: they call env.decision.decide."""
    source = (ROOT / "rosmeery_jax" / face).read_text()
    assert "decide(env" in source
    assert not re.search(r"\benv\.step\(|fori_loop|while_loop", source), face
