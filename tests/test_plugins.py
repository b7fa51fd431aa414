"""Plugins by name: a researcher's own explorer and metric, named FILE.py:Name or
package.module:Name, run like the built-ins; a broken plugin is one line naming it."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from conftest import one_line_error

from rosmeery_jax.apps.cli import main
from rosmeery_jax.env import make

ROOT = Path(__file__).resolve().parents[1]
SESSION = ["run", "--worlds", "small_office", "--seeds", "2", "--duration", "6", "--detector", "oracle", "--quiet"]
SAME_AS_FRONTIER = '''
from rosmeery_jax.policies.frontier import FrontierPolicy


class MyFrontier(FrontierPolicy):
    name = "my_frontier"

    def __init__(self, env):
        super().__init__(env, choose="biggest")
'''

SAME_AS_PERCEIVED = '''
from rosmeery_jax.mapping.perceived import PerceivedMapper


class MyPerceived(PerceivedMapper):
    name = "my_perceived"
'''


FRONTIER_AGENT = '''from types import SimpleNamespace

import jax
import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.gym import Agent
from rosmeery_jax.policies.frontier import FrontierPolicy


class FrontierAgent(Agent):
    """Sends the targets frontier would send, computed on the host from the observations."""

    name = "frontier_agent"

    def __init__(self, env):
        super().__init__(env)
        world = env.bank.env_at(0)
        policy = FrontierPolicy(world)

        def decide(occupancy, pose, status, pstate):
            mine = SimpleNamespace(grid=world.grid, occupancy=lambda s: (occupancy + 1).astype(jnp.int8))
            state = SimpleNamespace(pose=pose, nav=SimpleNamespace(status=status.astype(jnp.int32)))
            return policy.bind(mine).decide(state, pstate, jax.random.key(0))

        self.decide = jax.jit(jax.vmap(decide))
        self.pstate = jax.vmap(policy.init)(jax.random.split(jax.random.key(0), env.num_envs))

    def act(self, obs):
        target, self.pstate = self.decide(obs["occupancy"], obs["pose"], obs["nav_status"][:, 0], self.pstate)
        return np.asarray(target)
'''


def _same(df, column, a, b):
    """The rows with ``column`` a and b hold bitwise the same curves."""
    rest = [c for c in ("world", "policy", "mapper", "seed", "metric", "time_s") if c != column]
    x, y = (df[df[column] == v].sort_values(rest)[rest + ["value"]].reset_index(drop=True) for v in (a, b))
    pd.testing.assert_frame_equal(x, y, check_exact=True)


def test_plugins_run_like_builtins_in_one_session(tmp_path, capsys):
    """One session: frontier, a plugin equal to it (bitwise the same curves: the same
    decisions in the one batch), the example explorer (it drives), a plugin metric, and
    mappers: perceived, a plugin equal to it (bitwise the same curves), the numpy example and
    one that reads the depth of every step (what it is sent: :func:`_check_sweeps`), with two
    detector frames per decision (``detect_every`` 5)."""
    plugin = tmp_path / "mine.py"
    plugin.write_text(SAME_AS_FRONTIER + SAME_AS_PERCEIVED)
    records = tmp_path / "records"
    records.mkdir()
    sweeper = tmp_path / "sweeper.py"
    sweeper.write_text(SWEEPER.format(out=str(records)))
    example = f"{ROOT / 'examples' / 'farthest_free_policy.py'}:FarthestFree"
    metric = f"{ROOT / 'examples' / 'metric_plugin.py'}:labelled_share"
    mapper = f"{ROOT / 'examples' / 'numpy_mapper.py'}:VoxelMapper"
    out, toml = tmp_path / "o", tmp_path / "frames.toml"
    toml.write_text("detect_every = 5\n")
    assert main([*SESSION, "--policies", f"frontier,{plugin}:MyFrontier,{example}", "--metrics",
                 f"ori,opi,{metric}", "--mapper", f"oracle,perceived,fused,{plugin}:MyPerceived,{mapper},{sweeper}:Sweeper",
                 "--config", str(toml), "--out", str(out)]) == 0
    assert "mappers (fed and scored)" in capsys.readouterr().out
    df = pd.read_csv(out / "metrics.csv")
    assert set(df.policy) == {"frontier", "my_frontier", "farthest_free"}
    assert set(df.metric) == {"ori", "opi", "labelled_share"}
    assert set(df.mapper) == {"oracle", "perceived", "fused", "my_perceived", "voxel_numpy", "sweeper"}
    _check_sweeps(records, 6, 5)
    assert json.loads((out / "timing.json").read_text())["frames"] == 6 * 12  # 6 robots, 2 a second
    _same(df, "policy", "frontier", "my_frontier")
    _same(df, "mapper", "perceived", "my_perceived")
    for name in ("voxel_numpy", "fused"):  # a plugin's and the built-in fused mapper's maps
        own = df[(df.mapper == name) & (df.metric == "ori")]
        assert own.value.between(0, 1).all() and own[own.time_s == 0].value.eq(0).all() and own.value.max() > 0
        assert (out / "maps" / f"small_office__frontier__seed0__{name}.ply").is_file()
    share = df[df.metric == "labelled_share"].value
    assert share.between(0, 1).all() and share.max() > 0
    path = pd.read_csv(out / "trajectories.csv").query("policy == 'farthest_free'")
    for _, seed in path.groupby("seed"):  # the example drives towards the far free cells it chose
        start, end = seed.iloc[0], seed.iloc[-1]
        assert ((end.x - start.x) ** 2 + (end.y - start.y) ** 2) ** 0.5 > 0.2  # (turning first)


SWEEPER = '''
import numpy as np

from rosmeery_jax.mapping.protocol import Mapper, MapState

OUT = {out!r}


class Sweeper(Mapper):
    """Records what it is sent: detector frames and the depth of the steps between them."""

    name = "sweeper"

    def __init__(self, camera, categories):
        super().__init__(camera, categories)
        self.sent, self.depths, self.poses = [], [], []

    def add(self, frame):
        self.sent.append((0, frame.index, frame.time_s))

    def add_depth(self, frame):
        assert np.allclose(frame.camera_pose, self.camera.pose(frame.pose))
        self.sent.append((1, frame.step, frame.time_s))
        self.depths.append(frame.depth)
        self.poses.append(frame.pose)

    def semantic_map(self):
        if self.depths:  # the latest record of each robot's mapper: one file per robot
            np.savez(f"{{OUT}}/{{id(self)}}.npz", sent=np.array(self.sent), depth=np.stack(self.depths),
                     pose=np.stack(self.poses))
        return MapState(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros(0, np.float32))
'''


def _check_sweeps(records, runs: int, every: int) -> None:
    """Each robot's Sweeper got a detector frame every ``every`` steps and the depth of every
    step between them, in time order, each the depth camera's image at its pose (no return: 0)."""
    sent = [np.load(f) for f in sorted(records.glob("*.npz"))]
    assert len(sent) == runs  # one per robot (the check before the session sends no depth)
    env = make("small_office")
    periods = 60 // every  # 6 s of 0.1 s steps
    expect = [(1, every * k + j, (every * k + j) / 10) for k in range(periods) for j in range(1, every)]
    expect = sorted(expect + [(0, k, (k + 1) * every / 10) for k in range(periods - 1)],
                    key=lambda e: (e[2], -e[0]))  # the last map (at 6 s) holds the frames taken
    # before 6 s and the depth of every step before the last
    look = jax.jit(env.look)
    for run in sent:
        np.testing.assert_allclose(run["sent"], expect, atol=1e-9)
        assert run["depth"].shape == (periods * (every - 1), 48, 64)
        for k in (0, 20, len(run["depth"]) - 1):
            depth = np.asarray(look(jnp.asarray(run["pose"][k], jnp.float32))[0])
            np.testing.assert_allclose(run["depth"][k], np.where(depth < 8.0, depth, 0.0), atol=1e-4)
    assert max(np.ptp(run["pose"][:, :2], axis=0).max() for run in sent) > 0.1  # the robots drove


