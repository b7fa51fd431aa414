"""Fuzzing the loaders: mutated worlds, session configs, recordings, pose files and weight
files give a valid result or one clear error line, never a traceback. ``scripts/fuzz.py``
runs the same strategies for thousands of inputs and prints the counts."""

from __future__ import annotations

import fuzz_inputs as fz
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st


def fuzz(n: int):
    """Deterministic examples (CI runs the same inputs every time), no per-example deadline."""
    return settings(max_examples=n, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _write(tmp_path, name: str, data) -> object:
    path = tmp_path / name
    path.write_bytes(data if isinstance(data, bytes) else data.encode("utf-8", "surrogatepass"))
    return path


@fuzz(60)
@given(st.one_of(fz.edits().map(lambda e: fz.mutate(fz.SEED_WORLD, e)), fz.number_swaps(fz.SEED_WORLD)))
def test_mutated_worlds(tmp_path, text):
    fz.check_one(fz.load_world_file, _write(tmp_path, "world.xml", text))


@fuzz(120)
@given(st.one_of(fz.edits().map(lambda e: fz.mutate(fz.SEED_CONFIG, e)), fz.number_swaps(fz.SEED_CONFIG)))
def test_mutated_session_configs(tmp_path, text):
    fz.check_one(fz.load_session_config, _write(tmp_path, "session.toml", text))
    assert not (tmp_path / "never_written").exists()  # validation writes nothing


@pytest.fixture(scope="module")
def recording():
    return fz.recording_text()


@fuzz(100)
@given(data=st.data())
def test_mutated_recordings(tmp_path, recording, data):
    text = data.draw(st.one_of(fz.edits().map(lambda e: fz.mutate(recording, e)), fz.number_swaps(recording)))
    fz.check_one(fz.load_recording, _write(tmp_path, "rec.jsonl", text))


@fuzz(100)
@given(st.one_of(fz.edits().map(lambda e: fz.mutate(fz.SEED_POSES, e)), fz.number_swaps(fz.SEED_POSES)))
def test_mutated_pose_files(tmp_path, text):
    fz.check_one(fz.load_poses, _write(tmp_path, "poses.csv", text))


@fuzz(60)
@given(st.one_of(fz.edits().map(lambda e: fz.mutate(fz.SEED_TRAJECTORIES, e)), fz.number_swaps(fz.SEED_TRAJECTORIES)))
def test_mutated_session_trajectories(tmp_path, text):
    fz.check_one(fz.load_trajectories, _write(tmp_path, "trajectories.csv", text))


@fuzz(40)
@given(st.binary(max_size=256), st.integers(0, 2**20), st.integers(0, 64))
def test_corrupted_weight_files(tmp_path, junk, where, cut):
    pytest.importorskip("torch")
    from rosmeery_jax.detector.detections import DEFAULT_WEIGHTS

    good = DEFAULT_WEIGHTS.read_bytes()
    p = where % len(good)
    data = good[:p] + junk + good[p + cut:] if junk or cut else good[:p]
    fz.check_one(fz.load_weights, _write(tmp_path, "weights.pt", data))


@pytest.mark.parametrize("name, loader, seed", [
    ("map.ply", fz.load_map_ply, fz.SEED_MAP_PLY), ("map.json", fz.load_map_json, fz.SEED_MAP_JSON),
    ("transform.json", fz.load_transform, fz.SEED_TRANSFORM), ("name.txt", fz.load_procedural_name, fz.SEED_PROCEDURAL)])
def test_mutated_maps_transforms_and_procedural_names(tmp_path, name, loader, seed):
    assert fz.check_one(loader, _write(tmp_path, name, seed)) == "ok"  # the seed itself is valid

    @fuzz(60)
    @given(st.one_of(fz.edits().map(lambda e: fz.mutate(seed, e)), fz.number_swaps(seed)))
    def one(text):
        fz.check_one(loader, _write(tmp_path, name, text))

    one()


@fuzz(60)
@given(st.binary(max_size=256), st.integers(0, 2**16), st.integers(0, 64))
def test_corrupted_policy_files(tmp_path, junk, where, cut):
    good = fz.policy_bytes()
    where %= len(good)
    fz.check_one(fz.load_policy_file, _write(tmp_path, "policy.msgpack", good[:where] + junk + good[where + cut:]))


@pytest.mark.parametrize("name, loader, seed", [
    ("run.csv", fz.results_loader(f"runs/{fz.RUN}.metrics.csv", False), f"runs/{fz.RUN}.metrics.csv"),
    ("run.csv", fz.results_loader(f"runs/{fz.RUN}.metrics.csv", True), f"runs/{fz.RUN}.metrics.csv"),
    ("config.json", fz.results_loader("config.json", False), "config.json"),
    ("digest.csv", fz.results_loader(f"runs/{fz.RUN}.digest.csv", True), f"runs/{fz.RUN}.digest.csv")])
def test_damaged_results_folders(tmp_path, name, loader, seed):
    """A run file, config or digest of a results folder, damaged (and the damage recorded as
    the folder's own, so the tables' own checks read it): resume, join, plot and diff give a
    valid reading or one line naming the file."""
    text = fz.results_seed(seed)
    assert fz.check_one(loader, _write(tmp_path, name, text)) == "ok"

    @fuzz(40)
    @given(st.one_of(fz.edits().map(lambda e: fz.mutate(text, e)), fz.number_swaps(text)))
    def one(mutated):
        fz.check_one(loader, _write(tmp_path, name, mutated))

    one()


def test_mutated_plugin_modules(tmp_path):
    assert fz.check_one(fz.load_plugin_module, _write(tmp_path, "plugin.py", fz.SEED_PLUGIN)) == "ok"

    @fuzz(40)
    @given(st.one_of(fz.edits().map(lambda e: fz.mutate(fz.SEED_PLUGIN, e)), fz.number_swaps(fz.SEED_PLUGIN)))
    def one(text):
        fz.check_one(fz.load_plugin_module, _write(tmp_path, "plugin.py", text))

    one()


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_corrupted_map_bags(tmp_path, storage):
    """A bag of map clouds with bytes cut out and junk spliced into its storage file: read
    and scored, or one line naming the bag."""
    pytest.importorskip("rosbags")
    seed = fz.bag_seed(storage)
    good = seed[fz.bag_storage_name(seed)]
    loader = fz.bag_loader(storage)
    name = fz.bag_storage_name(seed)
    assert fz.check_one(loader, _write(tmp_path, name, good)) == "ok"

    @fuzz(30)
    @given(st.binary(max_size=64), st.integers(0, len(good) - 1), st.integers(0, 64))
    def one(junk, where, cut):
        fz.check_one(loader, _write(tmp_path, name, good[:where] + junk + good[where + cut:]))

    one()


@pytest.mark.parametrize("file", ["metrics.csv", "trajectories.csv"])
def test_mutated_tables_viewed_in_rerun(tmp_path, file):
    """A results table, damaged and recorded as the folder's own: `rosmeery view` writes a
    recording or gives one line naming the table."""
    pytest.importorskip("rerun")
    text = fz.rrd_seed(file)
    loader = fz.rrd_loader(file)
    assert fz.check_one(loader, _write(tmp_path, file, text)) == "ok"

    @fuzz(25)
    @given(st.one_of(fz.edits().map(lambda e: fz.mutate(text, e)), fz.number_swaps(text)))
    def one(mutated):
        fz.check_one(loader, _write(tmp_path, file, mutated))

    one()
