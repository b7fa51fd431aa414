"""Shared test helpers: tiny hand-made worlds written as MJCF."""

from __future__ import annotations

import contextlib
import os
import re
from pathlib import Path

import pytest

# One persistent compilation cache for the whole suite (and across CI runs on one machine).
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(Path(__file__).resolve().parents[1] / ".jax_cache"))
# One host device per test process: a session's default (one per core) would compile a copy of
# its program per device, twice the compiling beside the other xdist worker. Results do not
# depend on the device count; test_cluster checks two devices in a process of its own.
if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=1".strip()
# The suite's sessions are short: most of their time is XLA compiling, not running. LLVM's
# quick pipeline compiles a 4 s two-robot session in 17 s instead of 23 s; the code runs about
# 4x slower (a 120 s ten-robot session: 8 -> 34 s), which a few hundred steps do not feel.
# Results may differ from a default build in the last bits, so a test's subprocess sessions
# keep these flags (``suite_xla_flags``). Sessions outside the suite keep XLA's defaults.
# XLA's older fusion emitters compile a session about a third faster again (two-robot 4 s
# session: 23 -> 15 s of compile under load); the suite's test files run 14 % faster in all.
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] += (" --xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
                                " --xla_cpu_parallel_codegen_split_count=1 --xla_cpu_use_fusion_emitters=false")


# XLA's own optimisations back, for the few programs that run thousands of robot-steps: there the
# quick pipeline's slower code costs more than its faster compile saves (16 robots, 625
# steps: compile 20 -> 31 s, run 85 -> 13 s; 2-core Xeon, 2026-11-28). Per compiled
# function, as compiler options, so the rest of the process keeps the quick pipeline.
OPTIMIZED = {"xla_backend_optimization_level": 3, "xla_llvm_disable_expensive_passes": False,
             "xla_cpu_use_fusion_emitters": True}


@contextlib.contextmanager
def optimized():
    """Functions compiled by ``rosmeery_jax.jit`` within get :data:`OPTIMIZED` too."""
    from rosmeery_jax.core import xla

    with pytest.MonkeyPatch.context() as mp:
        for name, value in OPTIMIZED.items():
            mp.setitem(xla.COMPILER_OPTIONS, name, value)
        yield


def suite_xla_flags() -> str:
    """The suite's XLA flags less the host device count, for a subprocess that sets its own."""
    return re.sub(r"\s*--xla_force_host_platform_device_count=\d+", "", os.environ["XLA_FLAGS"]).strip()


# The slowest files first (cold-cache seconds on 2 cores, most of them compiling: test_engine
# about 370, test_stats under 1), so the two xdist workers (pyproject: a file per worker at a
# time, in this order) finish together rather than one waiting for the other's last long
# file. Within a file the order is unchanged.
SLOWEST_FIRST = ("test_engine", "test_cluster", "test_rl", "test_plugins", "test_hardening", "test_platform",
                 "test_detector", "test_noise", "test_runtime", "test_gym", "test_teleop", "test_session",
                 "test_metrics", "test_tasks", "test_navigation", "test_procedural", "test_experiments", "test_record",
                 "test_ros_bags", "test_rerun_view", "test_digest", "test_integrity", "test_safety", "test_explorers",
                 "test_field_metrics")


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(SLOWEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.stem, len(rank)))


def room_xml(bodies: str, categories: dict[str, str], spawn=(0.0, 0.0, 0.0), half: float = 2.0,
             walls: bool = True, extra_custom: str = "", height: float = 2.0) -> str:
    """A square room of side 2*half (walls 0.1 m thick, ``height`` high) around the origin."""
    wall = ""
    if walls:
        t, h = 0.05, half + 0.05
        wall = "\n".join(
            f'<geom name="wall_{i}" type="box" pos="{x} {y} {height / 2}" size="{sx} {sy} {height / 2}"/>'
            for i, (x, y, sx, sy) in enumerate([(h, 0, t, h + t), (-h, 0, t, h + t), (0, h, h + t, t), (0, -h, h + t, t)])
        )
    cats = "\n".join(f'<text name="rosmeery:category:{b}" data="{c}"/>' for b, c in categories.items())
    return f"""<mujoco model="test_room">
  <compiler angle="radian"/>
  <asset><material name="floor" rgba="0.7 0.7 0.7 1"/></asset>
  <custom>
    <numeric name="rosmeery:spawn" data="{spawn[0]} {spawn[1]} {spawn[2]}"/>
    {cats}
    {extra_custom}
  </custom>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 0.05" material="floor"/>
    {wall}
    {bodies}
  </worldbody>
</mujoco>
"""


@pytest.fixture
def write_world(tmp_path):
    """write_world(xml, name='w') -> Path of the file."""

    def _write(xml: str, name: str = "room") -> Path:
        path = tmp_path / f"{name}.xml"
        path.write_text(xml)
        return path

    return _write


# A small session setting shared by the modules that run many tiny sessions (each module's
# sessions then share one compiled function through the persistent cache).
SMALL_RUN = ["run", "--worlds", "small_office", "--policies", "random,frontier", "--duration", "4", "--detector",
             "off", "--quiet"]


def one_line_error(capsys, *needles) -> str:
    """The command's stderr: exactly one line, holding every needle."""
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for n in needles:
        assert n in err, (n, err)
    return err
