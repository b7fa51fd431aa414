"""The benchmark session: worlds x policies x seeds x duration, written as it goes.

One *run* is one (world, policy) pair with all its seeds batched by ``vmap``. A run steps
in chunks (``chunk_s`` of simulated time per jitted call, a ``lax.scan`` over decisions,
each a ``lax.scan`` over ``decide_every`` control steps), logs every object every step, and
when it ends writes its files atomically:

    OUT/runs/<world>__<policy>.metrics.csv    the run's curves (long format)
    OUT/runs/<world>__<policy>.objects.csv    final per-object state per seed
    OUT/maps/<world>__<policy>__seed<k>.ply / .json   semantic maps at the end
    OUT/runs/<world>__<policy>.trajectory.csv robot poses (sampled like metrics.csv)
    OUT/runs/<world>__<policy>.timing.json    wall time of simulation and of the detector
    OUT/metrics.csv, OUT/objects.csv, OUT/trajectories.csv   all finished runs, rewritten after each
    OUT/plots/<world>_<metric>.png            mean over seeds with a std band per policy
    OUT/config.json                           resolved configuration, versions, git revision

``--resume`` skips runs whose files exist (the configuration must match); without it an
existing results folder is refused rather than overwritten.
"""

from __future__ import annotations

import json
import platform as _platform
import subprocess
import time
import tomllib
from dataclasses import asdict, dataclass, field, fields, replace
from importlib import metadata
from pathlib import Path

import numpy as np
import pandas as pd

from rosmeery_jax import metrics, results
from rosmeery_jax.errors import InputError

DETECTORS = ("yolo", "oracle", "off")
MAX_DET = 32  # detections kept per frame (the most confident)


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
        from rosmeery_jax.policies import POLICIES
        from rosmeery_jax.world import world_names

        for w in self.worlds:
            if w not in world_names() and not Path(w).is_file():
                raise InputError(source, "worlds", f"{w!r} is neither a built-in world nor an MJCF file")
        for p in self.policies:
            if p.startswith("replay:"):
                try:
                    worlds = _recordings_by_world(p)
                except InputError as err:
                    raise InputError(err.source if err.source != "config" else source, err.where, err.problem) from None
                names = {Path(w).stem for w in self.worlds}
                if not set(worlds) & names:
                    raise InputError(source, "policies", f"no recording in {p!r} is of a session world "
                                     f"(recorded in: {', '.join(sorted(worlds))})")
            elif p not in POLICIES:
                raise InputError(source, "policies", f"unknown policy {p!r} (built in: {', '.join(POLICIES)}, "
                                 "replay:FILE[+FILE...])")
        if self.detector not in DETECTORS:
            raise InputError(source, "detector", f"{self.detector!r} is not available (available: {', '.join(DETECTORS)})")
        if not isinstance(self.conf_threshold, (int, float)) or not 0 <= self.conf_threshold <= 1:
            raise InputError(source, "conf_threshold", f"{self.conf_threshold!r} must be a number in [0, 1]")
        if self.weights and not Path(self.weights).is_file():
            raise InputError(source, "weights", f"{self.weights!r}: no such file")
        if self.detector == "yolo":
            try:
                import torch  # noqa: F401
            except ImportError:
                raise InputError(source, "detector", "'yolo' needs torch: pip install 'torch==2.13.0' "
                                 "(or use --detector oracle / off)") from None
        for name, v in (("seeds", self.seeds), ("decide_every", self.decide_every)):
            if not isinstance(v, int) or v < 1:
                raise InputError(source, name, f"{v!r} must be a whole number >= 1")
        for name, v in (("duration", self.duration), ("chunk_s", self.chunk_s), ("sample_s", self.sample_s)):
            if not isinstance(v, (int, float)) or not v > 0:
                raise InputError(source, name, f"{v!r} must be a number > 0")
        try:
            metrics.resolve(self.metrics)
            _decisions(self, 0.1)  # the control period is fixed at 0.1 s
        except InputError as err:
            raise InputError(source, err.where, err.problem) from None
        return self


