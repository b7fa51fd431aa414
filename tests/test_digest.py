"""Where two runs part: per-chunk digests of the state catch a one-ulp change in one env,
and `rosmeery diff` names the run, seed, chunk and part."""

from __future__ import annotations

import json

import re

import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from rosmeery_jax.apps.cli import main
from rosmeery_jax.session import digest, engine

from conftest import room_xml

BODIES = """
<body name="desk_1" pos="1.0 0.6 0"><geom type="box" pos="0 0 0.4" size="0.5 0.3 0.4"/></body>
<body name="chair_1" pos="-1.0 -1.0 0"><geom type="box" pos="0 0 0.25" size="0.22 0.22 0.25"/></body>
<body name="fridge_1" pos="-1.5 1.4 0"><geom type="box" pos="0 0 0.8" size="0.3 0.3 0.8"/></body>
"""


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> list[str]:
    """A 20 s session of three random walkers in a furnished room, with digests."""
    world = tmp_path_factory.mktemp("world") / "room.xml"
    world.write_text(room_xml(BODIES, {"desk_1": "desk", "chair_1": "chair", "fridge_1": "refrigerator"},
                              spawn=(0.3, -0.4, 0.0), half=2.2))
    return ["run", "--worlds", str(world), "--policies", "random", "--seeds", "3", "--duration", "20",
            "--detector", "oracle", "--detector-period-s", "5", "--digest", "--quiet"]


@pytest.fixture(scope="module")
def reference(run, tmp_path_factory):
    out = tmp_path_factory.mktemp("digest") / "a"
    assert main([*run, "--out", str(out)]) == 0
    return out