BROKEN = {
    "syntax": ("class P(:\n", "failed to import", "SyntaxError: invalid syntax (broken.py, line 1)"),
    "import": ("import no_such_module_here\n", "failed to import",
               "ModuleNotFoundError: No module named 'no_such_module_here' (broken.py, line 1, in <module>)"),
    "missing": ("x = 1\n", "defines no 'P'", ""),
    "not_a_policy": ("class P:\n    name = 'p'\n", "is not a Policy class", ""),
    "no_decide": ("from rosmeery_jax import Policy\nclass P(Policy):\n    name = 'p'\n", "lacks a decide", ""),
    "no_name": ("from rosmeery_jax import Policy\nclass P(Policy):\n    def decide(self, s, p, k):\n"
                "        return s.pose, p\n", "needs a class attribute name", ""),
    "shape": ("from rosmeery_jax import Policy\nclass P(Policy):\n    name = 'p'\n    def decide(self, s, p, k):\n"
              "        return s.pose[:2], p\n", "shape (2,)", ""),
    "nan": ("import jax.numpy as jnp\nfrom rosmeery_jax import Policy\nclass P(Policy):\n    name = 'p'\n"
            "    def decide(self, s, p, k):\n        return s.pose * jnp.nan, p\n", "not finite", ""),
    "untraceable": ("from rosmeery_jax import Policy\nclass P(Policy):\n    name = 'p'\n"
                    "    def decide(self, s, p, k):\n        if s.pose[0] > 0:\n            pass\n"
                    "        return s.pose, p\n", "cannot run under JAX", ""),
    "state": ("import jax.numpy as jnp\nfrom rosmeery_jax import Policy\nclass P(Policy):\n    name = 'p'\n"
              "    def decide(self, s, p, k):\n        return s.pose, jnp.zeros(4)\n", "policy state unlike init", ""),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_a_broken_policy_plugin_is_one_line_naming_it_with_nothing_written(tmp_path, capsys, case):
    code, needle, extra = BROKEN[case]
    plugin = tmp_path / "broken.py"
    plugin.write_text(code)
    out = tmp_path / "o"
    assert main([*SESSION, "--policies", f"{plugin}:P", "--out", str(out)]) == 2
    one_line_error(capsys, "broken.py:P", needle, extra)
    assert not out.exists()


MAPPER_HEAD = "import numpy as np\nfrom rosmeery_jax import Mapper, MapState\nclass M(Mapper):\n    name = 'm'\n"
ADD = "    def add(self, frame):\n        pass\n"
BROKEN_MAPPERS = {
    "not_a_mapper": ("class M:\n    pass\n", "is not a Mapper class"),
    "no_map": (MAPPER_HEAD + ADD, "lacks a semantic_map method"),
    "raises": (MAPPER_HEAD + "    def add(self, frame):\n        raise ValueError('boom')\n"
               "    def semantic_map(self):\n        pass\n", "failed on a test frame: ValueError: boom"),
    "not_a_map": (MAPPER_HEAD + ADD + "    def semantic_map(self):\n        return {}\n", "not a MapState"),
    "shape": (MAPPER_HEAD + ADD + "    def semantic_map(self):\n        return MapState(np.zeros((4, 2)), "
              "np.zeros(4, int), np.zeros(1, int), np.ones(1))\n", "not (V, 3) floats"),
    "nan": (MAPPER_HEAD + ADD + "    def semantic_map(self):\n        return MapState(np.full((4, 3), np.nan), "
            "np.zeros(4, int), np.zeros(1, int), np.ones(1))\n", "not finite"),
    "ids": (MAPPER_HEAD + ADD + "    def semantic_map(self):\n        return MapState(np.zeros((4, 3)), "
            "np.full(4, 2), np.zeros(1, int), np.ones(1))\n", "instance ids outside [0, 1)"),
    "label": (MAPPER_HEAD + ADD + "    def semantic_map(self):\n        return MapState(np.zeros((4, 3)), "
              "np.zeros(4, int), np.full(1, 999), np.ones(1))\n", "labels outside"),
    # passes the test frame, then raises in the session: a traceback through the engine's threads
    "raises_later": (MAPPER_HEAD + "    n = 0\n    def add(self, frame):\n        M.n += 1\n        if M.n > 1:\n"
                     "            raise ValueError('late')\n    def semantic_map(self):\n        return MapState("
                     "np.zeros((0, 3)), np.zeros(0, int), np.zeros(0, int), np.zeros(0))\n",
                     "failed in add (frame 0): ValueError: late (mapper.py, line 9, in add)"),
}


@pytest.mark.parametrize("case", sorted(BROKEN_MAPPERS))
def test_a_broken_mapper_plugin_is_one_line_naming_it_with_nothing_written(tmp_path, capsys, case):
    code, needle = BROKEN_MAPPERS[case]
    plugin = tmp_path / "mapper.py"
    plugin.write_text(code)
    out = tmp_path / "o"
    assert main([*SESSION, "--policies", "random", "--mapper", f"oracle,{plugin}:M", "--out", str(out)]) == 2
    one_line_error(capsys, "mapper.py:M", needle)
    assert not out.exists()


@pytest.mark.parametrize("code, needle", [
    ("def m(log, truth):\n    return log.ps\n", "must return one float per step"),
    ("def m(log, truth):\n    return float(log.ps.sum())\n", "cannot run under JAX"),
    ("m = 3\n", "is not a function"),
    ("import rosmeery_jax\n@rosmeery_jax.register_metric('../up')\ndef m(log, truth):\n    return log.ps.sum(-1)\n",
     "'../up' is not a plain name"),  # its plots would be named after it
])
def test_a_broken_metric_plugin_is_one_line(tmp_path, capsys, code, needle):
    plugin = tmp_path / "metric.py"
    plugin.write_text(code)
    assert main([*SESSION, "--policies", "random", "--metrics", f"ori,{plugin}:m", "--out", str(tmp_path / "o")]) == 2
    one_line_error(capsys, "metric.py:m", needle)
    assert not (tmp_path / "o").exists()


def test_a_missing_plugin_file_and_a_module_plugin(tmp_path, capsys):
    assert main([*SESSION, "--policies", f"{tmp_path}/nowhere.py:P", "--out", str(tmp_path / "o")]) == 2
    one_line_error(capsys, "no such file")
    from rosmeery_jax.policies import policy_label

    module = "rosmeery_jax.policies.random_walk:RandomPolicy"  # package.module:Name
    assert policy_label(module) == "random"
    assert main([*SESSION, "--policies", f"random,{module}", "--out", str(tmp_path / "o")]) == 2
    one_line_error(capsys, "'random' appears twice")  # the same label would share run files


def test_python_agents_run_in_a_session_and_one_sending_frontiers_targets_follows_frontier(tmp_path, capsys):
    """A host-side agent computing frontier's targets from its observations makes frontier's
    decisions: the runs agree to float rounding (the vector env's step is compiled apart
    from the session's chunk function, so poses may differ in the last bits; over longer
    runs such a difference can flip a decision). The PyTorch example runs beside them, and
    --resume finds every run done."""
    agent = tmp_path / "agent.py"
    agent.write_text(FRONTIER_AGENT)
    torch_agent = f"agent:{ROOT / 'examples' / 'torch_agent.py'}:TorchFrontier"
    out = tmp_path / "o"
    run = ["run", "--worlds", "small_office", "--seeds", "2", "--duration", "6", "--detector", "off", "--quiet",
           "--policies", f"frontier,agent:{agent}:FrontierAgent,{torch_agent}", "--out", str(out)]
    assert main(run) == 0
    df = pd.read_csv(out / "metrics.csv")
    assert set(df.policy) == {"frontier", "frontier_agent", "torch_frontier"}
    key = ["seed", "metric", "time_s"]
    a, b = (df[df.policy == p].sort_values(key).reset_index(drop=True) for p in ("frontier", "frontier_agent"))
    assert (a[key] == b[key]).all().all() and (a.value - b.value).abs().max() < 1e-4
    paths = pd.read_csv(out / "trajectories.csv")
    x, y = (paths[paths.policy == p].sort_values(["seed", "time_s"])[["x", "y"]].to_numpy()
            for p in ("frontier", "frontier_agent"))
    assert abs(x - y).max() < 1e-4 and abs(x[-1] - x[0]).max() > 0.1  # the same path, and a real one
    own = df[(df.policy == "torch_frontier") & (df.metric == "ori")]
    assert own.value.max() > 0 and (out / "maps" / "small_office__torch_frontier__seed1.ply").is_file()
    before = (out / "metrics.csv").read_bytes()
    assert main([*run, "--resume"]) == 0 and (out / "metrics.csv").read_bytes() == before


AGENT_HEAD = "import numpy as np\nfrom rosmeery_jax.gym import Agent\nclass A(Agent):\n    name = 'a'\n"


@pytest.mark.parametrize("code, extra, needle", [
    ("class A:\n    pass\n", [], "is not an Agent class"),
    (AGENT_HEAD, [], "lacks an act(obs) method"),
    (AGENT_HEAD + "    def act(self, obs):\n        return np.zeros((2, 2))\n", [], "shape (2, 2), not (2, 3)"),
    (AGENT_HEAD + "    def act(self, obs):\n        return obs['pose'] * np.nan\n", [], "not finite"),
    (AGENT_HEAD + "    def act(self, obs):\n        return obs['pose']\n", ["--detector", "oracle"], "--detector off"),
    (AGENT_HEAD + "    def act(self, obs):\n        raise ValueError('no')\n", [],  # a traceback
     "failed in act (decision 0): ValueError: no (agent.py, line 6, in act)"),
])
def test_a_broken_agent_is_one_line_with_nothing_written(tmp_path, capsys, code, extra, needle):
    plugin = tmp_path / "agent.py"
    plugin.write_text(code)
    out = tmp_path / "o"
    run = ["run", "--worlds", "small_office", "--seeds", "2", "--duration", "2", "--detector", "off", "--quiet",
           *extra, "--policies", f"agent:{plugin}:A", "--out", str(out)]
    assert main(run) == 2
    one_line_error(capsys, "agent.py:A", needle)
    assert not out.exists() or not any(out.iterdir())
