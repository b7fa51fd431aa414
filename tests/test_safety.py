"""Nothing lost, nothing written outside, nothing silently reinterpreted: every command
validates first, refuses an output that holds something else, writes nothing when it
refuses, and stops on Ctrl-C at a point it can resume from."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from conftest import SMALL_RUN, one_line_error

from rosmeery_jax.apps import cli
from rosmeery_jax.apps.cli import main
from rosmeery_jax.core.files import folder_lock
from rosmeery_jax.results.tables import METRIC_COLUMNS

RUN = SMALL_RUN  # test_hardening's setting: its compiled program is in the cache
PLY = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
       "property int instance\nend_header\n0.5 0.5 0.3 0\n0.6 0.5 0.3 0\n-1.0 0.2 0.4 1\n")


_one_line = one_line_error


def _tree(folder: Path) -> dict:
    return {p: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _map(folder: Path, name: str = "map", meta: dict | None = None, ply: str = PLY) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}.ply").write_text(ply)
    if meta is not False:
        meta = meta or {"frame": {"world": "small_office", "time_s": 5.0}, "objects": [{"id": 0, "label": "chair"}]}
        (folder / f"{name}.json").write_text(json.dumps(meta))
    return folder / f"{name}.ply"


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("safety") / "session"
    assert main([*RUN, "--seeds", "2", "--metrics", "ori", "--out", str(out)]) == 0
    return out


# --- overwrites ---

def test_evaluate_never_replaces_a_sessions_or_an_earlier_evaluations_tables(session, tmp_path, capsys):
    before = _tree(session)
    ply = _map(tmp_path / "maps")
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(session)]) == 2
    _one_line(capsys, str(session), "not empty")
    assert _tree(session) == before
    out = tmp_path / "eval"
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(out)]) == 0  # an ASCII PLY
    capsys.readouterr()
    first = _tree(out)
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(out)]) == 2
    _one_line(capsys, "not empty")
    assert _tree(out) == first
    target = tmp_path / "a_file"
    target.write_text("mine")
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(target)]) == 2
    _one_line(capsys, "a_file", "is a file")
    assert target.read_text() == "mine"
    named = tmp_path / "named"  # the name is the tables' policy column: one `rosmeery plot` would refuse
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--name", "../up", "--out", str(named)]) == 2
    _one_line(capsys, "--name", "'../up' is not a plain name")
    assert not named.exists()


def test_an_input_error_crosses_a_process_whole():
    """A Ray task's InputError reaches the driver pickled: it must rebuild, else Ray reports
    a failure to deserialise instead of the line."""
    import pickle

    from rosmeery_jax.core.errors import InputError

    err = pickle.loads(pickle.dumps(InputError("run.toml", "policies", "'p.py:P' drove seed 0")))
    assert type(err) is InputError and str(err) == "run.toml: policies: 'p.py:P' drove seed 0"
    assert (err.source, err.where, err.problem) == ("run.toml", "policies", "'p.py:P' drove seed 0")


def test_generate_never_replaces_an_edited_world(tmp_path, capsys):
    out = tmp_path / "worlds"
    args = ["worlds", "generate", "--kind", "office", "--seed", "4", "--count", "2", "--out", str(out)]
    assert main(args) == 0
    capsys.readouterr()
    edited = sorted(out.glob("*.xml"))[0]
    edited.write_text(edited.read_text().replace("</mujoco>", "<!-- my edit -->\n</mujoco>"))
    before = _tree(out)
    assert main(args) == 2
    _one_line(capsys, edited.name, "never replaced")
    assert _tree(out) == before
    for bad, needle in ((edited, "not a folder"), (tmp_path / "loop", "looping")):
        if bad.name == "loop":
            os.symlink(bad, bad)
        assert main([*args[:-1], str(bad)]) == 2
        _one_line(capsys, needle)


def test_an_edited_world_in_the_procedural_cache_is_refused(tmp_path, capsys, monkeypatch):
    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.world import load_world
    from rosmeery_jax.world.procedural import cache_dir

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    load_world("procedural:kitchen:7")
    cached = next(cache_dir().glob("*.xml"))
    cached.write_text(cached.read_text().replace("</mujoco>", "<!-- edited -->\n</mujoco>"))
    with pytest.raises(InputError, match="never replaced"):
        load_world("procedural:kitchen:7")


def test_a_dataset_or_weights_already_there_are_never_replaced(tmp_path, capsys):
    data = tmp_path / "data"
    data.mkdir()
    (data / "data.json").write_text("{}")
    assert main(["detector", "dataset", "--worlds", "small_office", "--per-world", "2", "--out", str(data)]) == 2
    _one_line(capsys, "not empty")
    assert (data / "data.json").read_text() == "{}"
    pytest.importorskip("torch")
    weights = tmp_path / "w.pt"
    weights.write_bytes(b"precious")
    assert main(["detector", "train", "--data", str(data), "--out", str(weights)]) == 2
    _one_line(capsys, "w.pt", "exists already")
    assert main(["detector", "train", "--data", str(data), "--out", str(tmp_path)]) == 2
    _one_line(capsys, "is a folder")
    assert weights.read_bytes() == b"precious"
    (tmp_path / "new.log.csv").write_text("my log")  # the log new.pt's training would write beside it
    assert main(["detector", "train", "--data", str(data), "--out", str(tmp_path / "new.pt")]) == 2
    _one_line(capsys, "new.log.csv", "exists already")
    assert (tmp_path / "new.log.csv").read_text() == "my log"


@pytest.mark.parametrize("args, needle", [
    (["detector", "dataset", "--per-world", "0"], "--per-world"), (["detector", "dataset", "--per-world", "-3"],
                                                                    "--per-world"),
    (["detector", "dataset", "--seed", "-1"], "--seed"), (["detector", "train", "--epochs", "0"], "--epochs"),
    (["detector", "dataset", "--worlds", "small_office", "--per-world", "1000000000"], "GB on disk"),  # was killed
    # for memory while drawing the viewpoints
    (["detector", "dataset", "--worlds", " , "], "--worlds: name at least one world"),  # wrote an empty dataset
    (["detector", "export", "--batch", "100000000"], "GB, more than this machine's"),  # torch's allocation
    (["detector", "export", "--size", "100000x100000"], "--size: '100000x100000' is not WxH"),  # traceback
    (["detector", "dataset", "--worlds", "small_office,small_office"], "appears twice"),  # its frames overwrote
    # each other
    (["detector", "train", "--batch", "0"], "--batch"), (["detector", "train", "--max-images", "0"], "--max-images"),
    (["teleop", "--world", "small_office", "--port", "70000"], "--port"),
    (["teleop", "--world", "small_office", "--port", "-1"], "--port"),
    (["teleop", "--world", "small_office", "--conf-threshold", "-1"], "--conf-threshold"),  # was taken
    (["teleop", "--world", "small_office", "--conf-threshold", "nan"], "--conf-threshold"),
    (["teleop", "--world", "small_office", "--seed", "-1"], "--seed"),
    (["teleop", "--world", "small_office", "--seed", str(2**64)], "--seed: 18446744073709551616 must be at most"),  # an
    # OverflowError after the compile
    (["detector", "dataset", "--seed", str(2**31)], "--seed: 2147483648 must be at most 2147483647"),
    (["worlds", "stats", "small_office", "--rows", "-1"], "--rows: -1 must be"),  # printed nothing, exit 0
    (["record", "--world", "small_office", "--seed", "3", "--seeds", "2"], "--seed"),
    # an oversize session names what made it so
    (["run", "--worlds", "small_office", "--seeds", "3", "--duration", "1e8"], "command line: duration: 3 seeds x"),
    (["run", "--worlds", "small_office", "--duration", "1e308"], "duration: 1e+308 s is more control steps"),  # hung
    (["run", "--worlds", "small_office", "--duration", "2e8", "--detector-period-s", "7"], "the nearest, 5 s or 8 s"),
    (["run", "--worlds", "small_office", "--seeds", "100000000", "--duration", "10"], "command line: seeds: 1000"),
])
def test_bad_numbers_are_one_line_before_anything(tmp_path, capsys, monkeypatch, args, needle):
    if args[:2] == ["detector", "train"]:
        pytest.importorskip("torch")
    monkeypatch.setattr(cli, "Teleop", lambda *a, **k: pytest.fail("teleop started"))  # not served forever
    out = tmp_path / "o"
    extra = [] if args[0] in ("teleop", "worlds") else ["--out", str(out / ("w.pt" if args[1] == "train" else "x"))]
    assert main([*args, *extra]) == 2
    _one_line(capsys, needle)
    assert not out.exists()


def test_world_pictures_need_a_file_and_a_folder(tmp_path, capsys):
    assert main(["world", "show", "small_office", "--out", str(tmp_path)]) == 2
    _one_line(capsys, "is a folder")
    target = tmp_path / "f"
    target.write_text("x")
    assert main(["worlds", "--pictures", str(target)]) == 2
    _one_line(capsys, "is a file")
    mine = tmp_path / "mine.png"  # a picture of the user's: never replaced
    mine.write_text("mine")
    assert main(["world", "show", "small_office", "--out", str(mine)]) == 2
    _one_line(capsys, "mine.png: --out: exists already")
    folder = tmp_path / "pictures"
    folder.mkdir()
    (folder / "laboratory.png").write_text("mine")
    assert main(["worlds", "--pictures", str(folder)]) == 2  # checked before the kitchen's is written
    _one_line(capsys, "laboratory.png: --pictures: exists already")
    assert mine.read_text() == "mine" and [p.name for p in folder.iterdir()] == ["laboratory.png"]
    assert main(["world", "show", "small_office", "--out", str(tmp_path / "small.txt")]) == 2  # was a traceback
    _one_line(capsys, "small.txt: --out: '.txt' is not a picture format")


# --- sessions: late errors, resumes, locks, interrupts ---

def test_a_late_error_leaves_no_config_behind(tmp_path, capsys):
    pytest.importorskip("torch")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not weights")
    out = tmp_path / "o"
    args = ["run", "--worlds", "small_office", "--policies", "random", "--seeds", "1", "--duration", "2", "--quiet",
            "--out", str(out)]
    assert main([*args, "--detector", "yolo", "--weights", str(bad)]) == 2
    _one_line(capsys, "bad.pt")
    assert not out.exists()  # so the corrected command is not refused as "already holds results"


def test_a_resume_may_add_runs_but_never_drop_or_change_them(session, capsys):
    before = _tree(session)
    only_random = [a if a != "random,frontier" else "random" for a in RUN]
    assert main([*only_random, "--seeds", "2", "--metrics", "ori", "--out", str(session), "--resume"]) == 2
    _one_line(capsys, "policies", "'frontier' is in the session")
    assert _tree(session) == before


def test_two_commands_on_one_folder_do_not_both_run(session, capsys):
    with folder_lock(session):
        assert main([*RUN, "--seeds", "2", "--metrics", "ori", "--out", str(session), "--resume"]) == 2
    _one_line(capsys, "in use by another")


def test_record_resume_keeps_its_settings(tmp_path, capsys):
    out = tmp_path / "rec"
    out.mkdir()
    (out / "record.json").write_text(json.dumps({"world": "small_office", "policy": "frontier", "duration": 2.0,
                                                 "width": 64, "height": 48, "rate_hz": 5.0, "decide_every": 10}))
    base = ["record", "--world", "small_office", "--duration", "2", "--out", str(out), "--resume", "--quiet"]
    for extra, field in ((["--width", "80", "--height", "48"], "width"), (["--width", "64", "--height", "48",
                                                                            "--rate", "2"], "rate_hz"),
                         (["--width", "64", "--height", "48", "--policy", "random"], "policy")):
        assert main([*base, *extra]) == 2
        _one_line(capsys, "record.json", field)
    assert sorted(p.name for p in out.iterdir()) == ["record.json"]


def test_ctrl_c_always_stops_a_run_and_leaves_it_resumable(tmp_path):
    """Ctrl-C is never lost (it once landed in JAX's garbage-collection callback and the run
    went on to exit 0): the run stops at the next chunk with status 130, and the same
    command with --resume is accepted. While simulating, it stops within the chunks queued
    (at most two: the run once queued them all, and a stop waited for every one)."""
    from rosmeery_jax.core.files import claim_folder

    out = tmp_path / "o"
    # 4 decisions per call, as the module's 4 s sessions: their compiled program serves, and a chunk is short
    cmd = [str(Path(sys.executable).with_name("rosmeery")), *RUN, "--duration", "3000", "--chunk-s", "4", "--seeds",
           "2", "--out", str(out)]
    # (wait before the signal, bound on the stop): while starting or compiling (a compile
    # cannot be cut short, on a machine busy with other tests), then while simulating
    for attempt, (wait, bound) in enumerate(((3, 60), (12, 30))):
        proc = subprocess.Popen(cmd + (["--resume"] if attempt else []), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        time.sleep(wait)
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 130, err[-2000:]
        assert time.monotonic() - t0 < bound, "stopped at the next chunk"  # the run had 3000 s to go
        assert "interrupted" in err and not (out / "metrics.csv").exists()
        claim_folder(out, resume=True)  # the same command with --resume is accepted


def test_a_full_disk_is_one_line(tmp_path, capsys, monkeypatch):
    import errno

    from rosmeery_jax.results import tables

    def full(df, path):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(tables, "write_csv", full)
    ply = _map(tmp_path / "m")
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(tmp_path / "o")]) == 1
    _one_line(capsys, "metrics.csv", "No space left")
    assert not (tmp_path / "o").exists()


# --- names from files never become paths ---

def test_plot_never_writes_outside_its_folder(tmp_path, capsys):
    shared = tmp_path / "shared" / "results"
    shared.mkdir(parents=True)
    row = {"world": "../../escaped", "policy": "random", "detector": "off", "mapper": "oracle", "seed": 0,
           "time_s": 0.0, "metric": "ori", "value": 0.5}
    pd.DataFrame([row], columns=METRIC_COLUMNS).to_csv(shared / "metrics.csv", index=False)
    before = _tree(tmp_path)
    assert main(["plot", str(shared)]) == 2
    _one_line(capsys, "metrics.csv", "row 2, column world", "plain name")
    assert _tree(tmp_path) == before and not (tmp_path / "escaped_ori.png").exists()
    for column, value, needle in (("seed", 1.5, "1.5 is not a seed"), ("value", "inf", "inf is not a finite number"),
                                  ("policy", None, "is empty")):  # an empty name cell was an AttributeError
        pd.DataFrame([{**row, "world": "w", column: value}], columns=METRIC_COLUMNS).to_csv(shared / "metrics.csv",
                                                                                          index=False)
        assert main(["plot", str(shared)]) == 2  # a seed 1.5 was read as seed 1
        _one_line(capsys, "metrics.csv", f"row 2, column {column}", needle)
    pd.DataFrame([], columns=METRIC_COLUMNS).to_csv(shared / "metrics.csv", index=False)
    assert main(["plot", str(shared)]) == 2  # was "wrote 0 plots", exit 0
    _one_line(capsys, "metrics.csv: rows: none: nothing to plot")
    assert not (shared / "plots").exists()


# --- silently reinterpreted, now refused ---

@pytest.mark.parametrize("option, needle", [
    ({}, None),  # the baseline: valid
    ({"mappers": "perceived,perceived", "detector": "oracle"}, "appears twice"),
    ({"weights": "x.pt"}, "is for --detector yolo"),
    ({"worlds": "procedural:office:0-100000000"}, "at most 10,000"),
    ({"worlds": "procedural:office:3:rooms=2:rooms=3"}, "given twice"),
    # a detector period the run cannot be cut into ran with the largest that divides it (7 -> 6 s)
    ({"detector": "oracle", "duration": 300.0, "detector_period_s": 7.0}, "detector_period_s.*nearest, 6 s or 10 s"),
    ({"detector": "oracle", "duration": 45.0}, "detector_period_s: 10 s .*nearest, 9 s or 15 s"),
    ({"detector": "oracle", "detector_period_s": 0.5}, "detector_period_s: 0.5 s .*nearest, 1 s"),
    ({"detector": "oracle", "detector_period_s": 60.0}, None),  # longer than the run: the run is one period
    ({"detector": "off", "duration": 45.0, "detector_period_s": 7.0}, None),  # no detector: no period
])
def test_session_options_that_were_reinterpreted(tmp_path, option, needle):
    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.session import load_config

    args = {**dict(worlds="small_office", policies="random", seeds=1, duration=4.0, detector="off",
                   out=str(tmp_path / "o")), **option}
    if needle is None:
        assert load_config(None, **args).policies == ("random",)
        return
    t0 = time.monotonic()
    with pytest.raises(InputError, match=needle):
        load_config(None, **args)
    assert time.monotonic() - t0 < 10  # refused by its size, never expanded


def test_an_output_that_cannot_be_made_is_one_line(capsys):
    assert main([*RUN, "--seeds", "1", "--out", "/proc/rosmeery/o"]) == 2
    _one_line(capsys, "/proc/rosmeery/o", "cannot be created")


def test_sample_s_and_sizes_that_cannot_be_honoured(tmp_path):
    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.session import load_config

    base = dict(worlds="small_office", policies="random", seeds=1, duration=4.0, detector="off", out=str(tmp_path))
    with pytest.raises(InputError, match="sample_s.*whole number of control periods"):
        load_config(None, **base, sample_s=0.03)
    deep = tmp_path / "deep.toml"
    deep.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(InputError, match="deep.toml"):
        load_config(deep)
    wide = tmp_path / "wide.toml"
    wide.write_text('worlds = ["small_office"]\n[env]\ncamera__width = 100000\n')
    with pytest.raises(InputError, match="env.camera.width"):
        load_config(wide)


@pytest.mark.parametrize("meta, needle", [
    (False, "needs its JSON beside it"),
    ({"frame": {"world": "kitchen", "time_s": 1.0}}, "is not the world scored"),
    ({"frame": {"world": "small_office", "time_s": float("nan")}}, "frame.time_s"),
    ({"frame": {"world": "small_office", "time_s": -5}}, "frame.time_s"),
    ({"frame": {"world": "small_office"}, "objects": [{"id": 0}, {"id": 0}]}, "appears twice"),
    ({"frame": {"world": "small_office"}, "objects": [{"id": 0, "confidence": float("nan")}]}, "confidence"),
    ("deep", "nested too deeply"),
])
def test_evaluation_maps_that_were_reinterpreted(tmp_path, capsys, meta, needle):
    folder = tmp_path / "m"
    ply = _map(folder, meta=None if meta == "deep" else meta)
    if meta == "deep":
        (folder / "map.json").write_text("[" * 100_000 + "]" * 100_000)
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(tmp_path / "o")]) == 2
    _one_line(capsys, needle)
    assert not (tmp_path / "o").exists()


def test_two_maps_at_one_time_and_an_empty_map(tmp_path, capsys):
    a, b = _map(tmp_path / "m", "a"), _map(tmp_path / "m", "b")
    assert main(["evaluate", "--world", "small_office", "--map", str(a), str(b), "--out", str(tmp_path / "o")]) == 2
    _one_line(capsys, "two maps have this time")
    empty = _map(tmp_path / "e", meta={"frame": {"world": "small_office", "time_s": 5.0}})
    empty.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
                      b"property float z\nproperty int instance\nend_header\n")  # as a mapper that saw nothing writes
    assert main(["evaluate", "--world", "small_office", "--map", str(empty), "--metrics", "ori,cori,opi,field",
                 "--out", str(tmp_path / "o")]) == 0  # an empty map: scored 0, as an empty cloud in a bag
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["ori"] == summary["cori"] == summary["opi"] == 0.0
    assert not pd.read_csv(tmp_path / "o" / "metrics.csv").value.isna().any()
    empty.write_text("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\n"
                     "property int instance\nend_header\n")  # the same in ASCII
    assert main(["evaluate", "--world", "small_office", "--map", str(empty), "--metrics", "ori,field",
                 "--out", str(tmp_path / "o2")]) == 0
    assert json.loads((tmp_path / "o2" / "summary.json").read_text())["ori"] == 0.0


def test_a_map_json_naming_an_object_with_no_points_is_refused(tmp_path, capsys):
    """A JSON object whose id no point holds: the JSON and the PLY are of different maps."""
    ply = _map(tmp_path / "m", meta={"frame": {"world": "small_office", "time_s": 5.0},
                                      "objects": [{"id": 0, "label": "chair"}, {"id": 41, "label": "chair"}]})
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(tmp_path / "o")]) == 2
    _one_line(capsys, "map.json", "objects", "41 has no points")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("confidence", [True, False, "0.5"])
def test_a_map_json_confidence_must_be_a_number(tmp_path, capsys, confidence):
    ply = _map(tmp_path / "m", meta={"frame": {"world": "small_office", "time_s": 5.0},
                                      "objects": [{"id": 0, "label": "chair", "confidence": confidence}]})
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(tmp_path / "o")]) == 2
    _one_line(capsys, "map.json", "objects[0].confidence")


def test_replayed_poses_outside_the_world_or_before_zero(tmp_path, capsys):
    for rows, needle in (("0,50,50,0\n1,50.1,50,0\n", "outside the world"), ("-5,0,0,0\n1,0.1,0,0\n", "start at 0")):
        poses = tmp_path / "p.csv"
        poses.write_text("t,x,y,yaw\n" + rows)
        assert main(["replay", "--world", "small_office", "--poses", str(poses), "--out", str(tmp_path / "o")]) == 2
        _one_line(capsys, "p.csv", needle)
        assert not (tmp_path / "o").exists()


def test_an_absolute_replay_glob_is_read(tmp_path):
    from rosmeery_jax.policies.teleop_replay import replay_files

    for name in ("a.jsonl", "b.jsonl"):
        (tmp_path / name).write_text("{}\n")
    assert [p.name for p in replay_files(f"replay:{tmp_path}/*.jsonl")] == ["a.jsonl", "b.jsonl"]


def test_train_refuses_a_range_of_worlds_by_its_size():
    from rosmeery_jax.core.errors import InputError
    from rosmeery_jax.rl import ppo

    with pytest.raises(InputError, match="at most 10,000"):
        ppo.load_train_config(None, worlds=["procedural:office:0-100000000"])


@pytest.mark.parametrize("option", [["--batches", "1,100000000"], ["--memory-batch", "100000000"]])
def test_a_bench_batch_beyond_the_machines_memory_is_refused_before_it_starts(option, capsys):
    assert main(["bench", *option]) == 2  # it was allocated until the system killed it
    _one_line(capsys, "command line", f"{option[0]}: 100,000,000 robots need about", "GB allows")


@pytest.mark.parametrize("devices, available, split", [
    (0, 1, 1), (0, 2, 2), (0, 6, 4), (0, 12, 8), (0, 64, 64), (0, 96, 64),  # 6 cores: the split was skipped
    (2, 6, 2), (8, 2, 2),  # as asked, at most those there are
])
def test_the_bench_splits_its_reference_batch_over_the_most_devices_that_divide_it(devices, available, split):
    from rosmeery_jax.apps.bench import BenchConfig, split_devices

    assert split_devices(BenchConfig(devices=devices), available) == split


@pytest.mark.parametrize("option, needle", [
    (["--steps", "0"], "--steps: 0 must be >= 1"), (["--memory-batch", "-1"], "--memory-batch: -1 must be >= 0"),
    (["--steps", "99999999999"], "--steps: 99999999999 must be at most 2147483647"),  # a traceback from JAX
    (["--session-s", "nan"], "--session-s: nan must be a number of seconds"),  # these ran the bench
    (["--devices", "1000"], "--devices: 1000 must divide the reference batch (64"),  # the split was skipped
    (["--session-s", "1e8"], "--session-s: duration: 5 seeds x 4 worlds"),  # refused after minutes of benching
])
def test_bench_options_out_of_range_are_refused_before_it_starts(option, needle, capsys, monkeypatch):
    monkeypatch.setattr(cli, "host_devices", lambda n: pytest.fail("devices set up"))
    assert main(["bench", *option]) == 2
    _one_line(capsys, "command line", needle)
