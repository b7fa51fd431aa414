"""The benchmark session: worlds x policies x seeds x duration.

Every unfinished (world, policy) pair of a session is simulated in one batch per env
configuration (:mod:`rosmeery_jax.session.engine`: worlds as padded data, one compiled chunk
function, the detector in a worker thread), and each *run* (one world and policy, all its
seeds) is then written atomically (:func:`write_run`):

    OUT/runs/<world>__<policy>.metrics.csv    the run's curves (long format)
    OUT/runs/<world>__<policy>.objects.csv    final per-object state per seed
    OUT/maps/<world>__<policy>__seed<k>.ply / .json   semantic maps at the end (mapper "oracle";
        ``__seed<k>__perceived`` for the perceived mapper's: rosmeery_jax.scoring.perceived)
    OUT/runs/<world>__<policy>.trajectory.csv robot poses (sampled like metrics.csv)
    OUT/runs/<world>__<policy>.timing.json    the batch's compile, simulation and detector times
    OUT/metrics.csv, OUT/objects.csv, OUT/trajectories.csv   all finished runs, merged once at the end
    OUT/plots/<world>_<metric>.png            mean over seeds with a std band per policy
    OUT/config.json                           resolved configuration, input hashes, versions
    OUT/timing.json                           compile (``compiles``), simulation, detector and wall times

Everything is validated before anything is written. ``--resume`` skips finished runs and
refuses a changed configuration or changed input files; without it an existing results
folder is refused rather than overwritten. A seed's curves are bitwise the same whatever
runs beside it (engine: blocks) and whatever ``chunk_s`` is.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform as _platform  # the standard library
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field, fields, replace
from importlib import metadata
from pathlib import Path

import numpy as np
import pandas as pd

from rosmeery_jax.scoring import metrics, results

from rosmeery_jax.core import overrides
from rosmeery_jax.core.errors import InputError, read_toml

DETECTORS = ("yolo", "oracle", "off")
MAPPERS = ("oracle", "perceived")
LOG_BYTES_PER_OBJECT_STEP = 24  # ObjectLog: six 4-byte fields
DEVICE_BYTES_PER_ENV = 2.5e6  # measured: 1,024 envs peak at 2.0 GB (docs/performance.md)
# Settings that change results: resume refuses a change to any of them.
RESULT_FIELDS = ("seeds", "duration", "detector", "conf_threshold", "decide_every", "detector_period_s", "sample_s",
                 "metrics", "env", "mappers")


@dataclass(frozen=True)
class SessionConfig:
    worlds: tuple[str, ...] = ("kitchen", "laboratory", "small_office", "large_office")
    policies: tuple[str, ...] = ("frontier", "random")
    seeds: int = 5
    duration: float = 300.0  # simulated seconds per run
    detector: str = "yolo"  # "yolo" (torch), "oracle" (simulated from ground truth), "off"
    conf_threshold: float = 0.25  # detections below it are dropped
    weights: str = ""  # YOLO-v5 weights for "yolo" ("" = the shipped ones)
    metrics: tuple[str, ...] = metrics.DEFAULT_METRICS
    decide_every: int = 10  # control steps between policy decisions (10 = 1 s)
    chunk_s: float = 30.0  # simulated seconds per jitted call without a detector (progress
    # granularity only: results do not depend on it)
    detector_period_s: float = 10.0  # labels from the frames of one period reach the robot's
    # knowledge (what policies see) at the start of the period after next
    sample_s: float = 1.0  # seconds between rows of metrics.csv
    mappers: tuple[str, ...] = ("oracle",)  # who builds the scored map: "oracle" (the built-in
    # knowledge: detections tied to objects by the ground-truth segmentation) and/or
    # "perceived" (depth inside detector boxes, no ground truth: rosmeery_jax.scoring.perceived)
    out: str = "results/session"
    env: dict = field(default_factory=dict)  # EnvConfig overrides, e.g. {"camera__cull": 0}
    devices: int = 0  # split each batch over this many devices (speed only: results are the same);
    # 0 = every device JAX has (on a CPU one host device per core, less one for torch when
    # the YOLO detector runs), at most one per block

    def validate(self, source: str = "config") -> "SessionConfig":
        """Every check that can be made before a run starts; one InputError naming ``source``."""
        _check_values(self, source)
        if self.devices != 1:
            # Before anything below starts JAX. With YOLO, torch needs a core of its own: on the
            # 2-core machine two host devices beside it made the paper session slower (docs/cluster.md).
            host_devices(self.devices or max(1, cores() - (self.detector == "yolo")))
        from rosmeery_jax.env import EnvConfig

        for name, values in (("worlds", self.worlds), ("policies", self.policies), ("metrics", self.metrics),
                         ("mappers", self.mappers)):
            if not values:
                raise InputError(source, name, "is empty: name at least one")
        with _as_source(source):
            metrics.resolve(self.metrics)
            EnvConfig().with_overrides(source, **overrides.flatten(self.env))
            for w in self.worlds:
                _check_world_name(w)
            worlds = [_load_world(w) for w in self.worlds]
            for p in self.policies:
                _check_policy(p, worlds)
            _decisions(self, 0.1)  # the control period is fixed at 0.1 s
        _check_unique(self, worlds, source)
        if self.weights and not Path(self.weights).is_file():
            raise InputError(source, "weights", f"{self.weights!r}: no such file")
        if self.detector == "yolo":
            try:
                import torch  # noqa: F401
            except ImportError:
                raise InputError(source, "detector", "'yolo' needs torch: pip install 'torch==2.13.0' "
                                 "(or use --detector oracle / off)") from None
        _check_size(self, worlds, source)
        if self.devices > 1:
            import jax

            if len(jax.devices()) < self.devices:
                raise InputError(source, "devices", f"{self.devices} asked, {len(jax.devices())} "
                                 f"{jax.devices()[0].platform} device(s) available (host devices are made "
                                 "from the CPU's cores only if JAX has not started yet)")
        return self


class _as_source:
    """Name ``source`` in InputErrors that checks deeper down raise with the generic source
    "config" (they do not know which file the value came from)."""

    def __init__(self, source: str):
        self.source = source

    def __enter__(self):
        return self

    def __exit__(self, kind, err, tb):
        if isinstance(err, InputError) and err.source == "config":
            raise InputError(self.source, err.where, err.problem) from None
        return False


def cores() -> int:
    """The CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def host_devices(n: int) -> None:
    """Let XLA make ``n`` devices of the CPU's cores, for ``devices`` on a machine without
    accelerators. XLA reads the flag when JAX starts, so once JAX has started (a notebook,
    a test run) the environment is left as it is: child processes would inherit it."""
    if "jax" in sys.modules:
        from jax._src import xla_bridge  # JAX has no public way to ask whether it has started

        if xla_bridge.backends_are_initialized():
            return
    if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={n}".strip()


