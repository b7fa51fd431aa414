"""Sensor streams out: what the robot saw, in the layout external mappers already read.

``record(world, policy, seeds, duration, out)`` drives the robot with a policy (a session
with the detector off, all seeds in one batch) and writes, per seed, a TUM RGB-D sequence
plus the laser and odometry (docs/record.md has every convention)::

    OUT/seed<k>/rgb/<t>.png          8-bit colour, width x height
    OUT/seed<k>/depth/<t>.png        16-bit depth along the optical axis, 5000 per metre, 0 = none
    OUT/seed<k>/seg/<t>.png          16-bit ground-truth instance id + 1 (0: wall, floor, nothing),
                                     for checking a mapper, not for feeding it
    OUT/seed<k>/rgb.txt, depth.txt, seg.txt   "timestamp filename" per frame
    OUT/seed<k>/groundtruth.txt      "timestamp tx ty tz qx qy qz qw": the camera's optical
                                     frame (x right, y down, z forward) in the world, every step
    OUT/seed<k>/camera.json          pinhole intrinsics, depth scale, the camera on the robot
    OUT/seed<k>/scan.txt             "timestamp r_0 ... r_K-1" laser ranges (m), every step
    OUT/seed<k>/odometry.txt         "timestamp x y yaw v w" base pose and velocities, every step
    OUT/seed<k>/objects.json         seg ids -> object name and category
    OUT/session/                     the session that drove the robot (its own scores)
    OUT/record.json                  the settings every seed was recorded with (a resume keeps them)

With ``RecordConfig.format`` "mcap" or "sqlite3" a seed is a ROS 2 bag instead
(``OUT/seed<k>/bag/``, :mod:`rosmeery_jax.apps.ros_bags`), beside its camera.json,
objects.json and info.json.

Timestamps are simulated seconds from the start. Each seed's folder is written under a
temporary name and renamed when complete, so a folder that exists is whole, and
``resume=True`` records only the seeds still missing.
"""

from __future__ import annotations

import json
import shutil
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from rosmeery_jax.apps.ros_bags import FORMATS, BagStreams, rosbags
from rosmeery_jax.core import xla
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import require_same, write_atomic
from rosmeery_jax.detector.detections import DETECTORS, make_detector
from rosmeery_jax.env import make
from rosmeery_jax.raycast.sensors import CameraConfig, laser, laser_dirs, rgbd
from rosmeery_jax.session import Session, SessionConfig
from rosmeery_jax.session.batch import run_overrides
from rosmeery_jax.session.schedule import control_dt
from rosmeery_jax.sim import localisation, noise
from rosmeery_jax.world import load_world

DEPTH_SCALE = 5000.0  # TUM RGB-D: a 16-bit depth value of 5000 is one metre
FRAME_BATCH = 8  # frames rendered per jitted call (bounds the memory of a 640 x 480 cast)


@dataclass(frozen=True)
class RecordConfig:
    width: int = 640
    height: int = 480
    rate_hz: float = 5.0  # RGB-D frames per simulated second (a divisor of the 10 Hz control rate)
    decide_every: int = 10
    format: str = "tum"  # tum (folders of PNG and text), or a ROS 2 bag: mcap, sqlite3 (apps.ros_bags)
    depth_encoding: str = "32FC1"  # a bag's depth images: 32FC1 metres, or 16UC1 millimetres
    detector: str = "off"  # a bag's /detections: off, oracle or yolo (the session's detectors)
    noise: str = "off"  # sensor and actuation noise preset (sim.noise): the run and the streams written
    localisation: str = "ground_truth"  # odometry: the true pose, or the robot's own estimate (sim.localisation)

    def stride(self, dt: float) -> int:
        """Control steps between frames."""
        return int(round(1.0 / (self.rate_hz * dt)))


