"""Where two runs part: per-chunk digests of the state catch a one-ulp change in one env,
and `rosmeery diff` names the run, seed, chunk and part."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from rosmeery_jax.apps.cli import main
from rosmeery_jax.session import digest, engine

RUN = ["run", "--worlds", "small_office", "--policies", "random", "--seeds", "3", "--duration", "20",
       "--detector", "oracle", "--detector-period-s", "5", "--digest", "--quiet"]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("digest") / "a"
    assert main([*RUN, "--out", str(out)]) == 0
    return out


def test_the_digest_catches_a_one_ulp_change_in_one_env(reference, tmp_path, monkeypatch, capsys):
    table = pd.read_csv(reference / "runs" / "small_office__random.digest.csv", dtype=str)
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
    assert main([*RUN, "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["diff", str(reference), str(out)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0] == "small_office__random seed 0: identical over 4 chunks"
    assert lines[1].startswith("small_office__random seed 1: different from the first chunk; at chunk 0 (5.0 s) "
                               "physics")
    assert lines[2] == "small_office__random seed 2: identical over 4 chunks"


def test_without_digests_the_paths_are_compared(reference, tmp_path, capsys):
    other = tmp_path / "c"
    (other / "runs").mkdir(parents=True)
    for suffix in (".metrics.csv", ".trajectory.csv"):
        df = pd.read_csv(reference / "runs" / f"small_office__random{suffix}")
        if suffix == ".trajectory.csv":
            df.loc[(df.seed == 2) & (df.time_s >= 7.0), "x"] += 0.25
        df.to_csv(other / "runs" / f"small_office__random{suffix}", index=False)
    lines = digest.compare(reference, other)
    assert lines[0].startswith("small_office__random seed 0: the same path")
    assert lines[2].startswith("small_office__random seed 2: the paths part at 7 s by 0.25")
    (other / "runs" / "kitchen__random.metrics.csv").write_text("")  # a run of the second folder alone
    assert digest.compare(reference, other)[0] == f"kitchen__random: only in {other}"
    assert main(["diff", str(reference), str(tmp_path / "typo")]) == 2  # was: every run "only in" the first
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "typo: runs: no finished runs" in err