def test_the_digest_catches_a_one_ulp_change_in_one_env(run, reference, tmp_path, monkeypatch, capsys):
    table = pd.read_csv(reference / "runs" / "room__random.digest.csv", dtype=str)
    assert list(table.columns) == ["seed", "chunk", "time_s", *digest.PARTS] and len(table) == 3 * 4
    assert table.time_s.tolist()[:4] == ["5.0", "10.0", "15.0", "20.0"]
    start = engine._start

    def one_ulp_in_seed_1(*args):
        s = start(*args)
        qpos = np.array(s.state.physics.qpos)
        k = int(np.argmax(np.abs(qpos[1])))  # its heading: positions start at 0 (offsets from the spawn)
        qpos[1, k] = np.nextafter(qpos[1, k], np.float32(np.inf))  # one ulp in seed 1
        physics = s.state.physics.replace(qpos=jnp.asarray(qpos))
        return s._replace(state=s.state._replace(physics=physics))

    monkeypatch.setattr(engine, "_start", one_ulp_in_seed_1)
    out = tmp_path / "b"
    assert main([*run, "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["diff", str(reference), str(out)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0] == "room__random seed 0: identical over 4 chunks"
    assert lines[1].startswith("room__random seed 1: different from the first chunk; at chunk 0 (5.0 s) "
                               "physics")
    assert lines[2] == "room__random seed 2: identical over 4 chunks"


def test_without_digests_the_paths_are_compared(reference, tmp_path, capsys):
    other = tmp_path / "c"
    (other / "runs").mkdir(parents=True)
    for suffix in (".metrics.csv", ".trajectory.csv"):
        df = pd.read_csv(reference / "runs" / f"room__random{suffix}")
        if suffix == ".trajectory.csv":
            df.loc[(df.seed == 2) & (df.time_s >= 7.0), "x"] += 0.25
        df.to_csv(other / "runs" / f"room__random{suffix}", index=False)
    lines = digest.compare(reference, other)
    assert lines[0].startswith("room__random seed 0: the same path")
    assert lines[2].startswith("room__random seed 2: the paths part at 7 s by 0.25")
    (other / "runs" / "kitchen__random.metrics.csv").write_text("")  # a run of the second folder alone
    assert digest.compare(reference, other)[0] == f"kitchen__random: only in {other}"
    assert main(["diff", str(reference), str(tmp_path / "typo")]) == 2  # was: every run "only in" the first
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "typo: runs: no finished runs" in err


def _folder(root, digest_text=None, path_text=None):
    """A results folder of one run, by hand: what `rosmeery diff` reads."""
    runs = root / "runs"
    runs.mkdir(parents=True)
    (runs / "w__random.metrics.csv").write_text("")
    if digest_text is not None:
        (runs / "w__random.digest.csv").write_text(digest_text)
    if path_text is not None:
        (runs / "w__random.trajectory.csv").write_text(path_text)
    return root


def test_a_run_without_a_detector_is_identical_to_itself(tmp_path):
    """Its digests' detections are empty: read as NaN they differed from themselves, and a
    folder was 'different from the first chunk' from itself."""
    text = "seed,chunk,time_s,physics,map,knowledge,detections\n0,0,2.0,2aa2,0192,a8ea,\n0,1,4.0,2bb2,0193,a8eb,\n"
    a, b = _folder(tmp_path / "a", text), _folder(tmp_path / "b", text)
    assert digest.compare(a, b) == ["w__random seed 0: identical over 2 chunks"]
    c = _folder(tmp_path / "c", text.replace("a8eb,", "a8eb,ffff"))
    assert digest.compare(a, c) == ["w__random seed 0: identical up to chunk 0 (2.0 s); at chunk 1 (4.0 s) "
                                    "detections differ"]


def test_a_seed_only_one_folder_holds_is_named_so(tmp_path):
    """Another seed count or first seed: each seed of one side alone is 'only in' it (it was
    'identical over 0 chunks', and the other side's were not named)."""
    row = "{s},0,2.0,2aa2,0192,a8ea,\n"
    head, path_head = "seed,chunk,time_s,physics,map,knowledge,detections\n", "seed,time_s,x,y,yaw\n"
    a = _folder(tmp_path / "a", head + "".join(row.format(s=s) for s in (0, 1, 10)))
    b = _folder(tmp_path / "b", head + "".join(row.format(s=s) for s in (1, 2)))
    assert digest.compare(a, b) == [f"w__random seed 0: only in {a}", f"w__random seed 2: only in {b}",
                                    f"w__random seed 10: only in {a}", "w__random seed 1: identical over 1 chunks"]
    c = _folder(tmp_path / "c", None, path_head + "0,1.0,0,0,0\n1,1.0,0,0,0\n")
    d = _folder(tmp_path / "d", None, path_head + "1,1.0,0,0,0\n")
    assert digest.compare(c, d) == [f"w__random seed 0: only in {c}",
                                    "w__random seed 1: the same path at every sampled time (no digests to compare)"]


@pytest.mark.parametrize("digest_text, path_text, needle", [
    ("garbage\n", None, "w__random.digest.csv: columns: missing seed, chunk"),  # an AttributeError
    ("seed,chunk,time_s,physics,map,knowledge,detections\n0,x,2.0,a,b,c,\n", None, "row 2, column chunk: 'x' is not"),
    (None, "garbage\n", "w__random.trajectory.csv: columns: missing seed, time_s, x"),  # a KeyError
    (None, "seed,time_s,x,y,yaw\n0,1.0,oops,0,0\n", "row 2, column x: 'oops' is not a finite number"),
])
def test_a_malformed_run_file_is_one_line_naming_it(tmp_path, digest_text, path_text, needle):
    from rosmeery_jax.core.errors import InputError

    good = ("seed,chunk,time_s,physics,map,knowledge,detections\n0,0,2.0,a,b,c,\n" if digest_text else None,
            "seed,time_s,x,y,yaw\n0,1.0,0,0,0\n" if path_text else None)
    a, b = _folder(tmp_path / "a", *good), _folder(tmp_path / "b", digest_text, path_text)
    with pytest.raises(InputError, match=re.escape(needle)):
        digest.compare(a, b)


def test_diff_says_first_which_settings_differ(tmp_path):
    """Two folders of other noise and localisation part for that reason: diff says so first."""
    folders = []
    for name, noise, loc in (("a", "off", "ground_truth"), ("b", "realistic", "scan_matching")):
        f = _folder(tmp_path / name, path_text="seed,time_s,x,y,yaw\n0,0.0,1.0,1.0,0.0\n")
        (f / "config.json").write_text(json.dumps({"session": {"noise": noise, "localisation": loc, "seeds": 1,
                                                               "out": str(f), "duration": 5.0}}))
        folders.append(f)
    lines = digest.compare(*folders)
    assert lines[0] == (f"settings differ ({folders[0]} / {folders[1]}): localisation 'ground_truth' / "
                        "'scan_matching'; noise 'off' / 'realistic'")
    assert lines[1].startswith("w__random seed 0: the same path")
