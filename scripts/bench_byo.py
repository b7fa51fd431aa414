"""What a researcher's own system costs, against the built-ins (figures in docs/performance.md):

1. a plugin policy (a subclass of ``FrontierPolicy`` under another name) against ``frontier``;
2. a trivial Python agent through the vector env (no camera frames, as the engine renders none
   with the detector off) against the engine running ``random``;
3. a second mapper scored at every sampled second against a session with ``perceived`` alone.

Each pair runs as separate sessions, alternating, ``--repeats`` times; the median of each
is printed with the batch, world and duration. Simulation rates exclude compiling.

    .venv/bin/python scripts/bench_byo.py [--seeds 16] [--duration 60] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
from pathlib import Path

from rosmeery_jax.session import Session, SessionConfig

PLUGINS = '''
import numpy as np
from rosmeery_jax.gym import Agent
from rosmeery_jax.policies.frontier import FrontierPolicy
from rosmeery_jax.mapping.perceived import PerceivedMapper


class PluginFrontier(FrontierPolicy):
    name = "plugin_frontier"


class Ahead(Agent):  # trivial: a target 1 m ahead, every decision
    name = "ahead"
    camera = False  # it does not look (the engine renders no frame with the detector off either)

    def act(self, obs):
        x, y, yaw = obs["pose"].T
        return np.stack([x + np.cos(yaw), y + np.sin(yaw), yaw], -1)


class SecondPerceived(PerceivedMapper):
    name = "second_perceived"
'''


def timing(folder: Path, **cfg) -> dict:
    Session(SessionConfig(out=str(folder), **cfg).validate(), progress=False).run()
    return json.loads((folder / "timing.json").read_text())


def compare(tmp: Path, name: str, a: dict, b: dict, repeats: int, figure) -> None:
    got = {"a": [], "b": []}
    for r in range(repeats):
        for k, cfg in (("a", a), ("b", b)):
            got[k].append(figure(timing(tmp / f"{name}_{k}{r}", **cfg)))
    ma, mb = statistics.median(got["a"]), statistics.median(got["b"])
    print(f"{name}: {ma:,.1f} vs {mb:,.1f} (ratio {mb / ma:.2f}; runs {got})", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--world", default="small_office")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        plugins = tmp / "plugins.py"
        plugins.write_text(PLUGINS)
        base = dict(worlds=(args.world,), seeds=args.seeds, duration=args.duration)
        print(f"{args.world}, {args.seeds} seeds, {args.duration:g} s, medians of {args.repeats}", flush=True)
        rate = lambda t: t["env_steps"] / t["sim_s"]  # noqa: E731
        off = dict(base, detector="off")
        compare(tmp, "policy env-steps/s: frontier vs plugin", dict(off, policies=("frontier",)),
                dict(off, policies=(f"{plugins}:PluginFrontier",)), args.repeats, rate)
        compare(tmp, "env-steps/s: engine random vs Python agent", dict(off, policies=("random",)),
                dict(off, policies=(f"agent:{plugins}:Ahead",)), args.repeats, rate)
        seen = dict(base, detector="oracle", policies=("frontier",))
        compare(tmp, "wall s: perceived vs perceived + a second mapper", dict(seen, mappers=("oracle", "perceived")),
                dict(seen, mappers=("oracle", "perceived", f"{plugins}:SecondPerceived")), args.repeats,
                lambda t: t["wall_s"])
        t = timing(tmp / "scoring", **dict(seen, mappers=("oracle", "perceived", f"{plugins}:SecondPerceived")))
        print(f"scoring both mappers' maps every {SessionConfig().sample_s:g} s: {t['score_s']:.2f} s of "
              f"{t['wall_s']:.1f} s wall ({100 * t['score_s'] / t['wall_s']:.1f} %); mappers in all "
              f"{t['mapper_s']:.2f} s", flush=True)


if __name__ == "__main__":
    main()