def _check_values(cfg: SessionConfig, source: str) -> None:
    if cfg.detector not in DETECTORS:
        raise InputError(source, "detector", f"{cfg.detector!r} is not available (available: {', '.join(DETECTORS)})")
    if not 0 <= cfg.conf_threshold <= 1:
        raise InputError(source, "conf_threshold", f"{cfg.conf_threshold!r} must be a number in [0, 1]")
    for name in ("seeds", "decide_every"):
        if getattr(cfg, name) < 1:
            raise InputError(source, name, f"{getattr(cfg, name)!r} must be a whole number >= 1")
    if cfg.devices < 0:
        raise InputError(source, "devices", f"{cfg.devices!r} must be a whole number >= 0 (0: every device)")
    for name in ("duration", "chunk_s", "sample_s", "detector_period_s"):
        if not getattr(cfg, name) > 0:
            raise InputError(source, name, f"{getattr(cfg, name)!r} must be a number > 0")
    for m in cfg.mappers:
        if m not in MAPPERS:
            raise InputError(source, "mappers", f"{m!r} is not a mapper (mappers: {', '.join(MAPPERS)})")
    if "perceived" in cfg.mappers and cfg.detector == "off":
        raise InputError(source, "mappers", "'perceived' builds its map from detector boxes: use --detector yolo "
                         "or oracle")


