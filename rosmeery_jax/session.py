"""The benchmark session: worlds x policies x seeds x duration, written as it goes.

One *run* is one (world, policy) pair with all its seeds batched. A run is built
(:func:`build_run`), simulated in chunks (``chunk_s`` of simulated time per jitted call, a
``lax.scan`` over decisions, each a ``lax.scan`` over ``decide_every`` control steps, every
object logged every step), and written atomically when it ends (:func:`write_run`):

    OUT/runs/<world>__<policy>.metrics.csv    the run's curves (long format)
    OUT/runs/<world>__<policy>.objects.csv    final per-object state per seed
    OUT/maps/<world>__<policy>__seed<k>.ply / .json   semantic maps at the end
    OUT/runs/<world>__<policy>.trajectory.csv robot poses (sampled like metrics.csv)
    OUT/runs/<world>__<policy>.timing.json    wall time of simulation and of the detector
    OUT/metrics.csv, OUT/objects.csv, OUT/trajectories.csv   all finished runs, merged at the end
    OUT/plots/<world>_<metric>.png            mean over seeds with a std band per policy
    OUT/config.json                           resolved configuration, input hashes, versions

Everything is validated before anything is written. ``--resume`` skips finished runs and
refuses a changed configuration or changed input files; without it an existing results
folder is refused rather than overwritten.

**Seeds do not depend on their batch-mates.** XLA compiles a different program for every
batch shape, and programs of different shapes round differently, so seed 0 run beside one
other seed would drift (by 1e-5 m within seconds, then onto another path) from seed 0 run
beside two. The batch is therefore always padded to whole blocks of ``BLOCK`` envs, one
compiled block width for every session, and ``lax.map`` runs the blocks: seed k's curves
are bitwise the same in any session with the same settings.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform as _platform  # the standard library
import subprocess
import time
from dataclasses import asdict, dataclass, field, fields, replace
from importlib import metadata
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pandas as pd

from rosmeery_jax import metrics, overrides, results
from rosmeery_jax.errors import InputError, read_toml

DETECTORS = ("yolo", "oracle", "off")
MAX_DET = 32  # detections kept per frame (the most confident)
BLOCK = 8  # envs per compiled block (see the module docstring)
LOG_BYTES_PER_OBJECT_STEP = 24  # ObjectLog: six 4-byte fields
DEVICE_BYTES_PER_ENV = 2.5e6  # measured: 1,024 envs peak at 2.0 GB (docs/performance.md)
# Settings that change results: resume refuses a change to any of them.
RESULT_FIELDS = ("seeds", "duration", "detector", "conf_threshold", "decide_every", "chunk_s", "sample_s",
                 "metrics", "env")


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
    chunk_s: float = 30.0  # simulated seconds per jitted call (progress granularity)
    sample_s: float = 1.0  # seconds between rows of metrics.csv
    out: str = "results/session"
    env: dict = field(default_factory=dict)  # EnvConfig overrides, e.g. {"camera__cull": 0}

    def validate(self, source: str = "config") -> "SessionConfig":
        """Every check that can be made before a run starts; one InputError naming ``source``."""
        from rosmeery_jax.env import EnvConfig

        _check_values(self, source)
        for name, values in (("worlds", self.worlds), ("policies", self.policies), ("metrics", self.metrics)):
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


def _check_values(cfg: SessionConfig, source: str) -> None:
    if cfg.detector not in DETECTORS:
        raise InputError(source, "detector", f"{cfg.detector!r} is not available (available: {', '.join(DETECTORS)})")
    if not 0 <= cfg.conf_threshold <= 1:
        raise InputError(source, "conf_threshold", f"{cfg.conf_threshold!r} must be a number in [0, 1]")
    for name in ("seeds", "decide_every"):
        if getattr(cfg, name) < 1:
            raise InputError(source, name, f"{getattr(cfg, name)!r} must be a whole number >= 1")
    for name in ("duration", "chunk_s", "sample_s"):
        if not getattr(cfg, name) > 0:
            raise InputError(source, name, f"{getattr(cfg, name)!r} must be a number > 0")


def _check_world_name(name: str) -> None:
    """A name that is neither a built-in world nor an existing file is the config's error."""
    from rosmeery_jax.world import world_names

    if name not in world_names() and not Path(name).is_file():
        raise InputError("config", "worlds", f"{name!r} is neither a built-in world ({', '.join(world_names())}) "
                         "nor an MJCF file")


