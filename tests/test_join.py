"""`rosmeery join`: parts of a sweep split by seeds joined into one folder. Bitwise the files
of one session over all the seeds: tests/test_engine.py. Here, on hand-written folders: the
order of the rows, what the joined config says, and the parts that are refused."""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path

import fuzz_inputs as fz
import pytest
from conftest import one_line_error
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import rosmeery_jax as rj
from rosmeery_jax.apps.cli import main
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.session import SessionConfig, join
from rosmeery_jax.session.outputs import seal_run

RUN = "small_office__random"
HEADER = "world,policy,detector,seed,time_s,metric,value,mapper"
SEED_RECORD = json.dumps({"session": {"worlds": ["small_office"], "policies": ["random"], "seeds": 2, "first_seed": 3,
                                      "duration": 4.0, "detector": "off"},
                          "inputs": {"worlds": {"small_office": "abc"}}, "versions": {"git": None}})


def _part(folder: Path, first: int, seeds: int, **change) -> Path:
    """A finished session of small_office x random over seeds first..first+seeds-1: every
    file holds one row (or map) per seed, its value the seed."""
    cfg = replace(SessionConfig(worlds=("small_office",), policies=("random",), duration=1.0, seeds=seeds,
                                first_seed=first, out=str(folder)), **change)
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(json.dumps({"session": json.loads(json.dumps(asdict(cfg))),
                                                    "inputs": {"worlds": {"small_office": "abc"}},
                                                    "versions": {"git": f"part{first}"}}))
    (folder / "runs").mkdir()
    (folder / "maps").mkdir()
    rows = [f"small_office,random,oracle,{s},{t},ori,{s / 100 + t / 10},oracle" for s in range(first, first + seeds)
            for t in (0, 1)]
    (folder / "runs" / f"{RUN}.metrics.csv").write_text("\n".join([HEADER, *rows]) + "\n")
    nav = [f"small_office,random,{s},{s}.5" for s in range(first, first + seeds)]
    (folder / "runs" / f"{RUN}.navigation.csv").write_text("\n".join(["world,policy,seed,moving_s", *nav]) + "\n")
    timing = {"env_steps": 10 * seeds, "wall_s": 2.0, "sim_s": 1.0, "env_steps_per_s": 5.0 * seeds}
    (folder / "runs" / f"{RUN}.timing.json").write_text(json.dumps(timing))
    for s in range(first, first + seeds):
        (folder / "maps" / f"{RUN}__seed{s}.ply").write_text(f"map of seed {s}")
    seal_run(folder, RUN)
    return folder


def test_parts_join_in_seed_order_into_one_sessions_folder(tmp_path, capsys):
    a, b, c = _part(tmp_path / "a", 3, 2), _part(tmp_path / "b", 0, 1), _part(tmp_path / "c", 1, 2)
    before = {p: p.read_bytes() for d in (a, b, c) for p in d.rglob("*") if p.is_file()}
    out = tmp_path / "deep" / "joined"
    assert main(["join", str(a), str(b), str(c), "--out", str(out)]) == 0
    assert "seeds 0-4" in capsys.readouterr().out
    lines = (out / "runs" / f"{RUN}.metrics.csv").read_text().splitlines()
    assert lines[0] == HEADER and [int(x.split(",")[3]) for x in lines[1:]] == [0, 0, 1, 1, 2, 2, 3, 3, 4, 4]
    nav = (out / "runs" / f"{RUN}.navigation.csv").read_text().splitlines()
    assert nav[1:] == [f"small_office,random,{s},{s}.5" for s in range(5)]
    assert sorted(p.name for p in (out / "maps").iterdir()) == [f"{RUN}__seed{s}.ply" for s in range(5)]
    assert (out / "maps" / f"{RUN}__seed3.ply").read_text() == "map of seed 3"
    record = json.loads((out / "config.json").read_text())
    assert (record["session"]["first_seed"], record["session"]["seeds"], record["session"]["out"]) == (0, 5, str(out))
    assert [(p["first_seed"], p["seeds"], p["versions"]["git"]) for p in record["joined"]] == [
        (0, 1, "part0"), (1, 2, "part1"), (3, 2, "part3")]
    timing = json.loads((out / "runs" / f"{RUN}.timing.json").read_text())
    assert (timing["env_steps"], timing["wall_s"], timing["env_steps_per_s"]) == (50, 6.0, 50 / 6.0)
    merged = (out / "metrics.csv").read_text().splitlines()  # the merged table, as a session draws it
    assert len(merged) == 11 and list((out / "plots").glob("*.png"))
    assert {p: p.read_bytes() for d in (a, b, c) for p in d.rglob("*") if p.is_file()} == before
    assert not [p for p in tmp_path.rglob(".joined.*")]  # the scratch folder is gone
    assert oct((out / "runs").stat().st_mode & 0o777) == oct(out.parent.stat().st_mode & 0o777)
    again = tmp_path / "again"  # a joined folder joins like any part (here from Python); its parts are listed
    assert rj.join_results([out, _part(tmp_path / "d", 5, 1)], again) == again
    assert [p["first_seed"] for p in json.loads((again / "config.json").read_text())["joined"]] == [0, 1, 3, 5]
    with pytest.raises(TypeError, match="a list of results folders"):
        rj.join_results(str(out), tmp_path / "never")
    assert len((again / "runs" / f"{RUN}.metrics.csv").read_text().splitlines()) == 1 + 2 * 6