def _check_world_name(name: str) -> None:
    """A name that is neither a built-in world nor an existing file is the config's error."""
    from rosmeery_jax.world import world_names

    if name not in world_names() and not Path(name).is_file() and not name.startswith("procedural:"):
        raise InputError("config", "worlds", f"{name!r} is neither a built-in world ({', '.join(world_names())}) "
                         "nor an MJCF file nor procedural:KIND:SEED")


def _load_world(name: str):
    from rosmeery_jax.world import load_world

    return load_world(name)


def _check_policy(spec: str, worlds) -> None:
    from rosmeery_jax.policies import LearnedPolicy, REPLAY_PREFIX, policy_class
    from rosmeery_jax.policies.learned import policy_file
    from rosmeery_jax.policies.replay import recordings_by_world

    from rosmeery_jax.env import EnvConfig

    if policy_class(spec) is LearnedPolicy:
        from rosmeery_jax.rl.ppo import load_policy

        load_policy(policy_file(spec))  # one line naming the file if it is not a policy file
    if spec.startswith(REPLAY_PREFIX):
        recorded = recordings_by_world(spec)
        if not set(recorded) & {w.name for w in worlds}:
            raise InputError("config", "policies", f"no recording in {spec!r} is of a session world "
                             f"(recorded in: {', '.join(sorted(recorded))})")
        for recs in recorded.values():  # one batch per world: one set of env settings
            for rec in recs:
                EnvConfig().with_overrides(f"{rec.path}: line 1: env", **overrides.flatten(rec.header.get("env", {})))
                if rec.header.get("env", {}) != recs[0].header.get("env", {}):
                    raise InputError(str(rec.path), "line 1: env", f"differs from {recs[0].path}'s: recordings "
                                     "replayed together need the same env settings")


def _check_unique(cfg: SessionConfig, worlds, source: str) -> None:
    """Two entries that would write the same run files are refused, not merged or overwritten."""
    from rosmeery_jax.policies import policy_label

    seen: dict[str, str] = {}
    for spec, w in zip(cfg.worlds, worlds):
        if w.name in seen:
            raise InputError(source, "worlds", f"{seen[w.name]!r} and {spec!r} are both named {w.name!r}: their "
                             "results would share files (rename one file)")
        seen[w.name] = spec
    labels = [policy_label(p) for p in cfg.policies]
    for label in labels:
        if labels.count(label) > 1:
            raise InputError(source, "policies", f"{label!r} appears twice (join replay files with '+' in one entry)")


