"""A session's results as a Rerun recording (``rosmeery view RESULTS_DIR``; docs/sessions.md).

One timeline, ``sim_time`` (simulated seconds). Per world, static: its objects' boxes
(labelled, coloured by category through an annotation context) and its ground-truth
surface samples. Per run (world, policy, seed): the robot's path and its pose over time,
its exported semantic maps (the built-in knowledge's and each mapper's, at the run's end:
points coloured by category, instance ids as labels of their boxes) and every metric curve
of ``metrics.csv`` as a time series. Which runs are logged is chosen by world, policy and
seed; every map is thinned to at most ``max_points`` points, so the size stays bounded.

Entity paths: ``world/<world>/objects``, ``world/<world>/samples``,
``world/<world>/<policy>/seed<k>/path|robot|map/<mapper>|camera``,
``metrics/<metric>/<world>/<policy>/<mapper>/seed<k>``.

The recording carries its default blueprint (``rerun.blueprint``): a large 3D view of the
worlds, maps and paths beside one time-series panel per metric holding every world,
policy, mapper and seed, each over the whole run.
"""

from __future__ import annotations

import tempfile
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
MAX_TIME_S = 1e9  # s: a recording's times (Rerun's timeline counts nanoseconds in int64: about 9.2e9 s)
MAX_COORDINATE = 1e6  # m: a path's positions (float32 in Rerun; a world is metres across)


def rerun():
    try:
        import rerun as rr  # noqa: PLC0415 (the optional view extra)
    except ImportError:
        raise InputError("rerun-sdk", "import", HINT) from None
    return rr


def check_out(out: str | Path, where: str = "--rerun") -> None:
    """Before any work: rerun-sdk importable, ``out`` a .rrd file name that is not there yet
    (a recording is never replaced), in a folder that exists and takes a new file."""
    rerun()
    out = Path(out)
    if out.suffix != ".rrd":
        raise InputError("command line", where, f"{out} must end in .rrd")
    if out.is_dir():
        raise InputError(str(out), where, "is a folder: name a new .rrd file")
    if out.exists() or out.is_symlink():
        raise InputError(str(out), where, "exists: a recording is never replaced; choose another name")
    folder = out.parent
    if not folder.is_dir():
        raise InputError(str(out), where, f"its folder {folder} does not exist")
    try:  # a file made and removed: the one test of writing that holds for root and read-only mounts alike
        tempfile.TemporaryFile(dir=folder).close()
    except OSError as err:
        raise InputError(str(out), where, f"its folder {folder} takes no new file ({err.strerror})") from None


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
    _within(df, folder / "metrics.csv", "time_s", MAX_TIME_S)
    for key, wanted in (("world", worlds), ("policy", policies), ("seed", seeds)):
        if wanted:
            missing = [w for w in wanted if w not in set(df[key])]
            if missing:
                raise InputError(folder / "metrics.csv", key, f"no {missing[0]!r} rows (it has "
                                 f"{', '.join(map(str, sorted(set(df[key]))))})")
            df = df[df[key].isin(wanted)]
    check_out(out, "--out")
    rec = rr.RecordingStream("rosmeery")
    rec.save(out, default_blueprint=blueprint(sorted(set(df.metric))))
    traj = _trajectories(folder)
    logged = {"worlds": 0, "runs": 0, "maps": 0, "curves": 0, "frames": 0}
    try:
        for world_name, part in df.groupby("world"):
            world = _world_of(folder, world_name)
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


def blueprint(metrics: list[str]):
    """The layout a recording opens with: the 3D world with its maps and the robots' paths
    (three fifths of the width), and one time-series panel per metric, every curve in it,
    over the whole run (not the last seconds)."""
    import rerun.blueprint as rrb  # noqa: PLC0415 (with rerun, found above)

    whole = rrb.VisibleTimeRange(TIMELINE, start=rrb.TimeRangeBoundary.infinite(),
                                 end=rrb.TimeRangeBoundary.infinite())
    axis = rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                 end=rrb.TimeRangeBoundary.infinite()))  # drawn: the whole run
    panels = [rrb.TimeSeriesView(origin=f"metrics/{m}", name=m, time_ranges=[whole], axis_x=axis) for m in metrics]
    return rrb.Blueprint(rrb.Horizontal(rrb.Spatial3DView(origin="world", name="worlds, maps and paths",
                                                          time_ranges=[whole]),
                                        rrb.Vertical(*panels), column_shares=[3, 2]),
                         collapse_panels=True)


def _trajectories(folder: Path) -> pd.DataFrame | None:
    """The folder's paths, their numbers checked (one InputError naming the file, row and column)."""
    path = folder / "trajectories.csv"
    if not path.exists():
        return None
    df = tables.read_table(path, ["world", "policy", "seed", "time_s", "x", "y", "yaw"])
    for c in ("seed", "time_s", "x", "y", "yaw"):
        df[c] = tables.numbers(df, path, c, seeds=c == "seed")
    for c, most in (("time_s", MAX_TIME_S), ("x", MAX_COORDINATE), ("y", MAX_COORDINATE)):
        _within(df, path, c, most)
    return df


def _within(df: pd.DataFrame, path: Path, column: str, most: float) -> None:
    """Every value of ``column`` in [-most, most] (times: [0, most]), or one InputError naming
    the row: Rerun keeps times in nanoseconds and positions in float32, and beyond these it
    drops what it cannot hold with a warning only."""
    low = 0.0 if column == "time_s" else -most
    bad = np.flatnonzero((df[column] < low) | (df[column] > most))
    if len(bad):
        raise InputError(str(path), f"row {bad[0] + 2}, column {column}", f"{df[column].iloc[bad[0]]} is outside "
                         f"[{low:g}, {most:g}]")


