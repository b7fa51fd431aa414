"""Rerun recordings of sessions and recordings, read back with Rerun's own reader: the
entities logged, their time ranges on the simulated-time timeline, the runs chosen."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

from rosmeery_jax.apps.cli import main  # noqa: E402

ARGS = ["--worlds", "small_office", "--policies", "frontier", "--seeds", "2", "--detector", "off", "--duration", "4",
        "--quiet"]


def _entities(rrd) -> dict:
    """{entity path: (rows, sim_time values)} of a .rrd file."""
    out: dict = {}
    for chunk in RrdReader(rrd).store().stream().to_chunks():
        batch = chunk.to_record_batch()
        times = batch.column("sim_time").to_numpy() if "sim_time" in batch.schema.names else np.zeros(0)
        rows, old = out.get(str(chunk.entity_path), (0, np.zeros(0)))
        out[str(chunk.entity_path)] = (rows + chunk.num_rows, np.r_[old, times.astype("timedelta64[ns]").astype(
            np.int64) / 1e9 if times.dtype.kind == "m" else times])
    return out


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("view")
    assert main(["run", *ARGS, "--out", str(root / "out"), "--rerun", str(root / "session.rrd")]) == 0
    return root


def test_a_session_is_logged_whole_on_simulated_time(session):
    e = _entities(session / "session.rrd")
    w = "/world/small_office"
    assert {f"{w}/objects", f"{w}/samples", f"{w}/frontier/seed0/path", f"{w}/frontier/seed1/robot",
            f"{w}/frontier/seed0/map/oracle"} <= set(e)
    assert e[f"{w}/objects"][0] == 1  # static: one row of 11 boxes
    rows, times = e[f"{w}/frontier/seed1/robot"]
    assert rows == 5 and times.min() == 0.0 and times.max() == pytest.approx(4.0)  # a pose per sampled second
    curves = [p for p in e if p.startswith("/metrics/") and "/small_office/frontier/oracle/" in p]
    assert len(curves) == 2 * 5  # five metrics, two seeds
    rows, times = e["/metrics/ori/small_office/frontier/oracle/seed0"]
    assert rows == 5 and list(times) == pytest.approx([0, 1, 2, 3, 4])
    assert e[f"{w}/frontier/seed0/map/oracle"][1] == pytest.approx([4.0])  # the exported map at the run's end


def test_view_chooses_runs_and_bounds_the_maps(session, tmp_path):
    rrd = tmp_path / "one.rrd"
    assert main(["view", str(session / "out"), "--seeds", "1", "--max-points", "100", "--out", str(rrd)]) == 0
    e = _entities(rrd)
    assert not any("seed0" in p for p in e) and any("seed1" in p for p in e)
    batch = next(c for c in RrdReader(rrd).store().stream().to_chunks()
                 if str(c.entity_path).endswith("seed1/map/oracle")).to_record_batch()
    positions = batch.column("Points3D:positions")
    assert len(positions[0]) <= 100


def test_a_recording_logs_its_camera_frames(tmp_path):
    rrd = tmp_path / "rec.rrd"
    assert main(["record", "--world", "small_office", "--duration", "2", "--width", "64", "--height", "48",
                 "--out", str(tmp_path / "rec"), "--rerun", str(rrd), "--quiet"]) == 0
    e = _entities(rrd)
    base = "/world/small_office/frontier/seed0/camera"
    assert e[f"{base}/rgb"][0] == 11 and e[f"{base}/depth"][0] == 11  # 5 Hz over 2 s, both ends
    assert e[f"{base}/rgb"][1].max() == pytest.approx(2.0)


def test_without_rerun_sdk_the_hint_is_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun now raises ImportError
    assert main(["view", str(tmp_path), "--out", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install" in err[0] and "rerun" in err[0]


def test_the_recording_opens_on_the_world_and_one_panel_per_metric(session):
    """The default blueprint: a 3D view of the world and a time-series panel per metric, each
    over the whole run (infinite visible range), every world, policy, mapper and seed in it."""
    from rosmeery_jax.apps.rerun_view import blueprint

    bp = blueprint(["cori", "ori"])
    world, metrics = bp.root_container.contents
    views = [world, *metrics.contents]
    names = [str(v.name) for v in views]
    assert names[0] == "worlds, maps and paths" and sorted(names[1:]) == ["cori", "ori"]
    assert [str(v.origin) for v in views[1:]] == ["metrics/cori", "metrics/ori"]
    reader = RrdReader(session / "session.rrd")
    (stored,) = reader.blueprints()  # the recording carries its layout: the 3D view and five metrics'
    paths = {str(c.entity_path) for c in reader.store(store=stored).stream().to_chunks()}
    assert sum(p.startswith("/view/") and p.endswith("/VisibleTimeRanges") for p in paths) == 1 + 5


@pytest.mark.parametrize("case", ["exists", "folder", "no folder", "unwritable"])
def test_a_rerun_output_is_checked_before_any_work_and_never_replaced(session, tmp_path, capsys, case):
    rrd = {"exists": tmp_path / "mine.rrd", "folder": tmp_path / "dir.rrd", "no folder": tmp_path / "no" / "x.rrd",
           "unwritable": Path("/proc/x.rrd")}[case]
    if case == "exists":
        rrd.write_bytes(b"the user's own recording")
    if case == "folder":
        rrd.mkdir()
    for args in (["run", *ARGS, "--out", str(tmp_path / "out"), "--rerun", str(rrd)],
                 ["view", str(session / "out"), "--out", str(rrd)],
                 ["record", "--world", "small_office", "--duration", "2", "--out", str(tmp_path / "rec"),
                  "--rerun", str(rrd), "--quiet"]):
        assert main(args) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(rrd) in err[0], err
        assert not (tmp_path / "out").exists() and not (tmp_path / "rec").exists()
    if case == "exists":
        assert rrd.read_bytes() == b"the user's own recording"


def test_a_bag_recording_logs_its_camera_frames(tmp_path):
    pytest.importorskip("rosbags")
    rrd = tmp_path / "rec.rrd"
    assert main(["record", "--world", "small_office", "--duration", "2", "--width", "64", "--height", "48",
                 "--format", "mcap", "--out", str(tmp_path / "rec"), "--rerun", str(rrd), "--quiet"]) == 0
    e = _entities(rrd)
    base = "/world/small_office/frontier/seed0/camera"
    assert e[f"{base}/rgb"][0] == 11 and e[f"{base}/depth"][0] == 11
    assert e[base][1].max() == pytest.approx(2.0)