def check(cfg: RecordConfig, out: Path, resume: bool, dt: float) -> None:
    """Every check on the recorder's own options before anything is written (``dt``: the
    control period)."""
    for name in ("width", "height"):
        if not 16 <= getattr(cfg, name) <= 4096:
            raise InputError("command line", f"--{name}", f"{getattr(cfg, name)!r} must be a whole number of "
                             "pixels in [16, 4096]")
    stride = 1.0 / (cfg.rate_hz * dt) if cfg.rate_hz > 0 else 0.0
    if not (cfg.rate_hz > 0 and abs(stride - round(stride)) < 1e-9 and stride >= 1):
        raise InputError("command line", "--rate", f"{cfg.rate_hz!r} Hz must divide the {1 / dt:g} Hz control rate "
                         "(10, 5, 2, 1, 0.5, ...)")
    noise.preset(cfg.noise, "command line", "--noise")
    if cfg.localisation not in localisation.MODES:
        raise InputError("command line", "--localisation", f"{cfg.localisation!r} is not one of "
                         f"{', '.join(localisation.MODES)}")
    if cfg.format not in FORMATS:
        raise InputError("command line", "--format", f"{cfg.format!r} is not one of {', '.join(FORMATS)}")
    if cfg.depth_encoding not in ("32FC1", "16UC1"):
        raise InputError("command line", "--depth-encoding", f"{cfg.depth_encoding!r} is not 32FC1 or 16UC1")
    if cfg.detector not in DETECTORS:
        raise InputError("command line", "--detector", f"{cfg.detector!r} is not one of {', '.join(DETECTORS)}")
    if cfg.format != "tum":
        rosbags()  # the optional package, before anything runs
    elif cfg.depth_encoding != RecordConfig.depth_encoding:
        raise InputError("command line", "--depth-encoding", f"{cfg.depth_encoding} is a bag's encoding: a TUM "
                         "folder's depth is 16-bit PNG at 5000 per metre (--format mcap or sqlite3 for a bag)")
    elif cfg.detector != "off":
        raise InputError("command line", "--detector", "detections are written to ROS 2 bags only (--format mcap "
                         "or sqlite3)")
    if out.exists() and not out.is_dir():
        raise InputError(str(out), "--out", "is a file, not a folder")
    if out.exists() and any(out.iterdir()) and not resume:
        raise InputError(str(out), "--out", "is not empty: pass --resume to finish a recording, or choose another")


def record(world: str, policy: str, seeds: int | list[int], duration: float, out: str | Path,
           cfg: RecordConfig = RecordConfig(), resume: bool = False, progress: bool = True) -> list[Path]:
    """Record the runs of ``policy`` in ``world`` for ``seeds`` (a count: seeds 0..n-1, or a
    list of seeds) into ``out`` (module docstring); returns the seed folders. The smallest
    seed to the largest are simulated in one batch (a seed's run does not depend on its
    batch-mates)."""
    out = Path(out)
    wanted = range(seeds) if isinstance(seeds, int) else sorted(set(seeds))  # a range: not listed before the
    if not wanted or wanted[0] < 0:  # session's memory check
        raise InputError("command line", "--seeds", f"{seeds!r}: name at least one seed, none negative")
    dt = control_dt(SessionConfig())
    check(cfg, out, resume, dt)
    settings = {"world": world, "policy": policy, "duration": duration, **asdict(cfg)}
    _check_settings(out, settings)
    session = SessionConfig(worlds=(world,), policies=(policy,), seeds=wanted[-1] - wanted[0] + 1,
                            first_seed=wanted[0], duration=duration, detector="off", decide_every=cfg.decide_every,
                            sample_s=dt, out=str(out / "session"), noise=cfg.noise,
                            localisation=cfg.localisation)
    session = session.validate("command line")  # a count this machine's memory holds, before it is listed
    if not (out / SETTINGS).exists():
        write_atomic(out / SETTINGS, json.dumps(settings, indent=2))
    folders = [out / f"seed{k}" for k in wanted]
    todo = [(k, f) for k, f in zip(wanted, folders) if not f.is_dir()]
    if not todo:
        return folders
    results = Session(session, progress=progress).run(resume=(out / "session" / "config.json").exists())
    trajectory = pd.read_csv(results / "trajectories.csv")
    env = _env(world, policy, session)
    for k, folder in todo:
        poses = trajectory[trajectory.seed == k].sort_values("time_s")
        odom = poses[["est_x", "est_y", "est_yaw"] if "est_x" in poses else ["x", "y", "yaw"]].to_numpy(np.float32)
        _write_seed(env, cfg, poses.time_s.to_numpy(), poses[["x", "y", "yaw"]].to_numpy(np.float32), odom, folder,
                    {"world": env.world.name, "policy": policy, "seed": k, "duration_s": duration})
    return folders


