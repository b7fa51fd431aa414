"""A session's results as a Rerun recording (``rosmeery view RESULTS_DIR``; docs/sessions.md).

One timeline, ``sim_time`` (simulated seconds). Per world, static: its objects' boxes
(labelled, coloured by category through an annotation context) and its ground-truth
surface samples. Per run (world, policy, seed): the robot's path and its pose over time,
its exported semantic maps (the built-in knowledge's and each mapper's, at the run's end:
points coloured by category, instance ids as labels of their boxes) and every metric curve
of ``metrics.csv`` as a time series. Which runs are logged is chosen by world, policy and
seed; every map is thinned to at most ``max_points`` points, so the size stays bounded.

Entity paths: ``world/<world>/objects``, ``world/<world>/samples``,
``world/<world>/<policy>/seed<k>/path|robot|map/<mapper>``,
``metrics/<world>/<policy>/<mapper>/<metric>/seed<k>``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.metrics.map_score import read_map
from rosmeery_jax.results import tables
from rosmeery_jax.world import load_world

HINT = "rerun-sdk is missing: pip install 'rosmeery-jax[view]' (or pip install rerun-sdk)"
TIMELINE = "sim_time"
MAX_POINTS = 50_000  # per map and per world's samples


def rerun():
    try:
        import rerun as rr  # noqa: PLC0415 (the optional view extra)
    except ImportError:
        raise InputError("rerun-sdk", "import", HINT) from None
    return rr


def check_out(out: str | Path, where: str = "--rerun") -> None:
    """Before any work: rerun-sdk importable and ``out`` a .rrd file name."""
    rerun()
    if Path(out).suffix != ".rrd":
        raise InputError("command line", where, f"{out} must end in .rrd")


def view(folder: str | Path, out: str | Path, worlds=None, policies=None, seeds=None,
         max_points: int = MAX_POINTS, maps: list | None = None, recording: Path | None = None) -> dict:
    """Write ``folder``'s runs (those of ``worlds``, ``policies``, ``seeds`` when given) to the
    Rerun recording ``out`` (.rrd); returns what was logged: worlds, runs, maps, curves,
    frames. ``maps``: SemanticMaps of its one run logged at their times instead of the
    folder's exported maps (an evaluation's); ``recording``: a TUM sequence folder of
    ``rosmeery record`` whose camera poses, colour and depth images are logged too."""
    rr = rerun()
    folder, out = Path(folder), Path(out)
    df = tables.load(folder)
    for key, wanted in (("world", worlds), ("policy", policies), ("seed", seeds)):
        if wanted:
            missing = [w for w in wanted if w not in set(df[key])]
            if missing:
                raise InputError(folder / "metrics.csv", key, f"no {missing[0]!r} rows (it has "
                                 f"{', '.join(map(str, sorted(set(df[key]))))})")
            df = df[df[key].isin(wanted)]
    check_out(out, "--out")
    rec = rr.RecordingStream("rosmeery")
    rec.save(out)
    traj = _trajectories(folder)
    logged = {"worlds": 0, "runs": 0, "maps": 0, "curves": 0, "frames": 0}
    try:
        for world_name, part in df.groupby("world"):
            world = load_world(world_name)
            _world(rr, rec, world, max_points)
            logged["worlds"] += 1
            for (policy, seed), run in part.groupby(["policy", "seed"]):
                base = f"world/{world.name}/{policy}/seed{seed}"
                if traj is not None:
                    _path(rr, rec, base, traj[(traj.world == world.name) & (traj.policy == policy)
                                              & (traj.seed == seed)])
                if maps is not None:
                    logged["maps"] += _given_maps(rr, rec, world, base, maps, max_points)
                else:
                    logged["maps"] += _maps(rr, rec, folder, world, base, policy, seed, float(run.time_s.max()),
                                            max_points)
                if recording is not None and seed == int(recording.name.removeprefix("seed")):
                    logged["frames"] += _frames(rr, rec, recording, base)
                logged["curves"] += _curves(rr, rec, run, world.name, policy, seed)
                logged["runs"] += 1
    finally:
        rec.flush()
        del rec
    return {**logged, "bytes": out.stat().st_size}


def _trajectories(folder: Path) -> pd.DataFrame | None:
    path = folder / "trajectories.csv"
    return tables.read_table(path, ["world", "policy", "seed", "time_s", "x", "y", "yaw"]) if path.exists() else None


def _world(rr, rec, world, max_points: int) -> None:
    """Static: the objects' boxes and the surface samples, coloured by category."""
    t, names = world.truth, world.taxonomy.names
    colors = (np.asarray([[int(255 * c) for c in _color(k)] for k in range(len(names))], np.uint8))
    rec.log(f"world/{world.name}", rr.AnnotationContext([(k, n, tuple(colors[k])) for k, n in enumerate(names)]),
            static=True)
    quats = Rotation.from_euler("z", np.asarray(t.bbox_yaw, np.float64)[:, None]).as_quat()
    rec.log(f"world/{world.name}/objects", rr.Boxes3D(centers=np.asarray(t.bbox_center), half_sizes=np.asarray(
        t.bbox_size) / 2, quaternions=quats, labels=list(t.names), class_ids=np.asarray(t.category_index)),
        static=True)
    pts = np.asarray(t.samples.points)
    keep = _thin(len(pts), max_points)
    rec.log(f"world/{world.name}/samples", rr.Points3D(pts[keep], class_ids=np.asarray(t.category_index)[
        np.asarray(t.samples.object)[keep]], radii=0.01), static=True)