def load_config(path: str | Path | None, **overrides) -> SessionConfig:
    """Built-in defaults, then the TOML file, then command-line overrides (None = unset)."""
    values: dict = {}
    source = "command line"
    if path is not None:
        source = str(path)
        try:
            values = tomllib.loads(Path(path).read_text())
        except FileNotFoundError:
            raise InputError(source, "file", "not found") from None
        except tomllib.TOMLDecodeError as err:
            raise InputError(source, "file", f"not valid TOML ({err})") from None
        values = values.get("session", values)
        known = {f.name for f in fields(SessionConfig)}
        for key in values:
            if key not in known:
                raise InputError(source, key, f"unknown option (options: {', '.join(sorted(known))})")
    values.update({k: v for k, v in overrides.items() if v is not None})
    for key in ("worlds", "policies", "metrics"):
        if isinstance(values.get(key), str):
            values[key] = tuple(x.strip() for x in values[key].split(",") if x.strip())
        elif key in values:
            values[key] = tuple(values[key])
    if "policies" in values:
        values["policies"] = _group_replay(values["policies"])
    if isinstance(values.get("duration"), int):
        values["duration"] = float(values["duration"])
    return replace(SessionConfig(), **values).validate(source)


def _run_name(world: str, policy: str) -> str:
    return f"{Path(world).stem}__{policy_label(policy)}"


def policy_label(policy: str) -> str:
    """The name a policy entry has in results: ``replay:FILES`` -> ``replay``."""
    return "replay" if policy.startswith("replay:") else policy


def replay_files(policy: str) -> list[Path]:
    """The recordings of a ``replay:`` entry: files or glob patterns joined by ``+``."""
    files: list[Path] = []
    for part in policy.removeprefix("replay:").split("+"):
        part = part.strip()
        if not part:
            continue
        hits = sorted(Path().glob(part)) if any(c in part for c in "*?[") else [Path(part)]
        if not hits:
            raise InputError("config", "policies", f"replay: no file matches {part!r}")
        files += hits
    return files


def _recordings_by_world(policy: str) -> dict:
    from rosmeery_jax.teleop.recording import read

    by_world: dict = {}
    for f in replay_files(policy):
        rec = read(f)
        by_world.setdefault(rec.world, []).append(rec)
    return by_world


def _group_replay(tokens: tuple[str, ...]) -> tuple[str, ...]:
    """``replay:a.jsonl,b.jsonl,random`` splits on commas: re-attach the files to their entry."""
    from rosmeery_jax.policies import POLICIES

    out: list[str] = []
    for tok in tokens:
        if out and out[-1].startswith("replay:") and tok not in POLICIES and not tok.startswith("replay:"):
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
            pass
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=Path(__file__).parent,
                             timeout=5)
        out["git"] = rev.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        out["git"] = None
    return out


def _check_out(cfg: SessionConfig, out: Path, resume: bool) -> None:
    saved = out / "config.json"
    if saved.exists():
        if not resume:
            raise InputError(str(out), "out", "already holds results: pass --resume to continue, or choose another --out")
        old = json.loads(saved.read_text())["session"]
        new = json.loads(json.dumps(asdict(cfg)))
        for key in ("seeds", "duration", "detector", "conf_threshold", "weights", "decide_every", "sample_s", "env"):
            if old.get(key) != new.get(key):
                raise InputError(str(saved), key, f"was {old.get(key)!r}, now {new.get(key)!r}: resume needs the same setting")


