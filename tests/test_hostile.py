"""What a hostile user tried on the newer surfaces (plugins, the Gymnasium envs, evaluate):
each case is one clear line (or a clear Python error) before anything is written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import SMALL_RUN, one_line_error
from hypothesis import given, settings
from hypothesis import strategies as st

from rosmeery_jax.apps.cli import main
from rosmeery_jax.core import specs

RUN = [*SMALL_RUN[:4], "random", *SMALL_RUN[5:], "--seeds", "1"]  # small_office x random, 4 s, detector off
METRICS = '''
import jax.numpy as jnp

def always_inf(log, truth):
    return jnp.full(log.ps.shape[:-1], jnp.inf)

def nan_later(log, truth):  # finite on the check's small logs, NaN once the robot has seen 50 samples
    return jnp.where(log.ps.sum(-1) > 50, jnp.nan, 0.0)

def whole_numbers(log, truth):
    return log.label.sum(-1)
'''
POLICIES = '''
import sys
from rosmeery_jax.policies.frontier import FrontierPolicy

class Spaced(FrontierPolicy):
    name = "my frontier"

class Long(FrontierPolicy):
    name = "f" * 300
'''


@pytest.fixture
def plugin_files(tmp_path) -> Path:
    (tmp_path / "metrics.py").write_text(METRICS)
    (tmp_path / "policies.py").write_text(POLICIES)
    (tmp_path / "exits.py").write_text("import sys\nsys.exit(0)\n")
    return tmp_path


@pytest.mark.parametrize("entry, needles", [
    ("metrics.py:always_inf", ("gave [inf, inf, inf] on a log of nothing seen", "finite numbers")),
    ("metrics.py:whole_numbers", ("gave int32 values of shape (3,)",)),
    ("exits.py:Anything", ("failed to import: it exits (sys.exit(0))",)),
])
def test_a_broken_metric_or_plugin_module_is_refused_before_the_session(plugin_files, capsys, entry, needles):
    out = plugin_files / "out"
    field = "--policies" if entry.startswith("exits") else "--metrics"  # the last --policies counts
    assert main([*RUN, field, f"{plugin_files / entry}", "--out", str(out)]) == 2
    one_line_error(capsys, *needles)
    assert not out.exists()


def test_a_metric_that_turns_nan_on_the_sessions_data_leaves_nothing(plugin_files, capsys):
    """It passes the check on small logs; its first run's curve is refused before any of the
    run's files is written, and the folder, with no run finished, is left as it was found."""
    out = plugin_files / "out"
    assert main([*RUN, "--metrics", f"ori,{plugin_files / 'metrics.py'}:nan_later", "--out", str(out)]) == 2
    one_line_error(capsys, "nan_later' gave nan at step", "a curve must be finite numbers")
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("name", ["Spaced", "Long"])
def test_a_policy_name_must_be_a_plain_name_of_at_most_64_characters(plugin_files, capsys, name):
    out = plugin_files / "out"
    assert main([*RUN[:4], f"{plugin_files / 'policies.py'}:{name}", *RUN[5:], "--out", str(out)]) == 2
    one_line_error(capsys, "needs a class attribute name", "at most 64 characters")
    assert not out.exists()


@given(st.text(max_size=80))
@settings(max_examples=200, deadline=None)
def test_a_label_name_is_letters_digits_and_few_marks(name):
    ok = specs.label_name(name)
    assert ok == (0 < len(name) <= 64 and not name.startswith((".", "-"))
                  and all(c.isascii() and (c.isalnum() or c in "_.-") for c in name))


def test_a_vector_env_too_large_for_memory_is_refused_before_it_allocates():
    from rosmeery_jax.gym import VectorEnv

    with pytest.raises(ValueError, match=r"num_envs 1,000,000,000: that many robots need about .* GB, more than"):
        VectorEnv(["small_office"], 10**9)


def _ascii_ply(path: Path, declared: int, rows: int) -> Path:
    head = ("ply\nformat ascii 1.0\nelement vertex %d\nproperty float x\nproperty float y\nproperty float z\n"
            "property int instance\nend_header\n" % declared)
    path.write_text(head + "".join(f"{0.5 + 0.1 * i} 0.5 0.3 {i}\n" for i in range(rows)))
    path.with_suffix(".json").write_text(json.dumps({"frame": {"world": "small_office", "time_s": 1.0}}))
    return path


@pytest.mark.parametrize("declared, rows, needle", [(5, 2, "body: 2 lines where the header declares 5"),
                                                    (1, 2, "body: 2 lines where the header declares 1")])
def test_an_ascii_ply_must_hold_what_its_header_declares(tmp_path, capsys, declared, rows, needle):
    ply = _ascii_ply(tmp_path / "m.ply", declared, rows)
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(tmp_path / "o")]) == 2
    one_line_error(capsys, str(ply), needle)
    assert not (tmp_path / "o").exists()


def test_an_ascii_vertex_line_holds_one_value_per_property(tmp_path, capsys):
    ply = _ascii_ply(tmp_path / "m.ply", 2, 2)
    ply.write_text(ply.read_text().replace("0.6 0.5 0.3 1", "0.6 0.5 0.3"))
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(tmp_path / "o")]) == 2
    one_line_error(capsys, str(ply))


@given(st.lists(st.tuples(st.integers(0, 6), st.integers(-1, 3)), min_size=1, max_size=60))
@settings(max_examples=100, deadline=None)
def test_each_instance_takes_its_most_common_label_the_smallest_of_ties(pairs):
    """The one-sort labelling agrees with counting instance by instance (which took
    instances x points steps: a map of 10^6 one-point instances did not finish)."""
    from rosmeery_jax.metrics.map_score import most_common

    group, value = (np.array(x) for x in zip(*pairs))
    ids, inst = np.unique(group, return_inverse=True)
    want = []
    for i in ids:
        vals, counts = np.unique(value[group == i], return_counts=True)
        want.append(vals[np.argmax(counts)])
    np.testing.assert_array_equal(most_common(inst, value, len(ids)), want)


def test_messages_name_the_join_and_the_transforms_cell(tmp_path):
    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.core.files import require_same
    from rosmeery_jax.metrics.align import read_transform

    with pytest.raises(InputError, match=r"a join needs the same setting"):
        require_same("b/config.json", {"worlds": ["kitchen"]}, {"worlds": ["small_office"]}, ["worlds"], "a join")
    path = tmp_path / "t.json"
    path.write_text(json.dumps({"transform": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, float("nan")], [0, 0, 0, 1]]}))
    with pytest.raises(InputError, match=r"t.json: transform\[2\]\[3\]: nan is not a finite number"):
        read_transform(path)


def test_ctrl_c_while_a_compile_runs_stops_at_once(monkeypatch):
    """A compile runs in a daemon thread and is waited for at safe points: a press stops the
    wait at once (it waited for the compile's end, 40 s cold), and the command knows a job
    still runs, so it exits without joining it."""
    import threading
    import time

    from rosmeery_jax.core import interrupt

    release = threading.Event()
    job = interrupt.background(lambda: release.wait(60), "compile")
    assert interrupt.busy()
    assert next(t for t in threading.enumerate() if t.name == "rosmeery-background-compile").daemon
    monkeypatch.setattr(interrupt._pressed, "is_set", lambda: True)  # Ctrl-C pressed under deferred()
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        interrupt.wait(job)
    assert time.monotonic() - t0 < 1.0
    release.set()
    job.result(timeout=5)
    time.sleep(0.1)
    assert not interrupt.busy()