def _color(k: int) -> tuple:
    import colorsys  # noqa: PLC0415

    return colorsys.hsv_to_rgb((k * 0.618034) % 1.0, 0.65, 0.95)


def _thin(n: int, most: int) -> np.ndarray:
    """Indices of at most ``most`` of ``n`` items, evenly spread (deterministic)."""
    return np.arange(n) if n <= most else np.linspace(0, n - 1, most).astype(int)


def _path(rr, rec, base: str, run: pd.DataFrame) -> None:
    """The robot's path (static) and its pose over time."""
    if run.empty:
        return
    run = run.sort_values("time_s")
    xyz = np.c_[run.x, run.y, np.full(len(run), 0.05)]
    rec.log(f"{base}/path", rr.LineStrips3D([xyz]), static=True)
    rec.send_columns(f"{base}/robot", indexes=[rr.TimeColumn(TIMELINE, duration=run.time_s.to_numpy())],
                     columns=rr.Points3D.columns(positions=xyz))


def _maps(rr, rec, folder: Path, world, base: str, policy: str, seed: int, end_s: float, max_points: int) -> int:
    """The run's exported maps at its end time; returns how many."""
    stem = f"{world.name}__{policy}__seed{seed}"
    count = 0
    for ply in sorted((folder / "maps").glob(f"{stem}*.ply")):
        mapper = ply.stem[len(stem) + 2:] or "oracle"
        m = read_map(ply, world.taxonomy)
        keep = _thin(len(m.points), max_points)
        label = np.array([world.taxonomy.index(m.labels[i]) if m.labels.get(i) else -1 for i in m.instance[keep]])
        rec.set_time(TIMELINE, duration=end_s)
        rec.log(f"{base}/map/{mapper}", rr.Points3D(m.points[keep], class_ids=np.maximum(label, 0), radii=0.012,
                                                     labels=None))
        count += 1
    return count


def _given_maps(rr, rec, world, base: str, maps: list, max_points: int) -> int:
    """Maps (SemanticMap) at their times, in order: the map over time."""
    for k, m in enumerate(maps):
        keep = _thin(len(m.points), max_points)
        label = np.array([world.taxonomy.index(m.labels[i]) if m.labels.get(i) else -1 for i in m.instance[keep]])
        rec.set_time(TIMELINE, duration=float(m.time_s if m.time_s is not None else k))
        rec.log(f"{base}/map/own", rr.Points3D(m.points[keep], class_ids=np.maximum(label, 0), radii=0.012))
    return len(maps)


def _frames(rr, rec, seq: Path, base: str, most: int = 300) -> int:
    """A TUM sequence's camera (pinhole at its ground-truth pose) with its colour and depth
    images, at most ``most`` frames evenly spread."""
    import json  # noqa: PLC0415

    import cv2  # noqa: PLC0415

    cam = json.loads((seq / "camera.json").read_text())
    if not (seq / "rgb.txt").exists():
        return 0  # a bag recording: its frames are in the bag
    rows = [line.split() for line in (seq / "groundtruth.txt").read_text().splitlines() if not line.startswith("#")]
    poses = {r[0]: np.array(r[1:], float) for r in rows}
    frames = [line.split() for line in (seq / "rgb.txt").read_text().splitlines() if not line.startswith("#")]
    frames = [frames[i] for i in _thin(len(frames), most)]
    k = [[cam["fx"], 0, cam["cx"]], [0, cam["fy"], cam["cy"]], [0, 0, 1]]
    rec.log(f"{base}/camera", rr.Pinhole(image_from_camera=k, resolution=[cam["width"], cam["height"]]), static=True)
    for stamp, name in frames:
        rec.set_time(TIMELINE, duration=float(stamp))
        p = poses[stamp]
        rec.log(f"{base}/camera", rr.Transform3D(translation=p[:3], quaternion=p[3:]))
        rec.log(f"{base}/camera/rgb", rr.Image(cv2.imread(str(seq / name))[..., ::-1]))
        depth = cv2.imread(str(seq / "depth" / f"{stamp}.png"), cv2.IMREAD_UNCHANGED)
        rec.log(f"{base}/camera/depth", rr.DepthImage(depth, meter=cam["depth_scale"]))
    return len(frames)


def _curves(rr, rec, run: pd.DataFrame, world: str, policy: str, seed: int) -> int:
    """Every metric curve of one run as a time series; returns how many."""
    count = 0
    for (mapper, metric), c in run.groupby(["mapper", "metric"]):
        c = c.sort_values("time_s")
        rec.send_columns(f"metrics/{world}/{policy}/{mapper}/{metric}/seed{seed}",
                         indexes=[rr.TimeColumn(TIMELINE, duration=c.time_s.to_numpy())],
                         columns=rr.Scalars.columns(scalars=c.value.to_numpy(np.float64)))
        count += 1
    return count