def _load_world(name: str):
    from rosmeery_jax.world import load_world

    return load_world(name)


def _check_policy(spec: str, worlds) -> None:
    from rosmeery_jax.policies import REPLAY_PREFIX, policy_class
    from rosmeery_jax.policies.replay import recordings_by_world

    from rosmeery_jax.env import EnvConfig

    policy_class(spec)
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
    """Refuse a session whose logs or batch cannot fit in this machine's memory."""
    steps = cfg.duration / 0.1  # floats: a huge duration must give a huge estimate, not an overflow
    batch = float(_padded(cfg.seeds))
    need_host = max(batch * steps * w.truth.num_objects * LOG_BYTES_PER_OBJECT_STEP for w in worlds)
    need_device = batch * DEVICE_BYTES_PER_ENV
    have = _memory_bytes()
    for what, need in (("the per-step logs of one run", need_host), ("the batch's device state", need_device)):
        if need > 0.8 * have:
            raise InputError(source, "seeds" if what.startswith("the batch") else "duration",
                             f"{cfg.seeds} seeds x {cfg.duration:g} s: {what} need about {need / 1e9:,.1f} GB, "
                             f"more than this machine's {have / 1e9:.1f} GB allows (fewer seeds or a shorter "
                             "duration)")


def _memory_bytes() -> float:
    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 8e9