def _check_size(cfg: SessionConfig, worlds, source: str) -> None:
    """Refuse a session whose logs or batch cannot fit in this machine's memory (the whole
    session is one batch: every world x policy x seed, each policy padded to whole blocks)."""
    from rosmeery_jax.session.engine import BLOCK

    steps = cfg.duration / 0.1 / log_every(cfg)  # logged steps; floats: a huge duration must give
    # a huge estimate, not an overflow
    per_policy = -(-cfg.seeds // BLOCK) * BLOCK * len(worlds)
    batch = float(per_policy * len(cfg.policies))
    need_host = batch * steps * max(w.truth.num_objects for w in worlds) * LOG_BYTES_PER_OBJECT_STEP
    need_device = batch * DEVICE_BYTES_PER_ENV
    have = _memory_bytes()
    for what, need in (("the logs", need_host), ("the batch's device state", need_device)):
        if need > 0.8 * have:
            raise InputError(source, "seeds" if what.startswith("the batch") else "duration",
                             f"{cfg.seeds} seeds x {len(worlds)} worlds x {len(cfg.policies)} policies x "
                             f"{cfg.duration:g} s: {what} need about {need / 1e9:,.1f} GB, more than this "
                             f"machine's {have / 1e9:.1f} GB allows (fewer seeds, worlds or a shorter duration)")


def _memory_bytes() -> float:
    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 8e9


def load_config(path: str | Path | None, **cli) -> SessionConfig:
    """Built-in defaults, then the TOML file, then command-line overrides (None = unset)."""
    values: dict = {}
    source = "command line"
    if path is not None:
        source = str(path)
        values = _read_toml(Path(path))
    values.update({k: v for k, v in cli.items() if v is not None})
    for key in ("worlds", "policies", "metrics", "mappers"):
        if isinstance(values.get(key), str):
            values[key] = tuple(x.strip() for x in values[key].split(",") if x.strip())
        elif key in values:
            if not isinstance(values[key], (list, tuple)) or not all(isinstance(x, str) for x in values[key]):
                raise InputError(source, key, f"{values[key]!r} must be a list of names or a comma-separated string")
            values[key] = tuple(values[key])
    if "worlds" in values:  # procedural:KIND:A-B is one world per seed
        from rosmeery_jax.world.generate import expand_names

        values["worlds"] = tuple(expand_names(values["worlds"]))
    if "policies" in values:
        values["policies"] = _group_replay(values["policies"])
    if "env" in values and not isinstance(values["env"], dict):
        raise InputError(source, "env", f"{values['env']!r} must be a table of EnvConfig overrides")
    lists = {k: values.pop(k) for k in ("worlds", "policies", "metrics", "mappers", "env") if k in values}
    cfg = overrides.apply(SessionConfig(), values, source)  # type-checks every scalar option
    return replace(cfg, **lists).validate(source)


def _read_toml(path: Path) -> dict:
    source = str(path)
    values = read_toml(path)
    if "session" in values:
        extra = sorted(set(values) - {"session"})
        if extra:
            raise InputError(source, extra[0], "is outside the [session] table: move it inside, or drop the table")
        values = values["session"]
        if not isinstance(values, dict):
            raise InputError(source, "session", "must be a table")
    known = {f.name for f in fields(SessionConfig)}
    for key in values:
        if key not in known:
            raise InputError(source, key, f"unknown option (options: {', '.join(sorted(known))})")
    return dict(values)


def _group_replay(tokens: tuple[str, ...]) -> tuple[str, ...]:
    """``replay:a.jsonl,b.jsonl,random`` splits on commas: re-attach the files to their entry."""
    from rosmeery_jax.policies import POLICIES, REPLAY_PREFIX

    out: list[str] = []
    for tok in tokens:
        if out and out[-1].startswith(REPLAY_PREFIX) and tok not in POLICIES and not tok.startswith(REPLAY_PREFIX):
            out[-1] += "+" + tok
        else:
            out.append(tok)
    return tuple(out)


def _versions() -> dict:
    out = {"python": _platform.python_version()}
    for pkg in ("rosmeery-jax", "jax", "jaxlib", "mujoco", "mujoco-mjx", "numpy", "pandas", "torch"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass  # not installed (torch without the detector extra)
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=Path(__file__).parent,
                             timeout=5)
        out["git"] = rev.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        out["git"] = None
    return out


def _sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def input_hashes(cfg: SessionConfig) -> dict:
    """sha256 of every input file whose contents change results: worlds, recordings, learned
    policies, weights."""
    from rosmeery_jax.policies import LearnedPolicy, REPLAY_PREFIX, policy_class
    from rosmeery_jax.policies.learned import policy_file
    from rosmeery_jax.policies.replay import replay_files

    out = {"worlds": {w.name: _sha256(w.path) for w in map(_load_world, cfg.worlds)},
           "recordings": {str(f): _sha256(f) for p in cfg.policies if p.startswith(REPLAY_PREFIX)
                          for f in replay_files(p)},
           "policies": {p: _sha256(policy_file(p)) for p in cfg.policies if policy_class(p) is LearnedPolicy}}
    if cfg.detector == "yolo":
        from rosmeery_jax.detector.detections import DEFAULT_WEIGHTS

        out["weights"] = _sha256(cfg.weights or DEFAULT_WEIGHTS)
    return out


def check_out(cfg: SessionConfig, resume: bool) -> dict:
    """Check the results folder before anything is written; returns the record for config.json."""
    out = Path(cfg.out)
    record = {"session": json.loads(json.dumps(asdict(cfg))), "inputs": input_hashes(cfg)}
    if out.exists() and not out.is_dir():
        raise InputError(str(out), "out", "is a file, not a results folder")
    saved = out / "config.json"
    if not saved.exists():
        if out.exists() and any(out.iterdir()):
            raise InputError(str(out), "out", "is not empty and has no config.json: choose another --out")
        return record
    if not resume:
        raise InputError(str(out), "out", "already holds results: pass --resume to continue, or choose another --out")
    try:
        old = json.loads(saved.read_text(encoding="utf-8"))
        old_session, old_inputs = old["session"], old["inputs"]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError):
        raise InputError(str(saved), "file", "unreadable or not a session config: cannot resume from it") from None
    for key in RESULT_FIELDS:
        if old_session.get(key) != record["session"][key]:
            raise InputError(str(saved), key, f"was {old_session.get(key)!r}, now {record['session'][key]!r}: "
                             "resume needs the same setting")
    for kind, hashes in record["inputs"].items():
        before = old_inputs.get(kind, {})
        for name, digest in (hashes.items() if isinstance(hashes, dict) else [(kind, hashes)]):
            was = before.get(name) if isinstance(before, dict) else before
            if was is not None and was != digest:
                raise InputError(str(saved), f"inputs.{kind}", f"{name} has changed since the session started: "
                                 "resume would mix results of two versions")
    record["inputs"] = _merged(old_inputs, record["inputs"])
    return record


