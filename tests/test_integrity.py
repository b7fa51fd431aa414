"""Results folders that know their own integrity: each run's files and the merged tables are
recorded (rows, sha256) when complete, and resume, join, plot and diff check the record
first, naming the damaged file and its rows."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest
from conftest import one_line_error

from rosmeery_jax.apps.cli import main
from rosmeery_jax.results import manifest

RUN = "small_office__random"
ARGS = ["run", "--worlds", "small_office", "--policies", "random", "--seeds", "2", "--duration", "3",
        "--detector", "off", "--quiet"]


@pytest.fixture(scope="module")
def parts(tmp_path_factory) -> tuple[Path, Path]:
    """Two finished sessions: seeds 0-1 and 2-3."""
    root = tmp_path_factory.mktemp("integrity")
    assert main([*ARGS, "--out", str(root / "a")]) == 0
    assert main([*ARGS, "--first-seed", "2", "--out", str(root / "b")]) == 0
    return root / "a", root / "b"


def _copy(folder: Path, tmp_path: Path, name: str) -> Path:
    return Path(shutil.copytree(folder, tmp_path / name))


def _drop_line(path: Path, line: int) -> None:
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:line - 1] + lines[line:]))


def test_the_record_lists_rows_and_digests_of_each_file(tmp_path):
    csv = tmp_path / "t.csv"
    csv.write_text("a,b\n1,2\n3,4\n")
    entry = manifest.describe(csv)
    assert entry["rows"] == 2 and entry["bytes"] == 12
    assert entry["sha256"] == hashlib.sha256(b"a,b\n1,2\n3,4\n").hexdigest()
    assert entry["blocks"] == [hashlib.sha256(b"1,2\n3,4").hexdigest()[:16]]
    manifest.write(tmp_path / "m.json", tmp_path, [csv])
    assert manifest.damage(tmp_path / "m.json", tmp_path) is None
    csv.write_text("a,b\n1,2\n3,5\n")
    err = manifest.damage(tmp_path / "m.json", tmp_path)
    assert str(err) == f"{csv}: lines 2-3: differ from what was written"
    csv.unlink()
    assert "not found, where the results folder recorded it" in str(manifest.damage(tmp_path / "m.json", tmp_path))


def test_every_file_of_a_session_is_recorded(parts):
    a, _ = parts
    recorded = json.loads((a / "runs" / f"{RUN}.manifest.json").read_text())["files"]
    assert f"runs/{RUN}.metrics.csv" in recorded and f"maps/{RUN}__seed1.ply" in recorded
    assert json.loads((a / "manifest.json").read_text())["files"].keys() == {
        "metrics.csv", "objects.csv", "trajectories.csv", "navigation.csv"}
    assert json.loads((a / "config.json").read_text())["integrity"] == 1


def test_a_damaged_run_is_simulated_again_on_resume(parts, tmp_path, capsys):
    """A row deleted from a run's file and from the merged table: the run was taken as done
    and metrics.csv rebuilt one row short; now the run is simulated again, saying why."""
    a, _ = parts
    b = _copy(a, tmp_path, "b")
    _drop_line(b / "runs" / f"{RUN}.metrics.csv", 5)
    _drop_line(b / "metrics.csv", 5)
    capsys.readouterr()
    assert main([*ARGS, "--out", str(b), "--resume"]) == 0
    err = capsys.readouterr().err
    assert f"{b}/runs/{RUN}.metrics.csv: rows: 39 where 40 were written: simulating {RUN} again" in err
    for name in ("metrics.csv", "objects.csv", "trajectories.csv", "navigation.csv"):
        assert (b / name).read_bytes() == (a / name).read_bytes(), name


@pytest.mark.parametrize("damage", ["nan", "truncated", "text"])
def test_join_refuses_a_damaged_part_naming_its_file(parts, tmp_path, capsys, damage):
    a, b = parts
    part = _copy(b, tmp_path, "part")
    path = part / "runs" / f"{RUN}.metrics.csv"
    text = path.read_text()
    if damage == "truncated":
        path.write_text(text[: len(text) // 2])
    else:
        lines = text.splitlines(keepends=True)
        cells = lines[3].rstrip("\n").split(",")
        cells[6] = "nan" if damage == "nan" else "abc"  # the value column
        lines[3] = ",".join(cells) + "\n"
        path.write_text("".join(lines))
    assert main(["join", str(a), str(part), "--out", str(tmp_path / "joined")]) == 2
    one_line_error(capsys, f"{path}: ", "resume")
    assert not (tmp_path / "joined").exists()


def test_plot_and_diff_name_the_damaged_file(parts, tmp_path, capsys):
    a, _ = parts
    c = _copy(a, tmp_path, "c")
    (c / "trajectories.csv").write_text((c / "trajectories.csv").read_text().replace(",0.", ",9.", 1))
    assert main(["plot", str(c)]) == 2
    one_line_error(capsys, f"{c}/trajectories.csv: lines 2-", "differ from what was written")
    shutil.copy(a / "trajectories.csv", c / "trajectories.csv")
    (c / "runs" / f"{RUN}.trajectory.csv").unlink()
    assert main(["diff", str(a), str(c)]) == 2
    one_line_error(capsys, f"{c}/runs/{RUN}.trajectory.csv: file: not found")


def test_a_folder_of_a_version_without_records_is_read_as_before(parts, tmp_path, capsys):
    a, _ = parts
    old = _copy(a, tmp_path, "old")
    for p in [old / "manifest.json", *(old / "runs").glob("*.manifest.json")]:
        p.unlink()
    record = json.loads((old / "config.json").read_text())
    del record["integrity"]
    (old / "config.json").write_text(json.dumps(record))
    assert main(["plot", str(old)]) == 0
    (old / "manifest.json").write_text("{}")  # a record that is there is read
    assert main(["plot", str(old)]) == 2
    one_line_error(capsys, f"{old}/manifest.json: file: unreadable")


def test_an_emptied_record_is_damage_not_a_switch(parts, tmp_path, capsys):
    """A run's record replaced by {"files": {}} beside a changed trajectory row: join refuses
    the part naming the record, and --resume simulates the run again (a record that names
    fewer files than the run wrote is damage); an emptied merged record stops plot."""
    a, b = parts
    part = _copy(b, tmp_path, "part")
    record = part / "runs" / f"{RUN}.manifest.json"
    record.write_text('{"files": {}}')
    traj = part / "runs" / f"{RUN}.trajectory.csv"
    traj.write_text(traj.read_text().replace(",0.", ",9.", 1))
    assert main(["join", str(a), str(part), "--out", str(tmp_path / "joined")]) == 2
    one_line_error(capsys, f"{record}: files: does not list", "resume")
    assert not (tmp_path / "joined").exists()
    assert main([*ARGS, "--first-seed", "2", "--out", str(part), "--resume"]) == 0
    assert f"{record}: files: does not list" in capsys.readouterr().err
    assert traj.read_bytes() == (b / "runs" / f"{RUN}.trajectory.csv").read_bytes()
    (part / "manifest.json").write_text('{"files": {}}')
    assert main(["plot", str(part)]) == 2
    one_line_error(capsys, f"{part}/manifest.json: files: does not list metrics.csv")
