"""The ``rosmeery`` command line (also ``python -m rosmeery_jax``).

Every sub-command turns bad input into one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pandas as pd

from rosmeery_jax import metrics
from rosmeery_jax.apps import detector_commands, rerun_view, ros_bags, world_commands
from rosmeery_jax.apps.arguments import WEIGHTS_HELP, int_list, positive
from rosmeery_jax.apps.bench import BenchConfig, check, format_table, run_bench
from rosmeery_jax.apps.columns import columns
from rosmeery_jax.apps.sensor_streams import RecordConfig, record
from rosmeery_jax.apps.teleop.server import Teleop, serve
from rosmeery_jax.core import specs
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import output_folder, require_new, write_atomic
from rosmeery_jax.core.xla import compilation_cache, cores, host_devices
from rosmeery_jax.detector import runtime as runtimes
from rosmeery_jax.env import make
from rosmeery_jax.metrics import field, map_score, tasks
from rosmeery_jax.metrics.align import to_world
from rosmeery_jax.metrics.map_file import write_semantic_map
from rosmeery_jax.metrics.trajectory import read_poses, replay
from rosmeery_jax.results import plots, statistics, tables, time_use
from rosmeery_jax.session import Session, SessionConfig, digest, load_config
from rosmeery_jax.session.join import join
from rosmeery_jax.session.outputs import check_folder, oracle_maps
from rosmeery_jax.world import episodes, load_world


def _cmd_bench(args) -> int:
    cfg = BenchConfig(world=args.world, batches=args.batches, steps=args.steps,
                      memory_batch=args.memory_batch, session_s=args.session_s, devices=args.devices)
    check(cfg)
    host_devices(args.devices or cores())  # before JAX starts
    load_world(args.world)  # a bad name fails here, in one line, before any compile
    quiet = (lambda msg: print(msg, file=sys.stderr)) if args.json else print
    result = run_bench(cfg, progress=quiet)
    print(json.dumps(result, indent=2) if args.json else format_table(result))
    return 0


def _policy_seed(run: str | None) -> tuple[str, int] | None:
    """``--run POLICY:SEED`` as (policy, seed); None when not given."""
    if run is None:
        return None
    policy, _, seed = run.rpartition(":")
    if not policy or not seed.isdigit():
        raise InputError("command line", "--run", f"{run!r} is not POLICY:SEED (as random:0)")
    return policy, int(seed)


def _cmd_replay(args) -> int:
    out = require_new(args.out)
    times, poses = read_poses(args.poses, load_world(args.world), _policy_seed(args.run))
    names = metrics.resolve(args.metrics.split(",")) if args.metrics else metrics.DEFAULT_METRICS
    env = make(args.world)
    run = replay(env, times, poses)
    curves = metrics.compute(run.logs, env.sk.truth, names)
    wanted, task = field.wanted(names), tasks.wanted(names)
    if wanted or task:  # the map metrics of the knowledge's map as it grew, sample by sample
        curves.update(oracle_maps(env.world, run.stamps, np.arange(len(times)), run.logs, wanted,
                                  tasks.TaskQuery(task) if task else None))
    curves = {n: curves[n] for n in names}
    tags = dict(policy="replay", detector="off", seed=0)
    final = jax.tree.map(lambda a: a[-1], run.logs)
    with output_folder(out):
        tables.write_csv(tables.metric_frame(curves, times, world=env.world.name, **tags), out / "metrics.csv")
        tables.write_csv(tables.object_frame(env.world, final, **tags), out / "objects.csv")
        write_semantic_map(out, "semantic_map", env.world, run.knowledge, float(times[-1]))
    print(f"{env.world.title}: {len(times)} poses over {times[-1] - times[0]:.1f} s")
    rows = []
    for name, c in curves.items():
        s = metrics.summarize(times, c)
        rows.append((name, f"{s['final']:.3f}", f"{s['auc']:.3f}", f"{s['t50_s']:.1f}", f"{s['t90_s']:.1f}"))
    print(columns(("metric", "final", "auc", "t50 s", "t90 s"), rows, right=(1, 2, 3, 4)))
    print(f"wrote {out}/metrics.csv, objects.csv, semantic_map.ply, semantic_map.json")
    return 0


def _cmd_run(args) -> int:
    cfg = load_config(args.config, worlds=args.worlds, policies=args.policies, seeds=args.seeds,
                      first_seed=args.first_seed, duration=args.duration, detector=args.detector, out=args.out,
                      metrics=args.metrics, conf_threshold=args.conf_threshold, weights=args.weights,
                      chunk_s=args.chunk_s, detector_runtime=args.detector_runtime,
                      detector_period_s=args.detector_period_s, mappers=args.mapper, devices=args.devices,
                      digest=args.digest or None, noise=args.noise, localisation=args.localisation,
                      task_episodes=args.task_episodes, task_attempts=args.task_attempts, task=args.task)
    seeds = f"{cfg.seeds} seeds" if not cfg.first_seed else f"seeds {cfg.first_seed}-{cfg.seed_range[-1]}"
    print(f"session: {len(cfg.worlds)} worlds x {len(cfg.policies)} policies x {seeds} x {cfg.duration:g} s -> "
          f"{cfg.out}")
    if args.rerun:
        rerun_view.check_out(args.rerun)  # the optional package and the name, before the session runs
    out = Session(cfg, progress=not args.quiet, cluster=args.cluster, cache=not args.no_cache).run(resume=args.resume)
    _print_summary(out)
    if args.rerun:
        _logged(rerun_view.view(out, args.rerun), args.rerun)
    return 0


def _logged(what: dict, rrd) -> None:
    print(f"rerun: {rrd} ({what['bytes'] / 1e6:.1f} MB: {what['runs']} runs, {what['maps']} maps, "
          f"{what['curves']} curves, {what['frames']} frames; open it with: rerun {rrd})")


def _cmd_view(args) -> int:
    d = Path(args.dir)
    out = Path(args.out) if args.out else d / "session.rrd"
    rerun_view.check_out(out, "--out")  # before any work
    check_folder(d)
    split = (lambda text: [x.strip() for x in text.split(",") if x.strip()] if text else None)  # noqa: E731
    positive(args, "max_points")
    try:
        seeds = [int(s) for s in split(args.seeds)] if args.seeds else None
    except ValueError:
        raise InputError("command line", "--seeds", f"{args.seeds!r} is not a list of seed numbers") from None
    _logged(rerun_view.view(d, out, split(args.worlds), split(args.policies), seeds, args.max_points), out)
    return 0


def _print_summary(out: Path) -> None:
    df = tables.load(out)
    df["policy"] = df.policy.where(df.mapper == "oracle", df.policy + " [" + df.mapper + "]")
    rows = []
    for (w, p, m), g in df.groupby(["world", "policy", "metric"], sort=False):
        per_seed = [metrics.summarize(s.time_s.to_numpy(), s.value.to_numpy()) for _, s in g.groupby("seed")]
        final = statistics.interval([x["final"] for x in per_seed])
        auc = sum(x["auc"] for x in per_seed) / len(per_seed)
        t90 = sum(x["t90_s"] for x in per_seed) / len(per_seed)
        rows.append((w, p, m, f"{final.mean:.3f}", final.bounds(".3f"), f"{auc:.3f}", f"{t90:.1f}"))
    print(columns(("world", "policy", "metric", "final", "95% CI over seeds", "auc", "t90 s"), rows,
                  right=(3, 5, 6)))
    if (out / "navigation.csv").exists():
        print(time_use.summary(pd.read_csv(out / "navigation.csv")))
    if (out / "timing.json").exists():
        t = json.loads((out / "timing.json").read_text())
        print(f"engine: {t['env_steps']:,} env-steps in {t['wall_s']:.1f} s ({t['env_steps_per_s']:,.0f} env-steps/s "
              f"end to end), of which compile {t['compile_s']:.1f} s ({t['compiles']} compiled chunk function"
              f"{'s' if t['compiles'] != 1 else ''})")
        if t["frames"]:
            print(f"detector: {t['frames']:,} frames in {t['detector_s']:.1f} s ({t['frames'] / t['detector_s']:,.0f} "
                  f"frames/s) in a worker thread; the simulation waited {t['wait_s']:.1f} s for it")
        if t.get("score_s"):  # a mapper's maps were scored (mapper_s also counts the empty feed)
            print(f"mappers (fed and scored): {t['mapper_s']:.1f} s in the same worker thread "
                  f"({t.get('mapper_cpu_s', 0):.1f} CPU-s over the mappers' threads), of which scoring their maps "
                  f"{t['score_s']:.1f} s")
        if (out / "tasks.csv").exists() and "task_s" in t:
            print(_tasks_line(pd.read_csv(out / "tasks.csv"), t["task_s"]))
    print(f"results in {out}/ (metrics.csv, objects.csv, config.json, maps/, plots/)")


def _tasks_line(tasks_df: pd.DataFrame, task_s: float) -> str:
    """The executed tasks in one line: per mapper, success and SPL over every episode."""
    per = tasks_df.groupby("mapper", sort=False)[["success", "spl"]].mean()
    said = "; ".join(f"{m}: success {r.success:.2f}, SPL {r.spl:.2f}" for m, r in per.iterrows())
    return f"objectnav: {len(tasks_df):,} episodes driven in {task_s:.1f} s ({said}; tasks.csv)"


def _cmd_teleop(args) -> int:
    if not 1 <= args.port <= 65535:
        raise InputError("command line", "--port", f"{args.port} is not a TCP port (1-65535)")
    positive(args, "seed")
    if not 0 <= args.conf_threshold <= 1:  # as a session's
        raise InputError("command line", "--conf-threshold", f"{args.conf_threshold!r} must be a number in [0, 1]")
    if args.detector == "yolo":
        runtimes.check(runtimes.DEFAULT, "command line", "--detector", "'yolo'", " (or use --detector oracle / off)")
    load_world(args.world)  # a bad name fails here, in one line
    record = Path(args.record or f"recordings/{Path(args.world).stem}-{time.strftime('%Y%m%d-%H%M%S')}.jsonl")
    if record.exists():
        raise InputError(str(record), "--record", "exists already: recordings are never overwritten")
    try:  # the port is checked before a minute of compiling, and before the recording exists
        with socket.create_server((args.host, args.port)):
            pass
    except OSError as err:
        raise InputError(f"{args.host}:{args.port}", "--port", f"cannot serve there ({err.strerror or err})") from None
    print(f"loading {args.world} and compiling (about a minute on first use)...", flush=True)
    app = Teleop(args.world, record=record, detector=args.detector, seed=args.seed,
                 conf_threshold=args.conf_threshold, weights=args.weights, view=args.view)

    def ready(addr):
        print(f"teleop: open http://{addr[0]}:{addr[1]}/ (arrow keys / WASD drive; Stop or Ctrl-C ends; "
              f"{args.view} view)", flush=True)
        print(f"recording to {record}", flush=True)

    try:
        serve(app, args.host, args.port, ready)
    except OSError as err:  # taken between the check and now
        app.stop()
        raise InputError(f"{args.host}:{args.port}", "--port", f"cannot serve there ({err.strerror or err})") from None
    if app.error:
        print(f"rosmeery: {app.error}", file=sys.stderr)
    f = app.frame
    print(f"stopped after {f.t:.1f} s; " + ", ".join(f"{k} {v:.3f}" for k, v in app.final_metrics().items()))
    print(f"recording: {record} (replay: rosmeery run --worlds {app.env.world.name} --policies replay:{record})")
    return 1 if app.error else 0


def _cmd_evaluate(args) -> int:
    map_score.check_tolerance(args.tolerance, "command line", "--tolerance")
    if args.rerun:
        rerun_view.check_out(args.rerun)
    names = tuple(n.strip() for n in args.metrics.split(",") if n.strip())
    try:
        names = metrics.resolve(names)
    except InputError as err:  # raised as the config's field: here it came from the command line
        raise InputError("command line", "--metrics", err.problem) from None
    if not specs.plain_name(args.name):  # the tables' policy column: `rosmeery plot` makes file names of it
        raise InputError("command line", "--name", f"{args.name!r} is not a plain name (no folders, no leading dot)")
    tasks.check_attempts(args.task_attempts, "command line", "--task-attempts")
    out = require_new(args.out)  # a session's or an earlier evaluation's tables are never replaced
    world = load_world(args.world)
    eps = episodes.read(args.episodes, world) if args.episodes else None
    if args.bag:  # a ROS mapper's PointCloud2 maps, each at its stamp (apps.ros_bags)
        maps = ros_bags.read_maps(Path(args.bag), args.topic, args.labels_topic, world.name, world.taxonomy)
    else:  # every map is read and checked before any write
        maps = [map_score.read_map(p, world.taxonomy) for p in args.map]
    maps, frame = to_world(world, maps, args.transform, args.align)
    if frame and frame["source"] == "icp":
        print(f"aligned by point-to-plane ICP: residual {1000 * frame['rms_m']:.1f} mm over "
              f"{100 * frame['inliers']:.0f}% of points, {frame['iterations']} iterations")
    metric_df, objects, classes, summary = map_score.evaluate(world, maps, args.tolerance, args.name, names, eps,
                                                              args.task_attempts)
    if frame:
        summary["alignment"] = frame
    with output_folder(out):
        tables.write_csv(metric_df, out / "metrics.csv")
        tables.write_csv(objects, out / "objects.csv")
        tables.write_csv(classes, out / "classes.csv")
        write_atomic(out / "summary.json", json.dumps(summary, indent=2))
    print(", ".join(f"{k} {summary[k]:.3f}" for k in names) +
          f"; {100 * summary['points_on_no_object']:.1f}% of points on no object; "
          f"{summary['unmatched_instances']} instances matched to no object")
    print(f"results in {out}/ (metrics.csv, objects.csv, classes.csv, summary.json)")
    if args.rerun:
        _logged(rerun_view.view(out, args.rerun, maps=maps), args.rerun)
    return 0


def _cmd_record(args) -> int:
    if args.rerun:
        rerun_view.check_out(args.rerun)
    if args.seed is not None and args.seeds is not None:
        raise InputError("command line", "--seed", "give --seed S (one seed) or --seeds N (seeds 0..N-1), not both")
    seeds = [args.seed] if args.seed is not None else 1 if args.seeds is None else args.seeds
    cfg = RecordConfig(width=args.width, height=args.height, rate_hz=args.rate, format=args.format,
                       depth_encoding=args.depth_encoding, detector=args.detector, noise=args.noise,
                       localisation=args.localisation)
    folders = record(args.world, args.policy, seeds, args.duration, args.out, cfg, resume=args.resume,
                     progress=not args.quiet)
    what = "TUM RGB-D layout, laser, odometry" if cfg.format == "tum" else \
        f"a ROS 2 bag each ({cfg.format}; play one with: ros2 bag play {folders[0] / 'bag'})"
    print(f"recorded {len(folders)} sequence(s) ({what}) in {args.out}/: " + ", ".join(f.name for f in folders))
    if args.rerun:
        _logged(rerun_view.view(Path(args.out) / "session", args.rerun, recording=folders[0]), args.rerun)
    return 0


def _cmd_train(args) -> int:
    from rosmeery_jax.rl import ppo  # gymnax (1-2 s to import) only for the command that trains

    cfg = ppo.load_train_config(args.config)
    out = ppo.train(cfg, args.out, resume=args.resume, progress=not args.quiet)
    print(trained_summary(ppo.read_curve(out), out))
    return 0


def trained_summary(curve: pd.DataFrame, out: Path) -> str:
    """The line a training run ends with, from its curve (a row per update)."""
    last, mean = curve.iloc[-1], curve["return"].tail(10).mean()  # NaN where no episode ended
    returns = f"mean return of the last 10 updates {mean:.3f}" if pd.notna(mean) else \
        "no episode ended in the last 10 updates"
    return (f"trained {int(last['update'])} updates ({int(last['env_steps']):,} env-steps; {returns}) -> "
            f"{out}/policy.msgpack (use it as --policies learned:{out}/policy.msgpack)")


def _cmd_diff(args) -> int:
    for line in digest.compare(args.a, args.b):
        print(line)
    return 0


def _cmd_join(args) -> int:
    out = join(args.parts, args.out)
    session = json.loads((out / "config.json").read_text())["session"]
    first, count = session["first_seed"], session["seeds"]
    print(f"joined {len(args.parts)} folders: seeds {first}-{first + count - 1} -> {out}")
    return 0


def _cmd_plot(args) -> int:
    d = Path(args.dir)
    check_folder(d)
    df = tables.load(d)
    if df.empty:
        raise InputError(str(d / "metrics.csv"), "rows", "none: nothing to plot")
    written = plots.plot_results(df, d / "plots")
    print(f"wrote {len(written)} plots to {d / 'plots'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rosmeery", description="Batched benchmark for robot semantic mapping.")
    sub = parser.add_subparsers(dest="command", required=True)
    d = SessionConfig()  # the help texts state the defaults of the config classes themselves
    _tasks_parser(sub)
    world_commands.add_worlds(sub)
    world_commands.add_world(sub)
    _bench_parser(sub, d)
    _replay_parser(sub, d)
    _run_parser(sub, d)
    _record_parser(sub, d)
    detector_commands.add_detector(sub)
    _teleop_parser(sub, d)
    _evaluate_parser(sub, d)
    _train_parser(sub, d)
    _plot_parser(sub, d)
    p = sub.add_parser("diff", help="where two results folders part: per run and seed, the last chunk they agree "
                       "on and the parts of the state that differ next (docs/paper.md)")
    p.add_argument("a", metavar="DIR_A")
    p.add_argument("b", metavar="DIR_B")
    p.set_defaults(func=_cmd_diff)
    p = sub.add_parser("join", help="join the parts of a sweep split by --first-seed into one results folder, "
                       "as one session of all their seeds would have written it (docs/sessions.md)")
    p.add_argument("parts", nargs="+", metavar="DIR", help="finished sessions of the same settings, seeds following "
                   "each other")
    p.add_argument("--out", required=True, metavar="DIR", help="the joined folder (new or empty)")
    p.set_defaults(func=_cmd_join)
    return parser


def _bench_parser(sub, d: SessionConfig) -> None:
    p = sub.add_parser("bench", help="env-steps/s by batch size, stage breakdown, and the C MuJoCo peer")
    p.add_argument("--world", default="large_office", metavar="NAME_OR_PATH")
    p.add_argument("--batches", type=int_list, default=(1, 16, 64, 256), metavar="B,B,...")
    p.add_argument("--steps", type=int, default=20, help="env-steps per timed chunk")
    p.add_argument("--memory-batch", type=int, default=1024, metavar="B",
                   help="also measure peak memory at this batch in a child process (0: skip)")
    p.add_argument("--session-s", type=float, default=20.0, metavar="S",
                   help="also time a default session of S simulated seconds end to end (0: skip)")
    p.add_argument("--devices", type=int, default=0, metavar="N", help="also time the reference batch split "
                   "over N devices (default 0: one host device per core, the batch split over as "
                   "many as divide it)")
    p.add_argument("--json", action="store_true", help="print one JSON object (progress goes to stderr)")
    p.add_argument("--no-cache", action="store_true", help="do not use the persistent compilation cache")
    p.set_defaults(func=_cmd_bench)


def _replay_parser(sub, d: SessionConfig) -> None:
    p = sub.add_parser("replay", help="score a recorded trajectory (CSV of t, x, y, yaw) without physics")
    p.add_argument("--world", required=True, metavar="NAME_OR_PATH")
    p.add_argument("--poses", required=True, metavar="FILE.csv",
                   help="t, x, y, yaw; or a session's trajectories.csv (with --run)")
    p.add_argument("--run", metavar="POLICY:SEED",
                   help="the run of a session's trajectories.csv to replay (needed when the world has several)")
    p.add_argument("--out", default="out/replay", metavar="DIR")
    p.add_argument("--metrics", metavar="NAME,...", help="active metrics (default: all built-in)")
    p.add_argument("--no-cache", action="store_true", help="do not use the persistent compilation cache")
    p.set_defaults(func=_cmd_replay)


def _run_parser(sub, d: SessionConfig) -> None:
    p = sub.add_parser("run", help="run a benchmark session (worlds x policies x seeds) and write results")
    p.add_argument("--config", metavar="FILE.toml", help="session options (the same names as below)")
    p.add_argument("--worlds", metavar="A,B", help=f"built-in names, MJCF paths or procedural:KIND:A-B (default: "
                   f"{','.join(d.worlds)})")
    p.add_argument("--policies", metavar="P,Q", help=f"default: {','.join(d.policies)}")
    p.add_argument("--seeds", type=int, metavar="N", help=f"runs per world and policy, batched (default {d.seeds})")
    p.add_argument("--first-seed", type=int, metavar="S", help="the runs are seeds S..S+N-1 (default 0): a seed's "
                   "run is the same in any session, so a sweep splits over machines")
    p.add_argument("--duration", type=float, metavar="S", help=f"simulated seconds per run (default {d.duration:g})")
    p.add_argument("--detector", help=f"yolo (the shipped YOLO-v5n), oracle (simulated from ground truth) or off "
                   f"(ground-truth labels of observed objects); default {d.detector}")
    p.add_argument("--conf-threshold", type=float, metavar="C", help=f"drop detections below C (default "
                   f"{d.conf_threshold:g})")
    p.add_argument("--weights", metavar="FILE.pt", help="YOLO-v5 weights for --detector yolo: " + WEIGHTS_HELP)
    p.add_argument("--detector-runtime", choices=runtimes.RUNTIMES, help="where YOLO's network runs (default "
                   f"{d.detector_runtime}; docs/detector.md)")
    p.add_argument("--metrics", metavar="M,N", help=f"active metrics (default: {','.join(d.metrics)})")
    p.add_argument("--mapper", metavar="M,N", help="who builds the scored map: oracle (the built-in knowledge, "
                   "ground-truth association), perceived (detector frames' depth cut to the detected objects), "
                   "fused (voxels and labels fused over frames) and/or your own mapper as "
                   f"FILE.py:Name or package.module:Name (docs/byo.md); default {','.join(d.mappers)}")
    p.add_argument("--out", metavar="DIR", help=f"results folder (default {d.out})")
    p.add_argument("--resume", action="store_true", help="continue an interrupted session in --out")
    p.add_argument("--rerun", metavar="FILE.rrd", help="also write the results as a Rerun recording (the view "
                   "extra; rosmeery view)")
    p.add_argument("--noise", metavar="PRESET", help="sensor and actuation noise: off (default: the exact "
                   "sensors) or realistic (docs/robot.md; each parameter as env noise__NAME in the config)")
    p.add_argument("--localisation", metavar="MODE", help="the robot's pose: told (ground_truth, the default) or its "
                   "own estimate, dead_reckoning or scan_matching (docs/robot.md)")
    p.add_argument("--task", metavar="TASK", help="objectnav: after exploring, each robot drives its world's "
                   "task episodes with each mapper's final map (tasks.csv; docs/tasks.md); default none")
    p.add_argument("--task-episodes", type=int, metavar="N", help="the task metrics' episodes per world (default "
                   f"{d.task_episodes}: its generated set, seed 0; docs/tasks.md)")
    p.add_argument("--task-attempts", type=int, metavar="N", help="map instances a task episode tries at most "
                   f"(default {d.task_attempts})")
    p.add_argument("--cluster", metavar="ADDRESS", help="run each (world, policy) as a Ray task: ray (a new local "
                   "cluster), auto (the running one), ray://HOST:PORT or HOST:PORT (docs/cluster.md; needs the "
                   "[cluster] extra)")
    p.add_argument("--devices", type=int, metavar="N", help="split each batch over N devices (GPUs, or N host "
                   f"devices made from the CPU's cores); results are the same (default {d.devices}: every device; "
                   "on a CPU one host device per core, less one for torch with --detector yolo; at most one "
                   "per block)")
    p.add_argument("--chunk-s", type=float, metavar="S", help="simulated seconds per jitted call without a "
                   f"detector (progress granularity only; default {d.chunk_s:g})")
    p.add_argument("--detector-period-s", type=float, metavar="S", help="labels from one period's frames reach "
                   f"the robot at the start of the period after next (default {d.detector_period_s:g})")
    p.add_argument("--digest", action="store_true", help="write a digest of each robot's state per chunk "
                   "(runs/*.digest.csv) for `rosmeery diff`; slower")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-cache", action="store_true", help="do not use the persistent compilation cache")
    p.set_defaults(func=_cmd_run)


def _record_parser(sub, d: SessionConfig) -> None:
    p = sub.add_parser("record", help="drive the robot with a policy and write what it saw: TUM RGB-D, laser, "
                       "odometry (docs/record.md)")
    p.add_argument("--world", required=True, metavar="NAME_OR_PATH")
    p.add_argument("--policy", default="frontier", metavar="P", help="default: frontier")
    p.add_argument("--seeds", type=int, metavar="N", help="record seeds 0..N-1, batched (default 1)")
    p.add_argument("--seed", type=int, metavar="S", help="record seed S only (instead of --seeds)")
    p.add_argument("--duration", type=float, default=60.0, metavar="S", help="simulated seconds (default 60)")
    rec = RecordConfig()
    p.add_argument("--width", type=int, default=rec.width, help=f"image width in pixels (default {rec.width})")
    p.add_argument("--height", type=int, default=rec.height, help=f"image height in pixels (default {rec.height})")
    p.add_argument("--rate", type=float, default=rec.rate_hz, metavar="HZ", help="RGB-D frames per simulated second "
                   f"(a divisor of the control rate; default {rec.rate_hz:g}); laser, odometry and poses are written "
                   "every control step")
    p.add_argument("--format", default=rec.format, choices=("tum", "mcap", "sqlite3"),
                   help="tum (default): TUM RGB-D folders and text files; mcap or sqlite3: a ROS 2 bag per seed "
                        "(the ros extra; docs/record.md)")
    p.add_argument("--depth-encoding", default=rec.depth_encoding, choices=("32FC1", "16UC1"),
                   help="a bag's depth images: 32FC1 metres (default) or 16UC1 millimetres")
    p.add_argument("--detector", default=rec.detector, choices=("off", "oracle", "yolo"),
                   help="a bag's /detections topic: off (default), oracle or yolo (the session's detectors)")
    p.add_argument("--out", required=True, metavar="DIR")
    p.add_argument("--rerun", metavar="FILE.rrd", help="also write the run, with the first seed's camera frames, as a "
                   "Rerun recording (the view extra)")
    p.add_argument("--noise", default=rec.noise, metavar="PRESET", help="sensor and actuation noise: off (default) "
                   "or realistic (docs/robot.md): the robot drives with it, and the images and laser written carry "
                   "it; the ground truth stays true")
    p.add_argument("--localisation", default=rec.localisation, metavar="MODE",
                   help="the odometry written: the true pose (ground_truth, default) or the robot's own estimate, "
                   "dead_reckoning or scan_matching (docs/robot.md)")
    p.add_argument("--resume", action="store_true", help="record only the seeds missing in --out")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_record)


def _teleop_parser(sub, d: SessionConfig) -> None:
    p = sub.add_parser("teleop", help="drive the robot from a local web page; the session is recorded")
    p.add_argument("--world", required=True, metavar="NAME_OR_PATH")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default: loopback only)")
    p.add_argument("--port", type=int, default=8765)
    p.add_argument("--record", metavar="FILE.jsonl", help="default: recordings/<world>-<time>.jsonl")
    p.add_argument("--detector", default="yolo", choices=("yolo", "oracle", "off"))
    p.add_argument("--conf-threshold", type=float, default=d.conf_threshold, metavar="C")
    p.add_argument("--weights", metavar="FILE.pt", help=WEIGHTS_HELP)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--view", default="blind", choices=("blind", "full"),
                   help="blind (default): only the map and the camera, as the paper's human saw; "
                        "full: also live scores and held labels (not a paper baseline)")
    p.add_argument("--no-cache", action="store_true", help="do not use the persistent compilation cache")
    p.set_defaults(func=_cmd_teleop)


def _evaluate_parser(sub, d: SessionConfig) -> None:
    p = sub.add_parser("evaluate", help="score your own semantic map(s) (PLY + JSON) against a world's ground truth")
    p.add_argument("--world", required=True, metavar="NAME_OR_PATH")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--map", nargs="+", metavar="MAP.ply", help="one or more maps of one run "
                        "(with MAP.json beside each: frame, labels; several maps with times give curves)")
    source.add_argument("--bag", metavar="DIR", help="a ROS 2 bag whose --topic holds the maps (sensor_msgs/"
                        "PointCloud2 with an instance field; the ros extra; docs/evaluate.md)")
    p.add_argument("--topic", default="/semantic_map", help="the bag's map topic (default /semantic_map)")
    p.add_argument("--labels-topic", metavar="TOPIC", help="a std_msgs/String topic of JSON instance labels "
                   "({\"objects\": [{\"id\", \"label\", \"confidence\"}]})")
    p.add_argument("--out", default="out/evaluate", metavar="DIR")
    p.add_argument("--tolerance", type=float, default=map_score.TOLERANCE, metavar="M",
                   help=f"a point within M metres of a surface sample lies on it (default {map_score.TOLERANCE:g})")
    p.add_argument("--name", default="external", help="the policy column of the tables (default external)")
    p.add_argument("--rerun", metavar="FILE.rrd", help="also write the maps and curves as a Rerun recording "
                   "(the view extra)")
    p.add_argument("--metrics", metavar="M,N", default=",".join(d.metrics),
                   help=f"metrics to score (default: {','.join(d.metrics)}; field: every field map metric, "
                        "docs/metrics.md; task: the map-use metrics, docs/tasks.md)")
    p.add_argument("--episodes", metavar="FILE.json", help="the object-goal episodes the task metrics put the maps "
                   "to (default: the world's generated set of 50, seed 0; rosmeery tasks writes one; docs/tasks.md)")
    p.add_argument("--task-attempts", type=int, default=tasks.ATTEMPTS, metavar="N",
                   help=f"instances a task query tries before it gives up (default {tasks.ATTEMPTS})")
    frame = p.add_mutually_exclusive_group()
    frame.add_argument("--align", action="store_true", help="align the maps to the world first (point-to-plane ICP)")
    frame.add_argument("--transform", metavar="FILE", help="a 4 x 4 map-to-world transform (JSON or text) to apply first")
    p.set_defaults(func=_cmd_evaluate)


def _tasks_parser(sub) -> None:
    p = sub.add_parser("tasks", help="write a world's object-goal episodes (the task metrics' queries; docs/tasks.md)")
    p.add_argument("--world", required=True, metavar="NAME_OR_PATH")
    p.add_argument("--episodes", type=int, default=episodes.DEFAULT_EPISODES, metavar="N",
                   help=f"how many (default {episodes.DEFAULT_EPISODES})")
    p.add_argument("--seed", type=int, default=episodes.DEFAULT_SEED, help="default 0: the set evaluate uses")
    p.add_argument("--out", metavar="FILE.json", help="default tasks/<world>_<seed>.json")
    p.set_defaults(func=_cmd_tasks)


def _cmd_tasks(args) -> int:
    episodes.check_count(args.episodes, "command line", "--episodes")
    world = load_world(args.world)
    out = Path(args.out or f"tasks/{world.name}_{args.seed}.json")
    if out.exists():
        raise InputError(str(out), "--out", "exists: an episode set is never replaced; choose another name")
    made = episodes.generate(world, args.episodes, args.seed)
    out.parent.mkdir(parents=True, exist_ok=True)
    episodes.write(out, world, made, args.seed)
    goals = sorted({e.goal for e in made})
    d = [e.geodesic_distance for e in made]
    print(f"{len(made)} episodes of {world.name} (seed {args.seed}; {len(goals)} goal categories; geodesic distance "
          f"{min(d):.1f}-{max(d):.1f} m, median {float(np.median(d)):.1f}) -> {out}")
    return 0


def _train_parser(sub, d: SessionConfig) -> None:
    p = sub.add_parser("train", help="train the learned explorer with PPO (flax + optax) on a world bank")
    p.add_argument("--config", metavar="FILE.toml", help="training options (default: the built-in defaults; "
                   "experiments/learned/ppo.toml trains the shipped policy)")
    p.add_argument("--out", default="results/train", metavar="DIR", help="checkpoints, curve.csv, curve.png and "
                   "policy.msgpack (default results/train)")
    p.add_argument("--resume", action="store_true", help="continue from the checkpoint in --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-cache", action="store_true", help="do not use the persistent compilation cache")
    p.set_defaults(func=_cmd_train)


def _plot_parser(sub, d: SessionConfig) -> None:
    p = sub.add_parser("plot", help="redraw the plots of a results folder")
    p.add_argument("dir", metavar="DIR")
    p.set_defaults(func=_cmd_plot)
    p = sub.add_parser("view", help="write a results folder as a Rerun recording: worlds, paths, maps, curves "
                       "(the view extra; docs/sessions.md)")
    p.add_argument("dir", metavar="DIR")
    p.add_argument("--out", metavar="FILE.rrd", help="default DIR/session.rrd")
    p.add_argument("--worlds", metavar="A,B", help="only these worlds")
    p.add_argument("--policies", metavar="P,Q", help="only these policies")
    p.add_argument("--seeds", metavar="S,T", help="only these seeds")
    p.add_argument("--max-points", type=int, default=rerun_view.MAX_POINTS, metavar="N",
                   help=f"thin every map to N points (default {rerun_view.MAX_POINTS:,})")
    p.set_defaults(func=_cmd_view)


RESUMABLE = " (finished runs are kept: the same command with --resume continues)"


def _stdout_to_devnull() -> None:
    """Point the closed standard output at /dev/null, so Python's last flush fails no more."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # not a real file (a captured stream)
        pass


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if hasattr(args, "no_cache"):
            compilation_cache(not args.no_cache)
        return args.func(args)
    except InputError as err:
        print(f"rosmeery: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("rosmeery: interrupted" + (RESUMABLE if args.command == "run" else ""), file=sys.stderr)
        return 130
    except BrokenPipeError:  # the program reading the output left (`| head`): no write failed of ours
        _stdout_to_devnull()
        print("rosmeery: stopped: the program reading its output closed it" + (RESUMABLE if args.command == "run"
                                                                              else ""), file=sys.stderr)
        return 1
    except OSError as err:  # a full disk, a folder that cannot be written: atomic writes left no part file
        where = err.filename or "a file"
        print(f"rosmeery: error: {where}: cannot write ({err.strerror or err})", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