def _world_of(folder: Path, name: str):
    """The world a results table names, or one InputError naming the table."""
    try:
        return load_world(name)
    except InputError as err:
        raise InputError(folder / "metrics.csv", "world", f"{name!r}: {err.problem}") from None


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
    """A recorded sequence's camera (pinhole at its ground-truth pose) with its colour and
    depth images (a TUM folder's or a bag's), at most ``most`` frames evenly spread."""
    import json  # noqa: PLC0415

    import cv2  # noqa: PLC0415

    cam = json.loads((seq / "camera.json").read_text())
    if (seq / "rgb.txt").exists():
        rows = [line.split() for line in (seq / "groundtruth.txt").read_text().splitlines()
                if not line.startswith("#")]
        poses = {r[0]: np.array(r[1:], float) for r in rows}
        frames = [line.split() for line in (seq / "rgb.txt").read_text().splitlines() if not line.startswith("#")]
        frames = [(float(stamp), poses[stamp], lambda n=name: cv2.imread(str(seq / n))[..., ::-1],
                   lambda s=stamp: cv2.imread(str(seq / "depth" / f"{s}.png"), cv2.IMREAD_UNCHANGED) /
                   cam["depth_scale"]) for stamp, name in frames]
    else:  # a bag recording: its images and its ground truth from the bag
        frames = _bag_frames(seq / "bag", cam, most)
    frames = [frames[i] for i in _thin(len(frames), most)]
    k = [[cam["fx"], 0, cam["cx"]], [0, cam["fy"], cam["cy"]], [0, 0, 1]]
    rec.log(f"{base}/camera", rr.Pinhole(image_from_camera=k, resolution=[cam["width"], cam["height"]]), static=True)
    for t, p, rgb, depth in frames:
        rec.set_time(TIMELINE, duration=t)
        rec.log(f"{base}/camera", rr.Transform3D(translation=p[:3], quaternion=p[3:]))
        rec.log(f"{base}/camera/rgb", rr.Image(rgb()))
        rec.log(f"{base}/camera/depth", rr.DepthImage(np.nan_to_num(depth()).astype(np.float32), meter=1.0))
    return len(frames)


def _bag_frames(bag: Path, cam: dict, most: int) -> list:
    """[(time, optical pose (7,), rgb (), depth ())] of at most ``most`` of a recorded bag's
    colour frames, evenly spread: its images, and its ground truth (``/ground_truth/odom``)
    carried to the optical frame by the mounting ``camera.json`` gives."""
    from dataclasses import replace  # noqa: PLC0415

    from rosmeery_jax.apps import ros_bags  # noqa: PLC0415 (the ros extra, only for a bag)
    from rosmeery_jax.apps.sensor_streams import optical_poses  # noqa: PLC0415
    from rosmeery_jax.raycast.sensors import CameraConfig  # noqa: PLC0415

    rosbag2, _ = ros_bags.rosbags()
    store = ros_bags.typestore()
    mount = cam["base_to_camera"]
    camera = replace(CameraConfig(), mount_x=mount["x"], mount_height=mount["z"], pitch=mount["pitch_rad"])
    topics = ("/camera/color/image_raw", "/camera/depth/image_raw", "/ground_truth/odom")
    with rosbag2.Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        count = sum(c.msgcount for c in conns if c.topic == topics[0])
        keep = set(_thin(count, most).tolist())
        seen, images, poses = -1, {}, {}
        for conn, ns, raw in reader.messages(connections=conns):
            if conn.topic == topics[0]:
                seen += 1
            if conn.topic == topics[2]:
                m = store.deserialize_cdr(raw, conn.msgtype).pose.pose
                q = m.orientation
                poses[ns] = (m.position.x, m.position.y, 2 * np.arctan2(q.z, q.w))
            elif seen in keep:
                images.setdefault(ns, {})[conn.topic] = store.deserialize_cdr(raw, conn.msgtype)
    out = []
    for ns, msgs in sorted(images.items()):
        if len(msgs) < 2 or ns not in poses:
            continue
        rgb, depth = msgs[topics[0]], msgs[topics[1]]
        pose = optical_poses(camera, np.asarray([poses[ns]], np.float32))[0]
        shape = (rgb.height, rgb.width)
        d = np.frombuffer(depth.data.tobytes(), "<f4" if depth.encoding == "32FC1" else "<u2").reshape(shape)
        scale = 1.0 if depth.encoding == "32FC1" else 1e-3
        out.append((ns * 1e-9, pose, lambda m=rgb, s=shape: np.frombuffer(m.data.tobytes(), np.uint8).reshape(*s, 3),
                    lambda d=d, k=scale: d.astype(np.float32) * k))
    return out


def _curves(rr, rec, run: pd.DataFrame, world: str, policy: str, seed: int) -> int:
    """Every metric curve of one run as a time series; returns how many."""
    count = 0
    for (mapper, metric), c in run.groupby(["mapper", "metric"]):
        c = c.sort_values("time_s")
        rec.send_columns(f"metrics/{metric}/{world}/{policy}/{mapper}/seed{seed}",
                         indexes=[rr.TimeColumn(TIMELINE, duration=c.time_s.to_numpy())],
                         columns=rr.Scalars.columns(scalars=c.value.to_numpy(np.float64)))
        count += 1
    return count