def _merged(old: dict, new: dict) -> dict:
    out = dict(old)
    for k, v in new.items():
        out[k] = {**old.get(k, {}), **v} if isinstance(v, dict) else v
    return out


class Session:
    """``cluster``: None to simulate here, or a Ray address (rosmeery_jax.session.cluster) to send
    each unfinished run to a worker; ``cache``: the workers' persistent compilation cache."""

    def __init__(self, cfg: SessionConfig, progress: bool = True, cluster: str | None = None, cache: bool = True):
        self.cfg, self.progress, self.cluster, self.cache = cfg, progress, cluster, cache

    def run(self, resume: bool = False) -> Path:
        """Run every unfinished (world, policy) pair in one batch per env configuration
        (rosmeery_jax.session.engine), or one Ray task each, write each run's files, then the
        merged tables and plots."""
        cfg = self.cfg
        out = Path(cfg.out)
        if self.cluster:
            from rosmeery_jax.session.cluster import require_ray

            require_ray()  # before anything is written
            if cfg.devices > 1:
                raise InputError("command line", "--devices", "not with --cluster: each Ray worker runs its "
                                 "shard on one device")
        record = check_out(cfg, resume)
        results.write_atomic(out / "config.json", json.dumps({**record, "versions": _versions()}, indent=2))
        todo = [(w, p) for w in cfg.worlds for p in cfg.policies
                if not (out / "runs" / f"{run_name(w, p)}.metrics.csv").exists()]
        t_start = time.perf_counter()
        parts, extra = [], {}
        if todo and self.cluster:
            from rosmeery_jax.session.cluster import simulate_on_cluster

            bar = _bar(len(todo) * cfg.duration, self.progress)
            parts = simulate_on_cluster(cfg, todo, out, self.cluster, bar, self.cache)
            bar.close()
            extra = {"cluster": self.cluster, "shards": len(parts)}
        elif todo:
            parts = self._simulate_here(todo, out)
        merge(out)
        if parts:
            timing = {**sum_timing(parts, t_start), **extra, "groups": [g for p in parts for g in p.get("groups", [p])]}
            results.write_atomic(out / "timing.json", json.dumps(timing, indent=2))
        return out

    def _simulate_here(self, todo: list[tuple[str, str]], out: Path) -> list[dict]:
        """Simulate the runs in this process; returns each group's timing."""
        from rosmeery_jax.session.runner import engine

        cfg = self.cfg
        total = _decisions(cfg, 0.1)
        groups = engine.build_groups(todo, cfg.env, cfg.detector != "off", cfg.seeds, cfg.decide_every,
                                     total * cfg.decide_every, cfg.devices)
        bar = _bar(len(groups) * cfg.duration, self.progress)
        timings = []
        for group in groups:
            clock = engine.CompileClock()
            t0 = time.perf_counter()
            sim = engine.simulate(group, total, _per_call(cfg, total), cfg.decide_every,
                                  _detectors(cfg, group), bar, clock, "perceived" in cfg.mappers, log_every(cfg))
            timing = {**sim.timing, "compile_s": clock.seconds, "wall_s": time.perf_counter() - t0,
                      "devices": group.devices}
            timings.append(timing)
            for run in group.runs:
                write_run(cfg, group, run, out, sim, timing)
        bar.close()
        return timings