SETTINGS = "record.json"  # what every seed of a recording folder was recorded with


def _check_settings(out: Path, settings: dict) -> None:
    """A resumed recording keeps its world, policy, duration, resolution and rate: seeds
    recorded otherwise would sit beside the old ones as if they were alike."""
    saved = out / SETTINGS
    if not out.is_dir() or not any(out.iterdir()):
        return
    try:
        old = json.loads(saved.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(str(out), "--out", f"holds no {SETTINGS}: not a recording folder; choose another") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        old = None
    if not isinstance(old, dict):
        raise InputError(str(saved), "file", "unreadable: cannot resume from it")
    require_same(saved, old, settings, list(settings))


def _env(world: str, policy: str, session):
    """The env the session drove (same camera, laser, robot and noise settings, and those
    the policy sets: a replay's recorded env)."""
    return make(world, **run_overrides(session, load_world(world).name, policy))


def camera_intrinsics(camera: CameraConfig, width: int, height: int) -> dict:
    """Pinhole intrinsics of the camera at width x height: pixel (u, v) with centre (u + 0.5,
    v + 0.5) looks along ((u - cx) / fx, (v - cy) / fy, 1) in the optical frame."""
    f = camera.focal(width)
    return {"width": width, "height": height, "fx": f, "fy": f, "cx": width / 2 - 0.5, "cy": height / 2 - 0.5,
            "distortion": [0.0] * 5, "hfov_deg": float(np.rad2deg(camera.hfov)),
            "depth_scale": DEPTH_SCALE, "depth_min_m": camera.min_range, "depth_max_m": camera.max_range}


def optical_poses(camera: CameraConfig, poses: np.ndarray) -> np.ndarray:
    """(T, 7) tx ty tz qx qy qz qw of the optical frame (x right, y down, z forward) in the
    world for robot poses (T, 3)."""
    cp, sp = np.cos(camera.pitch), np.sin(camera.pitch)
    forward, left, up = np.array([cp, 0, -sp]), np.array([0.0, 1, 0]), np.array([sp, 0, cp])
    body = np.stack([-left, -up, forward], 1)  # optical axes as columns, in the robot frame
    yaw = Rotation.from_euler("z", poses[:, 2:3].astype(np.float64)).as_matrix()
    rot = Rotation.from_matrix(yaw @ body)
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    t = np.stack([poses[:, 0] + camera.mount_x * c, poses[:, 1] + camera.mount_x * s,
                  np.full(len(poses), camera.mount_height)], 1)
    return np.concatenate([t, rot.as_quat()], 1)


def _render_fn(env, camera: CameraConfig):
    """jit: poses (F, 3), key, steps (F,) -> RGB (F, H, W, 3), depth (F, H, W), labels (F, H, W)."""
    cfg = env.config.noise

    def one(pose, key, step):
        img, depth, label = rgbd(env.rays, camera, pose)
        if cfg.depth:
            depth = noise.depth(noise.key(key, step, noise.DEPTH), depth, cfg, camera.focal(depth.shape[1]))
        if cfg.rgb:
            img = noise.rgb(noise.key(key, step, noise.RGB), img, cfg)
        return img, depth, label

    return xla.jit(jax.vmap(one, in_axes=(0, None, 0)))


def _write_seed(env, cfg: RecordConfig, times: np.ndarray, poses: np.ndarray, odom: np.ndarray, folder: Path,
                info: dict) -> None:
    """One seed's folder from its true poses (T, 3) and its odometry (T, 3): the robot's own
    estimate when it localises itself, else the true poses."""
    tmp = folder.with_name(f".{folder.name}.partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    camera = replace(env.config.camera, rgb_width=cfg.width, rgb_height=cfg.height)
    frames = np.arange(0, len(times), cfg.stride(env.dt))
    if cfg.format == "tum":
        _write_tum(env, cfg, camera, times, poses, odom, frames, tmp, info)
    else:
        _write_bag(env, cfg, camera, times, poses, odom, frames, tmp / "bag", info)
    truth = env.world.truth
    (tmp / "objects.json").write_text(json.dumps(
        {"seg_values": "object id + 1; 0 = wall, floor or nothing", "objects": [
            {"id": i, "seg": i + 1, "name": n, "category": c} for i, (n, c) in enumerate(zip(truth.names,
                                                                                        truth.categories))]},
        indent=1))
    mount = {"x": camera.mount_x, "y": 0.0, "z": camera.mount_height, "pitch_rad": camera.pitch}
    (tmp / "camera.json").write_text(json.dumps({**camera_intrinsics(camera, cfg.width, cfg.height),
                                                 "rate_hz": cfg.rate_hz, "base_to_camera": mount}, indent=1))
    (tmp / "info.json").write_text(json.dumps({**info, "frames": len(frames), "control_dt_s": env.dt,
                                               "format": cfg.format}, indent=1))
    tmp.rename(folder)


def _rendered(env, camera: CameraConfig, poses: np.ndarray, frames: np.ndarray, seed: int):
    """(start, RGB, depth, labels) per batch of FRAME_BATCH frames, rendered in order, with
    the env's camera noise (drawn from the seed and the frame's step)."""
    render = _render_fn(env, camera)
    for start in range(0, len(frames), FRAME_BATCH):
        part = frames[start:start + FRAME_BATCH]
        batch = np.zeros((FRAME_BATCH, 3), np.float32)  # a fixed batch shape: one compile
        steps = np.zeros(FRAME_BATCH, np.int32)
        batch[:len(part)], steps[:len(part)] = poses[part], part
        img, depth, label = render(jnp.asarray(batch), jax.random.key(seed), jnp.asarray(steps))
        yield (start, *(np.asarray(a)[:len(part)] for a in (img, depth, label)))


def _write_tum(env, cfg: RecordConfig, camera, times, poses, odom, frames, tmp: Path, info: dict) -> None:
    for sub in ("rgb", "depth", "seg"):
        (tmp / sub).mkdir()
    stamps = [f"{times[i]:.6f}" for i in frames]
    with ThreadPoolExecutor(max_workers=2) as pool:  # PNG encoding overlaps the next render
        jobs = [pool.submit(_write_pngs, tmp, stamps[start:start + FRAME_BATCH], img, depth, label)
                for start, img, depth, label in _rendered(env, camera, poses, frames, info["seed"])]
        for j in jobs:
            j.result()
    for sub in ("rgb", "depth", "seg"):
        _write_table(tmp / f"{sub}.txt", f"{sub} images of {info['world']}: timestamp filename",
                     [f"{s} {sub}/{s}.png" for s in stamps])
    gt = optical_poses(camera, poses)
    _write_table(tmp / "groundtruth.txt", "camera optical frame in the world: timestamp tx ty tz qx qy qz qw",
                 [f"{t:.6f} " + " ".join(f"{v:.6f}" for v in row) for t, row in zip(times, gt)])
    _write_laser(env, tmp, times, poses, info["seed"])
    _write_odometry(tmp, times, odom, env.dt, env.config.localisation != "ground_truth")


def _write_bag(env, cfg: RecordConfig, camera, times, poses, odom, frames, path: Path, info: dict) -> None:
    """The run as a ROS 2 bag (apps.ros_bags): every control step's clock, transforms,
    odometry, ground truth and laser; every frame's images, camera info and detections."""
    streams = BagStreams(path, cfg.format, cfg.depth_encoding)
    laser_cfg = env.config.laser
    ranges = _ranges(env, poses, info["seed"])
    v, w = _rates(odom, env.dt)
    angles = laser_dirs(laser_cfg)
    intr = camera_intrinsics(camera, cfg.width, cfg.height)
    detector = make_detector(cfg.detector, env.world, 0.25) if cfg.detector != "off" else None
    names = env.world.taxonomy.names
    streams.static(camera, laser_cfg)
    step = 0
    try:
        for start, img, depth, label in _rendered(env, camera, poses, frames, info["seed"]):
            dets = detector(img, label, [(info["seed"], start + k) for k in range(len(img))]) if detector else None
            for k, i in enumerate(frames[start:start + len(img)]):
                for j in range(step, i + 1):  # the steps up to the frame's, then the frame: time order
                    streams.step(times[j], odom[j], poses[j], v[j], w[j], ranges[j], laser_cfg, angles)
                step = i + 1
                streams.frame(times[i], img[k], depth[k], intr, dets[k][1:4] if dets else None, names)
        for j in range(step, len(times)):
            streams.step(times[j], odom[j], poses[j], v[j], w[j], ranges[j], laser_cfg, angles)
    finally:
        streams.close()


def _write_pngs(folder: Path, stamps: list[str], img, depth, label) -> None:
    for s, rgb, d, lab in zip(stamps, img, depth, label):
        cv2.imwrite(str(folder / "rgb" / f"{s}.png"), rgb[..., ::-1])  # OpenCV writes BGR
        cv2.imwrite(str(folder / "depth" / f"{s}.png"), np.round(d * DEPTH_SCALE).astype(np.uint16))
        cv2.imwrite(str(folder / "seg" / f"{s}.png"), np.maximum(lab + 1, 0).astype(np.uint16))


def _write_table(path: Path, header: str, lines: list[str]) -> None:
    path.write_text(f"# {header}\n" + "\n".join(lines) + "\n")


def _ranges(env, poses: np.ndarray, seed: int) -> np.ndarray:
    """(T, K) laser ranges at the poses (T, 3), with the env's laser noise (drawn from the
    seed and the step)."""
    las, cfg = env.config.laser, env.config.noise

    def one(p, step):
        r = laser(env.laser_rays, las, p)[0]
        if cfg.laser:
            r = noise.ranges(noise.key(jax.random.key(seed), step, noise.LASER), r, cfg, las.min_range, las.max_range)
        return r

    return np.asarray(xla.jit(jax.vmap(one))(jnp.asarray(poses), jnp.arange(len(poses))))


def _write_laser(env, folder: Path, times: np.ndarray, poses: np.ndarray, seed: int) -> None:
    cfg = env.config.laser
    ranges = _ranges(env, poses, seed)
    angles = laser_dirs(cfg)
    header = (f"laser ranges (m), {cfg.beams} beams from {angles[0]:.6f} to {angles[-1]:.6f} rad "
              f"(increment {angles[1] - angles[0]:.6f}) in the robot frame, {cfg.height} m above the floor at the "
              f"robot's centre; range {cfg.min_range}-{cfg.max_range} m, max_range = no return: timestamp r_0 ... r_K-1")
    _write_table(folder / "scan.txt", header, [f"{t:.6f} " + " ".join(f"{r:.4f}" for r in row)
                                               for t, row in zip(times, ranges)])


def _rates(poses: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Forward and turn rates (T,) from the pose differences (backward, 0 at the start)."""
    d = np.diff(poses, axis=0, prepend=poses[:1])
    yaw = poses[:, 2]
    return (d[:, 0] * np.cos(yaw) + d[:, 1] * np.sin(yaw)) / dt, np.angle(np.exp(1j * d[:, 2])) / dt


def _write_odometry(folder: Path, times: np.ndarray, poses: np.ndarray, dt: float, estimated: bool = False) -> None:
    """The odometry (the robot's own pose estimate, or the true pose) with forward and turn rates."""
    v, w = _rates(poses, dt)
    _write_table(folder / "odometry.txt", "base pose in the odom frame (= world, no drift): timestamp x y yaw v w"
                 if estimated is False else "base pose in the odom frame, the robot's own estimate: timestamp x y yaw v w",
                 [f"{t:.6f} {x:.6f} {y:.6f} {a:.6f} {vv:.5f} {ww:.5f}"
                  for t, (x, y, a), vv, ww in zip(times, poses, v, w)])
