"""The perceived mapper's cost, apart from the session: record every call a session makes to
a mapper (detector frames, every step's depth, map reads), then replay them through the
perceived mapper, timing each kind of call and profiling by function.

    .venv/bin/python scripts/bench_mapper.py [--worlds kitchen,large_office] [--duration 480]
        [--record DIR] [--top 20]

The recording session runs each world with frontier, random and semantic NBV, one seed,
YOLO labels (a few minutes); ``--record DIR`` keeps it (and reuses it when it is there).
The replay prints seconds per call kind, a digest of every map read (equal digests: the
same maps), and the profile's top functions by their own time.
"""

from __future__ import annotations

import argparse
import cProfile
import hashlib
import pickle
import pstats
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from rosmeery_jax.mapping.perceived import PerceivedMapper
from rosmeery_jax.mapping.protocol import Mapper, MapState

CALLS: list = []  # (camera, categories, calls) per mapper built, filled by Recorder


class Recorder(Mapper):
    """A mapper that keeps every call it gets, and holds an empty map."""

    name = "recorder"

    def __init__(self, camera, categories=()):
        super().__init__(camera, categories)
        self.calls: list = []
        CALLS.append((camera, tuple(categories), self.calls))

    @classmethod
    def reads_depth(cls) -> bool:
        return True

    def add(self, frame) -> None:
        self.calls.append(("add", frame._replace(rgb=None)))

    def add_depth(self, frame) -> None:
        self.calls.append(("depth", frame))

    def semantic_map(self) -> MapState:
        self.calls.append(("map", None))
        return MapState(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros(0, np.float32))


def record(worlds: tuple[str, ...], duration: float, out: Path) -> list:
    import rosmeery_jax as rj

    cfg = rj.SessionConfig(worlds=worlds, policies=("frontier", "random", "semantic_nbv"), seeds=1,
                           duration=duration, detector="yolo", mappers=("oracle", "bench_mapper:Recorder"),
                           out=str(out / "session"))
    rj.Session(cfg.validate(), progress=False).run()
    plugin = sys.modules["bench_mapper"]  # the session imported this file as the plugin's module
    runs = [c for c in plugin.CALLS if len(c[2]) > 10]  # the check's test frame left out
    (out / "calls.pkl").write_bytes(pickle.dumps(runs, protocol=5))
    return runs


def replay(runs: list) -> tuple[dict, list]:
    spent, digests = defaultdict(float), []
    for camera, categories, calls in runs:
        mapper, h = PerceivedMapper(camera, categories), hashlib.sha256()
        for kind, frame in calls:
            t0 = time.perf_counter()
            if kind == "add":
                mapper.add(frame)
            elif kind == "depth":
                mapper.add_depth(frame)
            else:
                state = mapper.semantic_map()
            spent[kind] += time.perf_counter() - t0
            if kind == "map":
                for a in state:
                    h.update(np.ascontiguousarray(a).tobytes())
        digests.append(h.hexdigest()[:16])
    return spent, digests


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", default="kitchen,large_office")
    ap.add_argument("--duration", type=float, default=480.0)
    ap.add_argument("--record", type=Path, default=None, help="keep the recording here (reused if present)")
    ap.add_argument("--top", type=int, default=20)
    args = ap.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parent))  # this file is the Recorder plugin's module
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.record or Path(tmp)
        saved = folder / "calls.pkl"
        runs = pickle.loads(saved.read_bytes()) if saved.is_file() else \
            record(tuple(args.worlds.split(",")), args.duration, folder)
        runs = [r for r in runs if len(r[2]) > 10]
        replay(runs[:1])  # compile the mapper's kernels first
        profile = cProfile.Profile()
        spent, digests = replay(runs)
        print(f"{sum(spent.values()):.2f} s for {len(runs)} runs of {args.duration:g} s: "
              + ", ".join(f"{k} {v:.2f} s" for k, v in spent.items()))
        print("map digests:", " ".join(digests))
        profile.enable()
        replay(runs)
        profile.disable()
        pstats.Stats(profile).sort_stats("tottime").print_stats(args.top)
    return 0


if __name__ == "__main__":
    sys.exit(main())