TIMING_KEYS = ("env_steps", "frames", "detector_s", "mapper_s", "wait_s", "compile_s", "compiles", "xla_compiles",
               "cache_hits", "sim_s")


def sum_timing(parts: list[dict], t_start: float) -> dict:
    """This invocation's figures: the groups' (or cluster shards') times summed, and the wall
    time from ``t_start`` to now (set-up, compile, simulation, detection, writing)."""
    total = {k: sum(g.get(k, 0) for g in parts) for k in TIMING_KEYS}
    wall = time.perf_counter() - t_start
    return {**total, "wall_s": wall, "env_steps_per_s": total["env_steps"] / wall,
            "sim_env_steps_per_s": total["env_steps"] / max(total["sim_s"], 1e-9)}


def run_name(world: str, policy: str) -> str:
    from rosmeery_jax.policies import policy_label

    return f"{_load_world(world).name}__{policy_label(policy)}"


def _per_call(cfg: SessionConfig, total: int) -> int:
    """Decisions per jitted call: the detector period with a detector (the label schedule
    is cut at its boundaries), else ``chunk_s`` (progress granularity only); the largest
    that divides the run, so one compiled function serves."""
    want = cfg.detector_period_s if cfg.detector != "off" else cfg.chunk_s
    want = max(1, int(round(want / (0.1 * cfg.decide_every))))
    return max(d for d in range(1, min(want, total) + 1) if total % d == 0)


def log_every(cfg: SessionConfig) -> int:
    """Steps between the engine's per-object logs: a divisor of ``sample_s`` in steps (the
    rows metrics.csv keeps) and of ``decide_every`` (the chunk function logs within each
    decision's steps)."""
    return math.gcd(_sample_steps(cfg), cfg.decide_every)


def _sample_steps(cfg: SessionConfig) -> int:
    """Control steps between the rows of metrics.csv (the control period is fixed at 0.1 s)."""
    return max(1, int(round(cfg.sample_s / 0.1)))


def _detectors(cfg: SessionConfig, group) -> dict | None:
    """{world index: detector} for the group's worlds, or None with the detector off."""
    if cfg.detector == "off":
        return None
    from rosmeery_jax.detector.detections import make_detector

    return {w: make_detector(cfg.detector, env.world, cfg.conf_threshold, cfg.weights or None)
            for w, env in enumerate(group.envs)}


def write_run(cfg: SessionConfig, group, run, out: Path, sim, timing: dict) -> None:
    """One run's files, each atomically; the metrics file last (its presence marks the run
    done). ``sim`` holds the group's real envs in row order; padding objects are cut off."""
    import jax

    from rosmeery_jax.scoring.semantic_map import write_semantic_map

    env = group.envs[run.world]
    world, policy = env.world, group.policies[run.policy].name
    n, s = world.truth.num_objects, len(world.truth.samples.object)
    rows = np.searchsorted(np.flatnonzero(group.real), run.rows)
    logs = jax.tree.map(lambda a: a[rows][..., :n], sim.logs)
    poses = sim.poses[rows]
    step = np.arange(logs.ps.shape[1]) * sim.log_every  # each log row's step
    times = step * env.dt
    every = _sample_steps(cfg) // sim.log_every
    keep = np.unique(np.r_[np.arange(0, len(times), every), len(times) - 1])
    tags = dict(world=world.name, policy=policy, detector=cfg.detector)
    curves, objects, paths = [], [], []
    for seed in range(len(rows)):  # per seed, so a seed's numbers never depend on the batch shape
        log = jax.tree.map(lambda a: a[seed], logs)
        mapped = {}
        if "oracle" in cfg.mappers:
            mapped["oracle"] = log
            k = jax.tree.map(lambda a: a[rows[seed]], sim.knowledge)
            k = k._replace(seen=k.seen[:s], **{f: getattr(k, f)[:n] for f in ("label", "confidence", "conf_true",
                                                                                "conf_any")})
            write_semantic_map(out / "maps", f"{run.name}__seed{seed}", world, k, float(times[-1]))
        if "perceived" in cfg.mappers:
            mapped["perceived"] = _perceived_log(env, sim.mappers[rows[seed]], step, cfg.decide_every,
                                                 out / "maps" / f"{run.name}__seed{seed}__perceived", times[-1])
        for mapper, mlog in mapped.items():
            c = metrics.compute(mlog, env.truth, cfg.metrics)  # {name: (T,)}
            curves.append(results.metric_frame({m: v[keep] for m, v in c.items()}, times[keep], seed=seed,
                                               mapper=mapper, **tags))
            final = jax.tree.map(lambda a: a[-1], mlog)
            objects.append(results.object_frame(world, final, seed=seed, mapper=mapper, policy=policy,
                                                detector=cfg.detector))
        paths.append(pd.DataFrame({"world": world.name, "policy": policy, "seed": seed,
                                   "time_s": np.round(times[keep], 6), "x": poses[seed, step[keep], 0],
                                   "y": poses[seed, step[keep], 1], "yaw": poses[seed, step[keep], 2]}))
    runs = out / "runs"
    results.write_csv(pd.concat(objects, ignore_index=True), runs / f"{run.name}.objects.csv")
    results.write_atomic(runs / f"{run.name}.timing.json", json.dumps(
        {**timing, "note": "simulated in one batch with the other runs of its group: the times are the group's"},
        indent=2))
    results.write_csv(pd.concat(paths, ignore_index=True), runs / f"{run.name}.trajectory.csv")
    results.write_csv(pd.concat(curves, ignore_index=True), runs / f"{run.name}.metrics.csv")


