"""Fuzz every user-facing loader with N generated inputs each and print the counts.

    .venv/bin/python scripts/fuzz.py [--n 1000] [--only bags,rerun]

For each loader (worlds, session configs, recordings, pose CSVs, maps as PLY and JSON,
transforms, procedural world names, policy files, results folders' run, config and digest
files as resume, join, plot and diff read them, plugin modules, weight files, map bags in
both storages as `evaluate --bag` reads them, results tables as `view` writes a Rerun
recording of them): inputs
tried, valid results, clear one-line errors, and tracebacks (must be 0). The strategies are
the suite's (tests/fuzz_inputs.py); the suite runs a few hundred, this runs thousands.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import fuzz_inputs as fz  # noqa: E402
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


def texts(seed: str):
    return st.one_of(fz.edits().map(lambda e: fz.mutate(seed, e)), fz.number_swaps(seed))


def binary(good: bytes):
    """The bytes with a stretch cut out and junk spliced in."""
    return st.tuples(st.binary(max_size=256), st.integers(0, 2**22), st.integers(0, 64)).map(
        lambda t: good[:t[1] % len(good)] + t[0] + good[t[1] % len(good) + t[2]:])


def weight_bytes():
    from rosmeery_jax.detector.detections import DEFAULT_WEIGHTS

    good = DEFAULT_WEIGHTS.read_bytes()
    return st.tuples(st.binary(max_size=256), st.integers(0, 2**22), st.integers(0, 64)).map(
        lambda t: good[:t[1] % len(good)] + t[0] + good[t[1] % len(good) + t[2]:])


def run(name: str, loader, strategy, filename: str, n: int, folder: Path) -> dict:
    counts = {"tried": 0, "ok": 0, "error": 0, "traceback": 0}
    failures: list[str] = []

    @settings(max_examples=n, deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(strategy)
    def one(data):
        path = folder / filename
        path.write_bytes(data if isinstance(data, bytes) else data.encode("utf-8", "surrogatepass"))
        counts["tried"] += 1
        try:
            counts[fz.check_one(loader, path)] += 1
        except AssertionError as err:
            counts["traceback"] += 1
            failures.append(str(err)[:200])

    t0 = time.perf_counter()
    one()
    counts["seconds"] = round(time.perf_counter() - t0, 1)
    for f in sorted(set(failures))[:5]:
        print(f"  {name}: {f}", file=sys.stderr)
    return counts


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1000, help="inputs per loader")
    ap.add_argument("--only", default="", help="comma-separated words: the loaders whose names hold one")
    args = ap.parse_args()
    loaders = [("worlds (MJCF)", fz.load_world_file, texts(fz.SEED_WORLD), "world.xml"),
               ("session configs (TOML)", fz.load_session_config, texts(fz.SEED_CONFIG), "session.toml"),
               ("recordings (JSONL)", fz.load_recording, texts(fz.recording_text()), "rec.jsonl"),
               ("pose files (CSV)", fz.load_poses, texts(fz.SEED_POSES), "poses.csv"),
               ("session trajectories (CSV)", fz.load_trajectories, texts(fz.SEED_TRAJECTORIES), "trajectories.csv"),
               ("maps (PLY)", fz.load_map_ply, texts(fz.SEED_MAP_PLY), "map.ply"),
               ("maps (JSON)", fz.load_map_json, texts(fz.SEED_MAP_JSON), "map.json"),
               ("transforms (JSON)", fz.load_transform, texts(fz.SEED_TRANSFORM), "transform.json"),
               ("procedural names", fz.load_procedural_name, texts(fz.SEED_PROCEDURAL), "name.txt"),
               ("policy files (msgpack)", fz.load_policy_file, binary(fz.policy_bytes()), "policy.msgpack"),
               ("damaged run files", fz.results_loader(f"runs/{fz.RUN}.metrics.csv", False),
                texts(fz.results_seed(f"runs/{fz.RUN}.metrics.csv")), "run.csv"),
               ("run files, recorded", fz.results_loader(f"runs/{fz.RUN}.metrics.csv", True),
                texts(fz.results_seed(f"runs/{fz.RUN}.metrics.csv")), "run.csv"),
               ("results config files", fz.results_loader("config.json", False),
                texts(fz.results_seed("config.json")), "config.json"),
               ("digest files, recorded", fz.results_loader(f"runs/{fz.RUN}.digest.csv", True),
                texts(fz.results_seed(f"runs/{fz.RUN}.digest.csv")), "digest.csv"),
               ("plugin modules", fz.load_plugin_module, texts(fz.SEED_PLUGIN), "plugin.py")]
    try:
        import rosbags  # noqa: F401

        for storage in ("mcap", "sqlite3"):
            seed = fz.bag_seed(storage)
            name = fz.bag_storage_name(seed)
            loaders.append((f"map bags ({storage})", fz.bag_loader(storage), binary(seed[name]), name))
    except ImportError:
        print("map bags skipped: rosbags not installed (pip install '.[ros]')", file=sys.stderr)
    try:
        import rerun  # noqa: F401

        for table in ("metrics.csv", "trajectories.csv"):
            loaders.append((f"rerun views ({table})", fz.rrd_loader(table), texts(fz.rrd_seed(table)), table))
    except ImportError:
        print("rerun views skipped: rerun-sdk not installed (pip install '.[view]')", file=sys.stderr)
    try:
        import torch  # noqa: F401

        loaders.append(("weight files (.pt)", fz.load_weights, weight_bytes(), "weights.pt"))
    except ImportError:
        print("weight files skipped: torch not installed (pip install '.[detector]')", file=sys.stderr)
    words = [w for w in args.only.split(",") if w]
    loaders = [entry for entry in loaders if not words or any(w in entry[0] for w in words)]
    print(f"{'loader':<26}{'tried':>7}{'valid':>7}{'errors':>8}{'tracebacks':>12}{'s':>7}")
    bad = 0
    with tempfile.TemporaryDirectory() as tmp:
        for name, loader, strategy, filename in loaders:
            c = run(name, loader, strategy, filename, args.n, Path(tmp))
            bad += c["traceback"]
            print(f"{name:<26}{c['tried']:>7}{c['ok']:>7}{c['error']:>8}{c['traceback']:>12}{c['seconds']:>7}",
                  flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