def _padded(b: int) -> int:
    return -(-b // BLOCK) * BLOCK


def load_config(path: str | Path | None, **cli) -> SessionConfig:
    """Built-in defaults, then the TOML file, then command-line overrides (None = unset)."""
    values: dict = {}
    source = "command line"
    if path is not None:
        source = str(path)
        values = _read_toml(Path(path))
    values.update({k: v for k, v in cli.items() if v is not None})
    for key in ("worlds", "policies", "metrics"):
        if isinstance(values.get(key), str):
            values[key] = tuple(x.strip() for x in values[key].split(",") if x.strip())
        elif key in values:
            if not isinstance(values[key], (list, tuple)) or not all(isinstance(x, str) for x in values[key]):
                raise InputError(source, key, f"{values[key]!r} must be a list of names or a comma-separated string")
            values[key] = tuple(values[key])
    if "policies" in values:
        values["policies"] = _group_replay(values["policies"])
    if "env" in values and not isinstance(values["env"], dict):
        raise InputError(source, "env", f"{values['env']!r} must be a table of EnvConfig overrides")
    lists = {k: values.pop(k) for k in ("worlds", "policies", "metrics", "env") if k in values}
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
    """sha256 of every input file whose contents change results: worlds, recordings, weights."""
    from rosmeery_jax.policies import REPLAY_PREFIX
    from rosmeery_jax.policies.replay import replay_files

    out = {"worlds": {w.name: _sha256(w.path) for w in map(_load_world, cfg.worlds)},
           "recordings": {str(f): _sha256(f) for p in cfg.policies if p.startswith(REPLAY_PREFIX)
                          for f in replay_files(p)}}
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


class Run(NamedTuple):
    """One (world, policy) pair ready to simulate. b: the entries kept (seeds or recordings);
    the batch is padded to ``_padded(b)`` envs."""

    name: str
    env: Any
    policy: Any
    detector: Any
    b: int


class Session:
    def __init__(self, cfg: SessionConfig, progress: bool = True):
        self.cfg, self.progress = cfg, progress

    def run(self, resume: bool = False) -> Path:
        cfg = self.cfg
        out = Path(cfg.out)
        record = check_out(cfg, resume)
        results.write_atomic(out / "config.json", json.dumps({**record, "versions": _versions()}, indent=2))
        todo = [(w, p) for w in cfg.worlds for p in cfg.policies
                if not (out / "runs" / f"{run_name(w, p)}.metrics.csv").exists()]
        bar = _bar(len(todo) * cfg.duration, self.progress)
        for world, policy in todo:
            run = build_run(cfg, world, policy)
            if run.b:  # a replay entry has no recording in this world
                write_run(cfg, run, out, *simulate(cfg, run, bar))
            bar.update(0 if run.b else cfg.duration)
        bar.close()
        merge(out)
        return out


def run_name(world: str, policy: str) -> str:
    from rosmeery_jax.policies import policy_label

    return f"{_load_world(world).name}__{policy_label(policy)}"


def build_run(cfg: SessionConfig, world: str, spec: str) -> Run:
    """The env, policy and detector of one (world, policy) pair."""
    from rosmeery_jax.env import make
    from rosmeery_jax.policies import make_policy, policy_class

    detecting = cfg.detector != "off"
    env = make(world, **{"labels": "detections" if detecting else "observed", **overrides.flatten(cfg.env),
                         **policy_class(spec).env_overrides(spec, _load_world(world).name)})
    policy = make_policy(spec, env, decide_every=cfg.decide_every,
                         total_steps=_decisions(cfg, env.dt) * cfg.decide_every)
    detector = None
    if detecting:
        from rosmeery_jax.detector.detections import make_detector

        detector = make_detector(cfg.detector, env.world, cfg.conf_threshold, cfg.weights or None)
    return Run(run_name(world, spec), env, policy, detector, policy.batch_size(cfg.seeds))


def blocked(fn):
    """jit of ``fn`` (one env) over a batch of B = k * BLOCK envs: vmap over a block, lax.map
    over blocks, so every session compiles the same block width (module docstring)."""
    import jax

    def run(*args):
        blocks = jax.tree.map(lambda a: a.reshape(a.shape[0] // BLOCK, BLOCK, *a.shape[1:]), args)
        out = jax.lax.map(lambda a: jax.vmap(fn)(*a), blocks)
        return jax.tree.map(lambda a: a.reshape(a.shape[0] * a.shape[1], *a.shape[2:]), out)

    return jax.jit(run)


def simulate(cfg: SessionConfig, run: Run, bar):
    """Step the run to its end. Returns logs (ObjectLog, (B, T + 1, N) numpy), poses
    (B, T + 1, 3), the final knowledge (batched) and the timing record; B = run.b."""
    import jax
    import jax.numpy as jnp

    env, policy = run.env, run.policy
    keys = jax.vmap(jax.random.key)(jnp.arange(_padded(run.b)))
    k_env, k_pol, k_run = (jax.vmap(lambda k, i=i: jax.random.fold_in(k, i))(keys) for i in range(3))
    state = blocked(env.reset)(k_env)
    policy.check_start(np.asarray(state.pose)[:run.b])
    pstate = policy.init_batch(k_pol)
    total = _decisions(cfg, env.dt)
    want = max(1, int(round(cfg.chunk_s / (env.dt * cfg.decide_every))))
    # The largest chunk that divides the run evenly, so one compiled function serves.
    per_chunk = max(d for d in range(1, min(want, total) + 1) if total % d == 0)
    capture = run.detector is not None
    chunk_fn = blocked(_chunk_fn(env, policy, cfg.decide_every, per_chunk, capture))
    label_fn = blocked(_label_fn(env)) if capture else None
    logs = [jax.tree.map(lambda a: np.asarray(a)[:, None], blocked(env.log)(state))]
    poses = [np.asarray(state.pose)[:, None]]
    timing = {"env_s": 0.0, "detector_s": 0.0, "frames": 0}
    label = f"{env.world.name}/{policy.name}"
    for c in range(total // per_chunk):
        t0 = time.perf_counter()
        state, pstate, k_run, chunk_logs, chunk_poses, frames = chunk_fn(state, pstate, k_run)
        chunk_logs = jax.tree.map(np.asarray, chunk_logs)  # (B, n, N)
        poses.append(np.asarray(chunk_poses))
        wall = time.perf_counter() - t0
        timing["env_s"] += wall
        if capture:
            t1 = time.perf_counter()
            state, chunk_logs = _detect(run, label_fn, state, chunk_logs, frames, c * per_chunk, cfg.decide_every)
            timing["detector_s"] += time.perf_counter() - t1
            timing["frames"] += run.b * per_chunk
        logs.append(chunk_logs)
        n = per_chunk * cfg.decide_every
        bar.update(n * env.dt)
        rate = f"{label} {run.b * n / wall:,.0f} env-steps/s"
        if capture:
            rate += f", detector {timing['frames'] / max(timing['detector_s'], 1e-9):,.0f} frames/s"
        bar.set_postfix_str(rate)
    keep = lambda a: a[:run.b]  # noqa: E731 - drop the padding entries
    logs = jax.tree.map(lambda *a: keep(np.concatenate(a, axis=1)), *logs)
    knowledge = jax.tree.map(lambda a: keep(np.asarray(a)), blocked(env.labelled_knowledge)(state))
    return logs, keep(np.concatenate(poses, axis=1)), knowledge, timing


def write_run(cfg: SessionConfig, run: Run, out: Path, logs, poses, knowledge, timing) -> None:
    """The run's files, each atomically; the metrics file last (its presence marks the run done)."""
    import jax

    from rosmeery_jax.semantic_map import write_semantic_map

    env = run.env
    times = np.arange(logs.ps.shape[1]) * env.dt
    every = max(1, int(round(cfg.sample_s / env.dt)))
    keep = np.unique(np.r_[np.arange(0, len(times), every), len(times) - 1])
    tags = dict(world=env.world.name, policy=run.policy.name, detector=cfg.detector)
    curves, objects, paths = [], [], []
    for seed in range(run.b):  # per seed, so a seed's numbers never depend on the batch shape
        log = jax.tree.map(lambda a: a[seed], logs)
        c = metrics.compute(log, env.sk.truth, cfg.metrics)  # {name: (T,)}
        curves.append(results.metric_frame({m: v[keep] for m, v in c.items()}, times[keep], seed=seed, **tags))
        paths.append(pd.DataFrame({"world": env.world.name, "policy": run.policy.name, "seed": seed,
                                   "time_s": np.round(times[keep], 6), "x": poses[seed, keep, 0],
                                   "y": poses[seed, keep, 1], "yaw": poses[seed, keep, 2]}))
        final = jax.tree.map(lambda a: a[-1], log)
        objects.append(results.object_frame(env.world, final, seed=seed, policy=run.policy.name,
                                            detector=cfg.detector))
        write_semantic_map(out / "maps", f"{run.name}__seed{seed}", env.world,
                           jax.tree.map(lambda a: a[seed], knowledge), float(times[-1]))
    runs = out / "runs"
    results.write_csv(pd.concat(objects, ignore_index=True), runs / f"{run.name}.objects.csv")
    results.write_atomic(runs / f"{run.name}.timing.json", json.dumps(timing, indent=2))
    results.write_csv(pd.concat(paths, ignore_index=True), runs / f"{run.name}.trajectory.csv")
    results.write_csv(pd.concat(curves, ignore_index=True), runs / f"{run.name}.metrics.csv")


def merge(out: Path) -> None:
    """The merged tables and plots of every finished run in ``out``."""
    from rosmeery_jax import plots

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


def _chunk_fn(env, policy, steps_per_decision: int, decisions: int, capture: bool = False):
    """One env: ``decisions`` policy decisions, each followed by ``steps_per_decision`` env
    steps; returns logs (decisions * steps, N), poses (decisions * steps, 3) and, with
    ``capture``, the detector's frames after each decision: RGB (F, Hr, Wr, 3) and labels
    (F, Hr, Wr) int16 (F = decisions); else None."""
    import jax
    import jax.numpy as jnp

    def one_env(state, pstate, key):
        def decide(carry, _):
            s, ps, k = carry
            k, sub = jax.random.split(k)
            action, ps = policy.decide(s, ps, sub)

            def step(s, a):
                s = env.step(s, a if policy.per_step else action)
                return s, (env.log(s), s.pose)

            s, logs = jax.lax.scan(step, s, action if policy.per_step else None, length=steps_per_decision)
            frame = None
            if capture:
                img, lab = env.camera_rgb(s)
                frame = (img, lab.astype(jnp.int16))
            return (s, ps, k), (logs, frame)

        (state, pstate, key), (logs, frames) = jax.lax.scan(decide, (state, pstate, key), None, length=decisions)
        logs, poses = jax.tree.map(lambda a: a.reshape(decisions * steps_per_decision, *a.shape[2:]), logs)
        return state, pstate, key, logs, poses, frames

    return one_env


def _label_fn(env):
    """One env: knowledge + detections (F, D) -> final knowledge and the label fields of the
    per-object log after each frame's detections (F, N)."""
    import jax

    def one_env(k, obj, label, conf):
        def body(k, d):
            k = env.sk.attach(k, *d)
            log = env.sk.log(k)
            return k, (log.conf_true, log.conf_any, log.label, log.declared, log.correct)

        return jax.lax.scan(body, k, (obj, label, conf))

    return one_env


_LABEL_FIELDS = ("conf_true", "conf_any", "label", "declared", "correct")


def _detect(run: Run, label_fn, state, logs, frames, first_frame: int, steps_per_decision: int):
    """Run the detector on a chunk's frames, fold the detections into the knowledge, and
    rewrite the chunk's label fields from the step after each frame on, so the curves carry
    no chunk-long lag (a frame taken at the end of decision f counts from decision f + 1)."""
    import jax.numpy as jnp

    from rosmeery_jax.detector.detections import pad

    b = run.b  # the padding entries' frames are not detected: they get no detections
    rgb, seg = (np.asarray(a)[:b] for a in frames)  # (b, F, H, W, 3), (b, F, H, W)
    f = rgb.shape[1]
    ids = np.stack(np.meshgrid(np.arange(b), first_frame + np.arange(f), indexing="ij"), -1).reshape(-1, 2)
    found = run.detector(rgb.reshape(b * f, *rgb.shape[2:]), seg.reshape(b * f, *seg.shape[2:]).astype(np.int32),
                         ids)
    dets = [pad(found[i * f:(i + 1) * f], f, MAX_DET) for i in range(b)]
    dets += [pad([], f, MAX_DET)] * (frames[0].shape[0] - b)
    obj, label, conf = (jnp.asarray(np.stack([d[j] for d in dets])) for j in range(3))
    knowledge, per_frame = label_fn(state.knowledge, obj, label, conf)
    state = state._replace(knowledge=knowledge)
    frame_of_step = np.arange(logs.ps.shape[1]) // steps_per_decision - 1  # -1: before the chunk's first frame
    take = frame_of_step >= 0
    updates = {}
    for name, values in zip(_LABEL_FIELDS, per_frame):
        new = getattr(logs, name).copy()
        new[:, take] = np.asarray(values)[:, frame_of_step[take]].astype(new.dtype)
        updates[name] = new
    return state, logs._replace(**updates)


def _bar(total: float, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="sim-s", disable=not enabled, bar_format=(
        "{l_bar}{bar}| {n:.0f}/{total:.0f} simulated s [{elapsed}<{remaining}{postfix}]"))