def _perceived_log(env, mapper, steps: np.ndarray, decide_every: int, stem: Path, time_s: float):
    """The perceived mapper's ObjectLog (T, N) at ``steps`` (T,): the map of the frames
    taken before each step (a frame counts from the step after it, as labels do); its final
    map is written to ``stem``.ply / .json."""
    from rosmeery_jax.scoring.evaluate import TOLERANCE
    from rosmeery_jax.scoring.perceived import frame_logs
    from rosmeery_jax.scoring.semantic_map import build_map, write_map

    counted = np.maximum(steps - 1, 0) // decide_every  # frames counted at each step
    per_frame = frame_logs(env.world, mapper, int(counted[-1]), TOLERANCE)
    points, instance, label, conf = mapper.snapshot(int(counted[-1]))
    names = [f"instance_{i}" for i in range(len(label))]
    write_map(stem.parent, stem.name, *build_map(env.world, points, instance, names, label, conf, float(time_s)))
    return type(per_frame)(*(a[counted] for a in per_frame))


def merge(out: Path) -> None:
    """The merged tables and plots of every finished run in ``out``."""
    from rosmeery_jax.scoring import plots

    runs = sorted((out / "runs").glob("*.metrics.csv")) if (out / "runs").exists() else []
    if not runs:
        return
    df = pd.concat([pd.read_csv(p) for p in runs], ignore_index=True)
    results.write_csv(df, out / "metrics.csv")
    for suffix, merged in ((".objects.csv", "objects.csv"), (".trajectory.csv", "trajectories.csv")):
        parts = [p.with_name(p.name.replace(".metrics.csv", suffix)) for p in runs]
        parts = [pd.read_csv(p) for p in parts if p.exists()]
        if parts:
            results.write_csv(pd.concat(parts, ignore_index=True), out / merged)
    plots.plot_results(df, out / "plots")


def _decisions(cfg: SessionConfig, dt: float) -> int:
    """Policy decisions in one run; the duration must be a whole number of them."""
    period = dt * cfg.decide_every
    if not math.isfinite(cfg.duration):
        raise InputError("config", "duration", f"{cfg.duration} must be a finite number of seconds")
    n = int(round(cfg.duration / period))
    if n < 1 or abs(n * period - cfg.duration) > 1e-6:
        raise InputError("config", "duration", f"{cfg.duration} s is not a whole number of decision periods "
                         f"({period:g} s = decide_every x {dt:g} s)")
    return n


def _bar(total: float, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="sim-s", disable=not enabled, bar_format=(
        "{l_bar}{bar}| {n:.0f}/{total:.0f} simulated s [{elapsed}<{remaining}{postfix}]"))