@pytest.mark.parametrize("second, needles", [
    (dict(first=1), ("b/config.json: first_seed", "seeds 1-2 overlap", "a's 0-1")),
    (dict(first=3), ("b/config.json: first_seed", "seeds 3-4 leave seeds 2 out")),
    (dict(first=2, duration=2.0), ("b/config.json: duration", "was 1.0, now 2.0")),
    (dict(first=2, detector="off"), ("b/config.json: detector", "now 'off'")),
    (dict(first=2, policies=("replay:rec.csv",)), ("b/config.json: policies", "a replay's runs are its recordings")),
    (dict(first=2, inputs="other"), ("b/config.json: inputs", "input files differ")),
    (dict(first=2, unfinished=True), ("b/runs: runs", "0 of the session's 1 runs finished")),
    (dict(first=2, missing=True), ("b/config.json: file", "not a results folder")),
])
def test_parts_that_are_not_one_sweep_are_one_line_and_nothing_is_written(tmp_path, capsys, second, needles):
    a = _part(tmp_path / "a", 0, 2)
    change = {k: v for k, v in second.items() if k not in ("first", "inputs", "unfinished", "missing")}
    b = _part(tmp_path / "b", second["first"], 2, **change)
    if "inputs" in second:
        record = json.loads((b / "config.json").read_text())
        (b / "config.json").write_text(json.dumps({**record, "inputs": {"worlds": {"small_office": "other"}}}))
    if second.get("unfinished"):
        (b / "runs" / f"{RUN}.manifest.json").unlink()  # the record marks a run finished
    if second.get("missing"):
        (b / "config.json").unlink()
    assert main(["join", str(a), str(b), "--out", str(tmp_path / "out")]) == 2
    one_line_error(capsys, *needles)
    assert not (tmp_path / "out").exists()


def test_one_folder_or_a_used_out_is_refused(tmp_path, capsys):
    a, b = _part(tmp_path / "a", 0, 2), _part(tmp_path / "b", 2, 1)
    assert main(["join", str(a), "--out", str(tmp_path / "out")]) == 2
    one_line_error(capsys, "two results folders or more")
    used = tmp_path / "used"
    used.mkdir()
    (used / "notes.txt").write_text("mine")
    assert main(["join", str(a), str(b), "--out", str(used)]) == 2
    one_line_error(capsys, "used: --out", "not empty")
    assert [p.name for p in used.iterdir()] == ["notes.txt"]
    assert main(["join", str(a), str(b), "--out", str(a)]) == 2  # a part itself: it holds results
    one_line_error(capsys, "a: --out", "not empty")


@settings(max_examples=80, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.one_of(fz.edits().map(lambda e: fz.mutate(SEED_RECORD, e)), fz.number_swaps(SEED_RECORD)))
def test_a_mutated_part_record_is_read_or_one_line_naming_the_part(tmp_path_factory, text):
    """What `join` reads of a part before anything is written: its config.json, its runs."""
    folder = tmp_path_factory.mktemp("part")
    (folder / "runs").mkdir()
    (folder / "runs" / f"{RUN}.metrics.csv").write_text(HEADER + "\n")
    (folder / "config.json").write_bytes(text.encode("utf-8", "surrogatepass"))
    try:
        part = join._read(folder)
    except InputError as err:
        assert "\n" not in str(err) and str(err).startswith(str(folder)), str(err)
    else:
        assert len(part.seeds) >= 1 and part.seeds.start >= 0
