"""Sensor streams out: the TUM RGB-D recording, its conventions, and a round trip through an
external mapper script back into the evaluator."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from rosmeery_jax.apps.cli import main

ROOT = Path(__file__).resolve().parents[1]
ARGS = ["record", "--world", "small_office", "--policy", "frontier", "--duration", "10", "--width", "160",
        "--height", "120", "--rate", "5", "--quiet"]


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec") / "out"
    assert main([*ARGS, "--seed", "1", "--out", str(out)]) == 0
    return out


def _lines(path):
    return [line.split() for line in path.read_text().splitlines() if not line.startswith("#")]


def test_the_sequence_has_the_tum_layout(rec):
    seq = rec / "seed1"
    assert sorted(p.name for p in rec.iterdir()) == ["record.json", "seed1", "session"]
    session = json.loads((rec / "session" / "config.json").read_text())["session"]
    assert (session["first_seed"], session["seeds"]) == (1, 1)  # seed 1 alone was simulated, not seeds 0-1
    rgb, depth = _lines(seq / "rgb.txt"), _lines(seq / "depth.txt")
    assert [r[0] for r in rgb] == [f"{0.2 * k:.6f}" for k in range(51)]  # 5 Hz over 10 s, both ends
    assert [d[0] for d in depth] == [r[0] for r in rgb] and depth[3][1] == "depth/0.600000.png"
    img = cv2.imread(str(seq / rgb[5][1]), cv2.IMREAD_UNCHANGED)
    d = cv2.imread(str(seq / depth[5][1]), cv2.IMREAD_UNCHANGED)
    assert img.shape == (120, 160, 3) and img.dtype == np.uint8
    assert d.shape == (120, 160) and d.dtype == np.uint16 and 0 < d.max() <= 8 * 5000
    cam = json.loads((seq / "camera.json").read_text())
    assert (cam["cx"], cam["cy"], cam["depth_scale"]) == (79.5, 59.5, 5000.0)
    assert cam["fx"] == pytest.approx(80 / np.tan(np.deg2rad(30)))
    gt, scan, odom = (_lines(seq / f) for f in ("groundtruth.txt", "scan.txt", "odometry.txt"))
    assert len(gt) == len(scan) == len(odom) == 101  # every 0.1 s
    assert all(len(r) == 8 for r in gt) and all(len(r) == 91 for r in scan) and all(len(r) == 6 for r in odom)
    q = np.array([r[4:] for r in gt], float)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-5)
    assert {float(r[3]) for r in gt} == {0.5}  # the camera's mounting height


def test_poses_match_the_session_that_drove_the_robot(rec):
    traj = pd.read_csv(rec / "session" / "trajectories.csv")
    traj = traj[traj.seed == 1].sort_values("time_s")
    odom = np.array(_lines(rec / "seed1" / "odometry.txt"), float)
    np.testing.assert_allclose(odom[:, 1:4], traj[["x", "y", "yaw"]].to_numpy(), atol=1e-6)
    gt = np.array(_lines(rec / "seed1" / "groundtruth.txt"), float)
    np.testing.assert_allclose(gt[:, 1], odom[:, 1] + 0.1 * np.cos(odom[:, 3]), atol=1e-5)  # 10 cm ahead of the base


def test_round_trip_through_an_external_script_lands_on_the_objects(rec, tmp_path):
    """Back-project the recorded depth with the recorded poses (a script outside the
    package), evaluate: every point lies on an object, and ORI is close to the session's
    own (different resolution and rate, so close, not equal)."""
    ply = tmp_path / "map.ply"
    subprocess.run([sys.executable, str(ROOT / "examples" / "tum_to_map.py"), str(rec / "seed1"), "--out", str(ply)],
                   check=True, capture_output=True)
    assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(tmp_path / "ev")]) == 0
    summary = json.loads((tmp_path / "ev" / "summary.json").read_text())
    assert summary["points_on_no_object"] < 0.005 and summary["unmatched_instances"] == 0
    m = pd.read_csv(rec / "session" / "metrics.csv")
    own = m[(m.seed == 1) & (m.metric == "ori") & (m.time_s == 10.0)].value.item()
    assert summary["ori"] > 0.1 and abs(summary["ori"] - own) < 0.1


def test_resume_re_records_a_missing_seed_identically(rec, tmp_path):
    before = (rec / "seed1" / "depth" / "2.000000.png").read_bytes()
    copy = tmp_path / "copy"
    subprocess.run(["cp", "-r", str(rec), str(copy)], check=True)
    subprocess.run(["rm", "-r", str(copy / "seed1")], check=True)
    assert main([*ARGS, "--seed", "1", "--out", str(copy), "--resume"]) == 0
    assert (copy / "seed1" / "depth" / "2.000000.png").read_bytes() == before
    assert (copy / "seed1" / "groundtruth.txt").read_text() == (rec / "seed1" / "groundtruth.txt").read_text()


@pytest.mark.parametrize("extra, field", [(["--rate", "3"], "--rate"), (["--width", "8"], "--width"),
                                          (["--seed", "-1"], "--seeds"), (["--duration", "0.05"], "duration"),
                                          (["--seeds", "0"], "--seeds: 0: name at least one"),  # recorded seed 0
                                          (["--depth-encoding", "16UC1"], "--depth-encoding"),  # TUM: ignored
                                          (["--seeds", "1000000000"], "seeds: 1000000000 seeds x")])  # listed the
# seeds until killed for memory
def test_bad_options_are_one_line_and_write_nothing(tmp_path, capsys, extra, field):
    out = tmp_path / "o"
    assert main([*ARGS, *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and field in err[0] and not out.exists()


def test_a_non_empty_folder_is_refused_without_resume(rec, capsys):
    assert main([*ARGS, "--seed", "1", "--out", str(rec)]) == 2
    assert "--resume" in capsys.readouterr().err


def test_a_replay_is_recorded_with_the_settings_its_header_names(tmp_path):
    """The replay file's ``env`` (here 45 laser beams and a lower camera) drives the streams
    as it drives the session: the laser and the camera poses written are the replay's."""
    from rosmeery_jax.policies.teleop_file import world_hash
    from rosmeery_jax.world import load_world

    w = load_world("small_office")
    header = {"format": "rosmeery-teleop", "version": 1, "world": "small_office", "world_sha256": world_hash(w),
              "seed": 0, "dt": 0.1, "start_pose": [float(v) for v in w.spawn],
              "env": {"laser__beams": 45, "camera__mount_height": 0.4}, "detector": "off"}
    steps = "".join(json.dumps({"k": k, "t": k / 10, "cmd": [0.3, 0.1], "pose": [0, 0, 0]}) + "\n"
                    for k in range(1, 11))
    replay = tmp_path / "drive.jsonl"
    replay.write_text(json.dumps(header) + "\n" + steps)
    out = tmp_path / "rec"
    assert main(["record", "--world", "small_office", "--policy", f"replay:{replay}", "--duration", "1",
                 "--width", "32", "--height", "24", "--rate", "5", "--quiet", "--out", str(out)]) == 0
    scan = _lines(out / "seed0" / "scan.txt")
    assert {len(row) - 1 for row in scan} == {45}
    assert {float(row[3]) for row in _lines(out / "seed0" / "groundtruth.txt")} == {0.4}