class Session:
    def __init__(self, cfg: SessionConfig, progress: bool = True):
        self.cfg, self.progress = cfg, progress

    def run(self, resume: bool = False) -> Path:
        cfg = self.cfg
        out = Path(cfg.out)
        _check_out(cfg, out, resume)
        results.write_atomic(out / "config.json", json.dumps({"session": asdict(cfg), "versions": _versions()}, indent=2))
        todo = [(w, p) for w in cfg.worlds for p in cfg.policies
                if not (out / "runs" / f"{_run_name(w, p)}.metrics.csv").exists()
                and (not p.startswith("replay:") or Path(w).stem in _recordings_by_world(p))]
        total = len(todo) * cfg.duration
        bar = _bar(total, self.progress)
        for world, policy in todo:
            self._one(world, policy, out, bar)
            self._merge(out)
        bar.close()
        self._merge(out)
        return out

    def _one(self, world_name: str, policy_name: str, out: Path, bar) -> None:
        import jax
        import jax.numpy as jnp

        from rosmeery_jax.env import make
        from rosmeery_jax.export import write_semantic_map
        from rosmeery_jax.policies import make_policy

        cfg = self.cfg
        detecting = cfg.detector != "off"
        overrides = {"start_yaw": "random", **({"labels": "detections"} if detecting else {}), **cfg.env}
        replaying = policy_name.startswith("replay:")
        if replaying:  # the recordings' own start pose and settings, velocity commands
            from rosmeery_jax.policies.replay import ReplayPolicy

            recs = _recordings_by_world(policy_name)[Path(world_name).stem]
            overrides.update({**recs[0].header.get("env", {}), "start_yaw": "spawn", "action_mode": "velocity"})
        env = make(world_name, **overrides)
        if replaying:
            from rosmeery_jax.teleop.recording import check_world

            for rec in recs:
                check_world(rec, env.world)
            policy = ReplayPolicy(env, recs, cfg.decide_every, _decisions(cfg, env.dt) * cfg.decide_every)
        else:
            policy = make_policy(policy_name, env)
        detector = None
        if detecting:
            from rosmeery_jax.detector.detections import make_detector

            detector = make_detector(cfg.detector, env.world, cfg.conf_threshold, cfg.weights or None)
            label_fn = _label_fn(env)
        b = len(recs) if replaying else cfg.seeds
        keys = jax.vmap(jax.random.key)(jnp.arange(b))
        k_env, k_pol, k_run = (jax.vmap(lambda k, i=i: jax.random.fold_in(k, i))(keys) for i in range(3))
        state = jax.jit(jax.vmap(env.reset))(k_env)
        if replaying:
            for rec, pose in zip(recs, np.asarray(state.pose)):
                if not np.allclose(pose, rec.header["start_pose"], atol=1e-4):
                    raise InputError(str(rec.path), "start_pose", f"{rec.header['start_pose']} is not the world's "
                                     f"start pose {pose.tolist()}")
            pstate = policy.init_batch()
        else:
            pstate = jax.vmap(policy.init)(k_pol)
        steps_per_decision = cfg.decide_every
        total_decisions = _decisions(cfg, env.dt)
        # The largest chunk that divides the run evenly, so one compiled function serves.
        want = max(1, int(round(cfg.chunk_s / (env.dt * steps_per_decision))))
        decisions = max(d for d in range(1, min(want, total_decisions) + 1) if total_decisions % d == 0)
        chunk_fn = _chunk_fn(env, policy, steps_per_decision, decisions, capture=detecting)
        logs, poses, first_log = [], [np.asarray(state.pose)[:, None]], jax.tree.map(np.asarray,
                                                                                  jax.jit(jax.vmap(env.log))(state))
        label = f"{env.world.name}/{policy.name}"
        timing = {"env_s": 0.0, "detector_s": 0.0, "frames": 0}
        for c in range(total_decisions // decisions):
            t0 = time.perf_counter()
            state, pstate, k_run, chunk_logs, chunk_poses, frames = chunk_fn(state, pstate, k_run)
            chunk_logs = jax.tree.map(np.asarray, chunk_logs)  # (B, n, N)
            poses.append(np.asarray(chunk_poses))
            wall = time.perf_counter() - t0
            timing["env_s"] += wall
            if detecting:
                t1 = time.perf_counter()
                state, chunk_logs = _detect(env, detector, label_fn, state, chunk_logs, frames, c * decisions,
                                            steps_per_decision)
                timing["detector_s"] += time.perf_counter() - t1
                timing["frames"] += b * decisions
            n = decisions * steps_per_decision
            logs.append(chunk_logs)
            bar.update(n * env.dt)
            rate = f"{label} {b * n / wall:,.0f} env-steps/s"
            if detecting:
                rate += f", detector {timing['frames'] / max(timing['detector_s'], 1e-9):,.0f} frames/s"
            bar.set_postfix_str(rate)
        logs = jax.tree.map(lambda *a: np.concatenate(a, axis=1), *logs)  # (B, T, N)
        logs = jax.tree.map(lambda a, f: np.concatenate([f[:, None], a], axis=1), logs, first_log)
        times = np.arange(logs.ps.shape[1]) * env.dt
        every = max(1, int(round(cfg.sample_s / env.dt)))
        keep = np.unique(np.r_[np.arange(0, len(times), every), len(times) - 1])
        curves = metrics.compute(logs, env.sk.truth, cfg.metrics)  # {name: (B, T)}
        poses = np.concatenate(poses, axis=1)  # (B, T, 3)
        frames, objects, paths = [], [], []
        tags = dict(world=env.world.name, policy=policy.name, detector=cfg.detector)
        knowledge = jax.tree.map(np.asarray, jax.jit(jax.vmap(env.knowledge))(state))
        name = _run_name(world_name, policy_name)
        for seed in range(b):
            frames.append(results.metric_frame({m: c[seed, keep] for m, c in curves.items()}, times[keep],
                                               seed=seed, **tags))
            paths.append(pd.DataFrame({"world": env.world.name, "policy": policy.name, "seed": seed,
                                       "time_s": np.round(times[keep], 6), "x": poses[seed, keep, 0],
                                       "y": poses[seed, keep, 1], "yaw": poses[seed, keep, 2]}))
            final = jax.tree.map(lambda a: a[seed, -1], logs)
            objects.append(results.object_frame(env.world, final, seed=seed, policy=policy.name, detector=cfg.detector))
            write_semantic_map(out / "maps", f"{name}__seed{seed}", env.world,
                               jax.tree.map(lambda a: a[seed], knowledge), float(times[-1]))
        results.write_csv(pd.concat(objects, ignore_index=True), out / "runs" / f"{name}.objects.csv")
        results.write_atomic(out / "runs" / f"{name}.timing.json", json.dumps(timing, indent=2))
        results.write_csv(pd.concat(paths, ignore_index=True), out / "runs" / f"{name}.trajectory.csv")
        # The metrics file last: its presence marks the run finished (resume).
        results.write_csv(pd.concat(frames, ignore_index=True), out / "runs" / f"{name}.metrics.csv")

    def _merge(self, out: Path) -> None:
        from rosmeery_jax import plots

        runs = sorted((out / "runs").glob("*.metrics.csv")) if (out / "runs").exists() else []
        if not runs:
            return
        df = pd.concat([pd.read_csv(p) for p in runs], ignore_index=True)
        results.write_csv(df, out / "metrics.csv")
        objs = [p.with_name(p.name.replace(".metrics.csv", ".objects.csv")) for p in runs]
        results.write_csv(pd.concat([pd.read_csv(p) for p in objs if p.exists()], ignore_index=True),
                          out / "objects.csv")
        paths = [p.with_name(p.name.replace(".metrics.csv", ".trajectory.csv")) for p in runs]
        paths = [pd.read_csv(p) for p in paths if p.exists()]
        if paths:
            results.write_csv(pd.concat(paths, ignore_index=True), out / "trajectories.csv")
        plots.plot_results(df, out / "plots")


def _decisions(cfg: SessionConfig, dt: float) -> int:
    """Policy decisions in one run; the duration must be a whole number of them."""
    period = dt * cfg.decide_every
    n = int(round(cfg.duration / period))
    if n < 1 or abs(n * period - cfg.duration) > 1e-6:
        raise InputError("config", "duration", f"{cfg.duration} s is not a whole number of decision periods "
                         f"({period:g} s = decide_every x {dt:g} s)")
    return n


def _chunk_fn(env, policy, steps_per_decision: int, decisions: int, capture: bool = False):
    """jit(vmap'd) function: ``decisions`` policy decisions, each followed by
    ``steps_per_decision`` env steps; returns logs (B, decisions * steps, N), poses
    (B, decisions * steps, 3) and, with
    ``capture``, the detector's frames after each decision: RGB (B, F, Hr, Wr, 3) and labels
    (B, F, Hr, Wr) int16 (F = decisions); else None."""
    import jax
    import jax.numpy as jnp

    def one_env(state, pstate, key):
        def decide(carry, _):
            s, ps, k = carry
            k, sub = jax.random.split(k)
            action, ps = policy.decide(s, ps, sub)
            per_step = getattr(policy, "per_step", False)  # replay: one action per step

            def step(s, a):
                s = env.step(s, a if per_step else action)
                return s, (env.log(s), s.pose)

            s, logs = jax.lax.scan(step, s, action if per_step else None, length=steps_per_decision)
            frame = None
            if capture:
                img, lab = env.camera_rgb(s)
                frame = (img, lab.astype(jnp.int16))
            return (s, ps, k), (logs, frame)

        (state, pstate, key), (logs, frames) = jax.lax.scan(decide, (state, pstate, key), None, length=decisions)
        logs, poses = jax.tree.map(lambda a: a.reshape(decisions * steps_per_decision, *a.shape[2:]), logs)
        return state, pstate, key, logs, poses, frames

    return jax.jit(jax.vmap(one_env))


def _label_fn(env):
    """jit(vmap'd): knowledge + detections (B, F, D) -> final knowledge and the label fields
    of the per-object log after each frame's detections (B, F, N)."""
    import jax

    def one_env(k, obj, label, conf):
        def body(k, d):
            k = env.sk.attach(k, *d)
            log = env.sk.log(k)
            return k, (log.conf_true, log.conf_any, log.label, log.declared, log.correct)

        return jax.lax.scan(body, k, (obj, label, conf))

    return jax.jit(jax.vmap(one_env))


_LABEL_FIELDS = ("conf_true", "conf_any", "label", "declared", "correct")


def _detect(env, detector, label_fn, state, logs, frames, first_frame: int, steps_per_decision: int):
    """Run the detector on a chunk's frames, fold the detections into the knowledge, and
    rewrite the chunk's label fields from the step after each frame on, so the curves carry
    no chunk-long lag (a frame taken at the end of decision f counts from decision f + 1)."""
    import jax
    import jax.numpy as jnp

    from rosmeery_jax.detector.detections import pad

    rgb, seg = (np.asarray(a) for a in frames)  # (B, F, H, W, 3), (B, F, H, W)
    b, f = rgb.shape[:2]
    ids = np.stack(np.meshgrid(np.arange(b), first_frame + np.arange(f), indexing="ij"), -1).reshape(-1, 2)
    found = detector(rgb.reshape(b * f, *rgb.shape[2:]), seg.reshape(b * f, *seg.shape[2:]).astype(np.int32), ids)
    dets = [pad(found[i * f:(i + 1) * f], f, MAX_DET) for i in range(b)]
    obj, label, conf = (jnp.asarray(np.stack([d[j] for d in dets])) for j in range(3))
    knowledge, fields = label_fn(state.knowledge, obj, label, conf)
    state = state._replace(knowledge=knowledge)
    fields = [np.asarray(x) for x in fields]  # each (B, F, N)
    frame_of_step = np.arange(logs.ps.shape[1]) // steps_per_decision - 1  # -1: before the chunk's first frame
    take = frame_of_step >= 0
    updates = {}
    for name, per_frame in zip(_LABEL_FIELDS, fields):
        old = getattr(logs, name)
        new = old.copy()
        new[:, take] = per_frame[:, frame_of_step[take]].astype(old.dtype)
        updates[name] = new
    return state, logs._replace(**updates)


def _bar(total: float, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="sim-s", disable=not enabled, bar_format=(
        "{l_bar}{bar}| {n:.0f}/{total:.0f} simulated s [{elapsed}<{remaining}{postfix}]"))
