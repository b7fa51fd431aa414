"""``rosmeery bench``: how fast the batched platform steps, and the C MuJoCo peer on the same work.

One env-step is 0.1 s of simulated time: MJX physics substeps, the laser, the depth +
segmentation camera, the occupancy map, the navigator and the surface coverage, with every
robot driving to its own random reachable target (target action mode). Figures per batch size B: env-steps/s
(median of ``repeats`` timed chunks of ``steps`` steps inside one ``lax.scan``) and the
first call's compile time. At the reference batch: a per-stage breakdown (each stage jitted
and vmapped alone), the share of camera pixels the frustum cull changes, and the CPU peer:
C MuJoCo physics through ``mujoco.rollout`` (threads = cores) plus ``mj_multiRay`` for the
same laser and camera rays from the same poses (a thread pool of cores; the binding releases
the GIL). The peer does no mapping or navigation, so the comparison flatters it. Its
physics runs open-loop over the whole chunk in one call, its best case.

Peak memory of a 1,024-robot batch is measured in a child process (``--memory-batch``),
so the figure is that batch's alone.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, fields, replace
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout

from rosmeery_jax.core import grid, xla
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.xla import MEMORY_SHARE, memory_bytes
from rosmeery_jax.detector.detections import DEFAULT_WEIGHTS, YoloDetector
from rosmeery_jax.env import EnvConfig, make
from rosmeery_jax.env.config import env_bytes
from rosmeery_jax.raycast.sensors import camera_rays, depth_seg, laser, laser_dirs
from rosmeery_jax.rl.task import STEP_LIMIT
from rosmeery_jax.session import Session, SessionConfig
from rosmeery_jax.session.program import Replicas
from rosmeery_jax.sim import noise


@dataclass(frozen=True)
class BenchConfig:
    world: str = "large_office"
    batches: tuple[int, ...] = (1, 16, 64, 256)
    reference_batch: int = 64
    steps: int = 20
    repeats: int = 3
    memory_batch: int = 1024
    seed: int = 0
    session_s: float = 20.0  # simulated seconds of the end-to-end default session (0 = skip)
    devices: int = 0  # also time the reference batch split over this many devices (0 = as many as divide it)


def check(cfg: BenchConfig) -> None:
    """Every option in range before JAX starts; one InputError naming the option. The
    session's duration is checked as a session checks it (its logs fit in memory)."""
    for option, value, low in (("--steps", cfg.steps, 1), ("--memory-batch", cfg.memory_batch, 0),
                               ("--devices", cfg.devices, 0)):
        if value < low:
            raise InputError("command line", option, f"{value} must be >= {low}")
    if cfg.steps > STEP_LIMIT:  # a chunk's steps are counted in int32
        raise InputError("command line", "--steps", f"{cfg.steps} must be at most {STEP_LIMIT}")
    if cfg.devices and cfg.reference_batch % cfg.devices:  # else the split was skipped without a word
        raise InputError("command line", "--devices", f"{cfg.devices} must divide the reference batch "
                         f"({cfg.reference_batch} robots)")
    for option, batch in (("--batches", max(cfg.batches)), ("--memory-batch", cfg.memory_batch)):
        need, have = batch * env_bytes(EnvConfig()), memory_bytes()
        if need > MEMORY_SHARE * have:
            raise InputError("command line", option, f"{batch:,} robots need about {need / 1e9:,.1f} GB, more than "
                             f"this machine's {have / 1e9:.1f} GB allows")
    if not (math.isfinite(cfg.session_s) and cfg.session_s >= 0):
        raise InputError("command line", "--session-s", f"{cfg.session_s!r} must be a number of seconds >= 0")
    if cfg.session_s:
        SessionConfig(duration=cfg.session_s, out="-").validate("command line: --session-s")


def split_devices(cfg: BenchConfig, available: int) -> int:
    """How many devices the reference batch is split over: ``--devices`` (at most those
    there are), or by default the most of them that divide the batch evenly (6 cores: 4)."""
    if cfg.devices:
        return min(cfg.devices, available)
    return max(n for n in range(1, available + 1) if cfg.reference_batch % n == 0)


def random_targets(world, n: int, seed: int) -> np.ndarray:
    """(n, 3) target poses at random reachable free-space cells, random yaw."""
    fs = world.free_space
    rng = np.random.default_rng(seed)
    ii, jj = np.nonzero(fs.reachable)
    k = rng.integers(len(ii), size=n)
    xy = grid.cell_centers(fs.origin, fs.resolution, ii[k], jj[k])
    return np.concatenate([xy, rng.uniform(-np.pi, np.pi, (n, 1))], -1).astype(np.float32)


def _timed(fn, *args, repeats: int) -> tuple[float, list[float], object]:
    """(first-call seconds, steady-call seconds, last output) of a jitted fn."""
    t = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t)
    return first, times, out


def _rollout(env, steps: int):
    """(state (B, ...), targets (B, 3)) -> state after ``steps`` full steps (not jitted)."""
    def run(state, targets):
        def body(s, _):
            return jax.vmap(env.step)(s, targets), None

        return jax.lax.scan(body, state, None, length=steps)[0]

    return run


def _rollout_fn(env, steps: int):
    return xla.jit(_rollout(env, steps))


def env_throughput(env, batch: int, cfg: BenchConfig, devices: int = 1) -> dict:
    """Full-step env-steps/s and compile time at one batch size, the batch split evenly over
    ``devices`` (each runs the one-device program on its share, as sessions do:
    ``program.Replicas``); also returns the final state."""
    keys = jax.random.split(jax.random.key(cfg.seed), batch)
    state = xla.jit(jax.vmap(env.reset))(keys)
    targets = jnp.asarray(random_targets(env.world, batch, cfg.seed))
    run, lead = _rollout_fn(env, cfg.steps), ()
    if devices > 1:  # Replicas' signature: (shared, one row per device's block, *per-env arguments)
        plain = _rollout(env, cfg.steps)
        run = Replicas(xla.jit(lambda shared, block, s, t: plain(s, t)), devices)
        lead = (None, jnp.zeros(devices))
    t = time.perf_counter()
    compiled = run.lower(*lead, state, targets).compile()
    compile_s = time.perf_counter() - t
    state = jax.block_until_ready(compiled(*lead, state, targets))  # warm: robots on their way
    _, times, state = _timed(compiled, *lead, state, targets, repeats=cfg.repeats)
    return {"batch": batch, "env_steps_per_s": batch * cfg.steps / statistics.median(times),
            "compile_s": compile_s, "state": state}


def stage_chain(env, state, cfg: BenchConfig) -> dict[str, float]:
    """Milliseconds per step of each stage of the step, run as a chain: each stage jitted
    alone, fed the previous stage's output and waited for, for ``steps`` steps. The parts
    add up to a step done in pieces; set against the fused step they show what fusing the
    stages into one program gains or loses."""
    targets = jnp.asarray(random_targets(env.world, state.pose.shape[0], cfg.seed + 1))
    fns = {name: xla.jit(jax.vmap(stage)) for name, stage in (
        ("navigation", env.navigate), ("physics", env.move), ("laser", env.scan), ("mapping", env.update_map),
        ("camera", env.look), ("coverage", env.sk.observe))}
    times: dict[str, list] = {}

    def timed(name, *args):
        t = time.perf_counter()
        out = jax.block_until_ready(fns[name](*args))
        times.setdefault(name, []).append(time.perf_counter() - t)
        return out

    def step(s):
        nav, cmd = timed("navigation", s, targets)
        d, pose = timed("physics", s.physics, cmd)
        ranges, labels = timed("laser", pose)
        logodds = timed("mapping", s.logodds, pose, ranges, labels)
        depth, seg = timed("camera", pose)
        knowledge = timed("coverage", s.knowledge, pose, depth)
        return s._replace(physics=d, pose=pose, nav=nav, ranges=ranges, logodds=logodds, depth=depth, seg=seg,
                          knowledge=knowledge, t=s.t + 1)

    state = step(state)  # compiles every stage
    times.clear()
    for _ in range(cfg.steps):
        state = step(state)
    return {k: 1e3 * statistics.median(v) for k, v in times.items()}


def cull_error(env, poses) -> float:
    """Share of camera pixels whose label differs between the culled and the all-box cast."""
    full = replace(env.config.camera, cull=0)
    _, a = xla.jit(jax.vmap(lambda p: depth_seg(env.rays, env.config.camera, p)))(poses)
    _, b = xla.jit(jax.vmap(lambda p: depth_seg(env.rays, full, p)))(poses)
    return float(np.mean(np.asarray(a) != np.asarray(b)))


def mujoco_peer(env, batch: int, cfg: BenchConfig, threads: int) -> dict:
    """C MuJoCo physics (rollout) + mj_multiRay for the same sensors: env-steps/s."""
    m = env.mj_model
    rc = env.config.robot
    nstep = cfg.steps * rc.substeps
    datas = [mujoco.MjData(m) for _ in range(threads)]
    init = np.zeros((batch, mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS)))
    d0 = mujoco.MjData(m)
    mujoco.mj_forward(m, d0)
    mujoco.mj_getState(m, d0, init[0], mujoco.mjtState.mjSTATE_FULLPHYSICS)
    init[:] = init[0]
    rng = np.random.default_rng(cfg.seed)
    ctrl = np.repeat(rng.uniform(-1, 1, (batch, cfg.steps, m.nu)), rc.substeps, axis=1)
    rollout.rollout(m, datas, init, ctrl, nstep=nstep)  # warm the pool
    physics = []
    for _ in range(cfg.repeats):  # a median of repeats, like our side
        t = time.perf_counter()
        states, _ = rollout.rollout(m, datas, init, ctrl, nstep=nstep)
        physics.append(time.perf_counter() - t)
    physics_s = statistics.median(physics)

    # Sensors from every env's pose after each control step, on the world's own MjModel.
    wm = env.world.mj_model
    qpos = states[:, rc.substeps - 1::rc.substeps, 1:4]  # (B, T, 3): state = time, qpos, ...
    poses = (qpos + np.r_[env.world.spawn[:2], 0.0]).reshape(-1, 3)
    cam = camera_rays(env.config.camera, env.config.camera.width, env.config.camera.height).astype(np.float64)
    beams = laser_dirs(env.config.laser).astype(np.float64)
    c, lz = env.config.camera, env.config.laser.height

    def cast_chunk(chunk):
        d = mujoco.MjData(wm)
        mujoco.mj_forward(wm, d)
        n_cam, n_las = len(cam), len(beams)
        gid_c, dist_c = np.zeros(n_cam, np.int32), np.zeros(n_cam)
        gid_l, dist_l = np.zeros(n_las, np.int32), np.zeros(n_las)
        for x, y, yaw in chunk:
            cs, sn = np.cos(yaw), np.sin(yaw)
            vec = np.stack([cs * cam[:, 0] - sn * cam[:, 1], sn * cam[:, 0] + cs * cam[:, 1], cam[:, 2]], -1)
            pnt = np.array([x + c.mount_x * cs, y + c.mount_x * sn, c.mount_height])
            mujoco.mj_multiRay(wm, d, pnt, vec.ravel(), None, 1, -1, gid_c, dist_c, None, n_cam, c.max_range)
            las = np.stack([np.cos(yaw + beams), np.sin(yaw + beams), np.zeros_like(beams)], -1)
            mujoco.mj_multiRay(wm, d, np.array([x, y, lz]), las.ravel(), None, 1, -1, gid_l, dist_l, None,
                               n_las, env.config.laser.max_range)

    chunks = np.array_split(poses, threads)
    rays = []
    with ThreadPoolExecutor(threads) as pool:
        for _ in range(cfg.repeats):
            t = time.perf_counter()
            list(pool.map(cast_chunk, chunks))
            rays.append(time.perf_counter() - t)
    rays_s = statistics.median(rays)
    n = batch * cfg.steps
    return {"env_steps_per_s": n / (physics_s + rays_s), "physics_env_steps_per_s": n / physics_s,
            "sensor_env_steps_per_s": n / rays_s, "threads": threads,
            "work": (ctrl[:, ::rc.substeps], poses.reshape(batch, cfg.steps, 3))}


def equal_work(env, batch: int, cfg: BenchConfig, ctrl: np.ndarray, poses: np.ndarray) -> float:
    """Our env-steps/s on the peer's work: physics under controls of the same magnitudes as
    the peer's, then the same laser and camera rays from the peer's poses (no mapping,
    navigation or coverage)."""
    c = env.config

    @xla.jit
    def run(d, ctrl, poses):
        def body(d, xs):
            u, p = xs  # u (B, 3) world-frame velocity (x, y, yaw); p (B, 3) the peer's pose
            d = jax.vmap(lambda d, u: env.platform.step(d, jnp.stack([jnp.hypot(u[0], u[1]), u[2]])))(d, u)
            ranges = jax.vmap(lambda p: laser(env.laser_rays, c.laser, p))(p)
            depth = jax.vmap(lambda p: depth_seg(env.rays, c.camera, p))(p)
            return d, (ranges, depth)

        # The sensor images are returned: XLA would drop a scan output nobody reads.
        return jax.lax.scan(body, d, (jnp.swapaxes(ctrl, 0, 1), jnp.swapaxes(poses, 0, 1)))

    keys = jax.random.split(jax.random.key(cfg.seed), batch)
    state = xla.jit(jax.vmap(env.reset))(keys)
    args = (state.physics, jnp.asarray(ctrl, jnp.float32), jnp.asarray(poses, jnp.float32))
    _, times, _ = _timed(run, *args, repeats=cfg.repeats)
    return batch * cfg.steps / statistics.median(times)


def session_rate(world_names=None, duration: float = 20.0, detector: str = "yolo") -> dict:
    """End to end: a short default session (the four worlds x frontier, random x 5 seeds)
    including set-up and compile (the persistent cache counts as it would for a user)."""
    if importlib.util.find_spec("torch") is None:  # the optional detector extra
        detector = "oracle"
    with tempfile.TemporaryDirectory() as tmp:
        kw = {"worlds": tuple(world_names)} if world_names else {}
        cfg = SessionConfig(duration=duration, detector=detector, out=str(Path(tmp) / "s"), **kw).validate("bench")
        Session(cfg, progress=False).run()
        t = json.loads((Path(tmp) / "s" / "timing.json").read_text())
    return {k: t[k] for k in ("env_steps", "wall_s", "env_steps_per_s", "sim_env_steps_per_s", "compile_s",
                              "compiles", "cache_hits", "detector_s", "wait_s")} | {"duration_s": duration,
                                                                                      "detector": detector}




def memory_probe(world: str, batch: int, steps: int) -> float:
    """Peak resident memory (GB) of a child process that runs ``steps`` env-steps at ``batch``."""
    code = (
        "import resource, jax, jax.numpy as jnp, rosmeery_jax;"
        "from rosmeery_jax.env import make; from rosmeery_jax.apps.bench import random_targets, _rollout_fn;"
        f"env = make({world!r}); keys = jax.random.split(jax.random.key(0), {batch});"
        "s = rosmeery_jax.jit(jax.vmap(env.reset))(keys);"
        f"t = jnp.asarray(random_targets(env.world, {batch}, 0));"
        f"jax.block_until_ready(_rollout_fn(env, {steps})(s, t));"
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return int(out.stdout.strip().splitlines()[-1]) / 1e6  # ru_maxrss is KiB on Linux


def detector_bench(env, state, decide_every: int = 10, env_rate: float | None = None, repeats: int = 3) -> dict:
    """The YOLO detector on the session's frames: images/s at the detector's resolution (batch
    of B frames rendered from the batch's poses), the cost of rendering those frames, and the
    detector's estimated share of a default session's wall time (one frame per env per
    decision, ``decide_every`` steps at ``env_rate`` env-steps/s)."""
    if importlib.util.find_spec("torch") is None:  # the optional detector extra
        return {"skipped": "torch is not installed"}
    if not DEFAULT_WEIGHTS.is_file():
        return {"skipped": f"no weights at {DEFAULT_WEIGHTS}"}
    render = xla.jit(jax.vmap(env.camera_rgb))
    first, times, (img, lab) = _timed(render, state, repeats=repeats)
    img, lab = np.asarray(img), np.asarray(lab)
    det = YoloDetector(env.world.taxonomy.names)
    det.finish(det.forward(img), lab)  # warm-up
    t = time.perf_counter()
    for _ in range(repeats):  # forward: the network on every frame, however often seen
        det.finish(det.forward(img), lab)
    ips = repeats * len(img) / (time.perf_counter() - t)
    cam = env.config.camera
    out = {"images_per_s": round(ips, 1), "runtime": det.runtime, "resolution": f"{cam.rgb_width}x{cam.rgb_height}",
           "batch": len(img),
           "detector_batch": det.batch, "render_ms_per_frame": round(1e3 * float(np.median(times)) / len(img), 3)}
    if env_rate:
        env_s = decide_every / env_rate  # wall seconds per env per decision
        det_s = 1.0 / ips
        out["session_share"] = round(det_s / (det_s + env_s), 3)
    return out


def run_bench(cfg: BenchConfig, progress=print) -> dict:
    env = make(cfg.world)
    threads = os.cpu_count() or 1
    result: dict = {"world": cfg.world, "steps_per_chunk": cfg.steps, "cores": threads,
                    "jax": jax.__version__, "env_steps_per_s": {}, "compile_s": {}}
    ref_state = None
    for b in cfg.batches:
        progress(f"batch {b} ...")
        r = env_throughput(env, b, cfg)
        result["env_steps_per_s"][str(b)] = round(r["env_steps_per_s"], 1)
        result["compile_s"][str(b)] = round(r["compile_s"], 2)
        if b == cfg.reference_batch:
            ref_state, ref_rate = r["state"], r["env_steps_per_s"]
    if ref_state is None:
        r = env_throughput(env, cfg.reference_batch, cfg)
        ref_state, ref_rate = r["state"], r["env_steps_per_s"]
    progress(f"stages at batch {cfg.reference_batch} ...")
    result["stages_ms"] = {k: round(v, 3) for k, v in stage_chain(env, ref_state, cfg).items()}
    result["fused_step_ms"] = round(1e3 * cfg.reference_batch / ref_rate, 3)
    result["camera_cull_pixel_error"] = cull_error(env, ref_state.pose)
    progress("C MuJoCo peer ...")
    peer = mujoco_peer(env, cfg.reference_batch, cfg, threads)
    ctrl, poses = peer.pop("work")
    result["mujoco_c"] = {k: (round(v, 1) if isinstance(v, float) else v) for k, v in peer.items()}
    progress(f"equal work (our physics + laser + camera on the peer's poses) at batch {cfg.reference_batch} ...")
    result["equal_work_env_steps_per_s"] = round(equal_work(env, cfg.reference_batch, cfg, ctrl, poses), 1)
    result["equal_work_ratio"] = round(result["equal_work_env_steps_per_s"] / peer["env_steps_per_s"], 2)
    # The peer's work (physics + the same rays) plus our mapping and navigation, without coverage.
    platform_env = make(cfg.world, knowledge__coverage__enabled=False)
    progress(f"platform step without coverage at batch {cfg.reference_batch} ...")
    ours = env_throughput(platform_env, cfg.reference_batch, cfg)["env_steps_per_s"]
    result["platform_env_steps_per_s"] = round(ours, 1)
    result["speedup_vs_mujoco_c"] = round(ours / peer["env_steps_per_s"], 2)
    result["speedup_full_step_vs_mujoco_c"] = round(ref_rate / peer["env_steps_per_s"], 2)
    result["reference_batch"] = cfg.reference_batch
    progress(f"full step with realistic noise and scan matching at batch {cfg.reference_batch} ...")
    real = noise.PRESETS["realistic"]
    noisy_env = make(cfg.world, localisation="scan_matching",
                     **{f"noise__{f.name}": getattr(real, f.name) for f in fields(real)})
    noisy = env_throughput(noisy_env, cfg.reference_batch, cfg)["env_steps_per_s"]
    result["noisy_env_steps_per_s"] = round(noisy, 1)
    result["noisy_cost"] = round(ref_rate / noisy, 2)  # the noisy step's time over the exact one's
    n = split_devices(cfg, len(jax.devices()))
    if n > 1:  # every core busy, as the peer's threads keep them
        progress(f"full and platform step at batch {cfg.reference_batch} split over {n} devices ...")
        full_n = env_throughput(env, cfg.reference_batch, cfg, n)["env_steps_per_s"]
        platform_n = env_throughput(platform_env, cfg.reference_batch, cfg, n)["env_steps_per_s"]
        result["devices"] = {"devices": n, "env_steps_per_s": round(full_n, 1),
                             "platform_env_steps_per_s": round(platform_n, 1),
                             "speedup_vs_mujoco_c": round(platform_n / peer["env_steps_per_s"], 2)}
    progress(f"detector at batch {cfg.reference_batch} ...")
    result["detector"] = detector_bench(env, ref_state, env_rate=ref_rate)
    result["peak_memory_gb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6, 2)
    if cfg.session_s:
        progress(f"a default session of {cfg.session_s:g} s end to end ...")
        sess = session_rate(duration=cfg.session_s)
        sess["share_of_full_step"] = round(sess["env_steps_per_s"] / ref_rate, 2)
        result["session"] = sess
    if cfg.memory_batch:
        progress(f"memory at batch {cfg.memory_batch} ...")
        result["memory_batch"] = cfg.memory_batch
        result["memory_batch_peak_gb"] = round(memory_probe(cfg.world, cfg.memory_batch, 2), 2)
    return result


def format_table(r: dict) -> str:
    lines = [f"rosmeery bench: {r['world']}, {r['cores']} cores, jax {r['jax']}, one step = 0.1 s simulated",
             "", f"{'batch':>6}{'env-steps/s':>14}{'compile s':>11}"]
    for b, v in r["env_steps_per_s"].items():
        lines.append(f"{b:>6}{v:>14,.0f}{r['compile_s'][b]:>11.1f}")
    ref = r["reference_batch"]
    lines += ["", f"stages at batch {ref} as a chain (each jitted alone, fed the last one's output; ms per step):"]
    total = sum(r["stages_ms"].values())
    for k, v in r["stages_ms"].items():
        lines.append(f"  {k:<11}{v:>8.2f} ms  {100 * v / total:>4.0f}%")
    lines.append(f"  {'sum':<11}{total:>8.2f} ms; the fused step: {r['fused_step_ms']:.2f} ms")
    lines.append(f"  camera cull changes {100 * r['camera_cull_pixel_error']:.3f}% of pixels")
    p = r["mujoco_c"]
    lines += ["", f"C MuJoCo peer at batch {ref} ({p['threads']} threads): {p['env_steps_per_s']:,.0f} env-steps/s "
              f"(physics alone {p['physics_env_steps_per_s']:,.0f}, sensors alone {p['sensor_env_steps_per_s']:,.0f})",
              f"ours without coverage (the peer's work plus mapping and navigation): "
              f"{r['platform_env_steps_per_s']:,.0f} env-steps/s",
              f"speedup vs MuJoCo C: {r['speedup_vs_mujoco_c']:.2f}x (full step with coverage: "
              f"{r['speedup_full_step_vs_mujoco_c']:.2f}x)",
              *([f"split over {dv['devices']} devices (every core busy, like the peer's threads): full step "
                 f"{dv['env_steps_per_s']:,.0f} env-steps/s, without coverage {dv['platform_env_steps_per_s']:,.0f}, "
                 f"{dv['speedup_vs_mujoco_c']:.2f}x the peer"] if (dv := r.get("devices")) else []),
              *([f"full step with realistic noise and scan matching: {r['noisy_env_steps_per_s']:,.0f} env-steps/s, "
                 f"{r['noisy_cost']:.2f} times the exact step's time"] if "noisy_cost" in r else []),
              f"equal work (our physics + laser + camera on the peer's poses): "
              f"{r['equal_work_env_steps_per_s']:,.0f} env-steps/s, {r['equal_work_ratio']:.2f}x the peer",
              f"peak memory (this process): {r['peak_memory_gb']:.2f} GB"]
    d = r.get("detector", {})
    if "skipped" in d:
        lines.append(f"detector: skipped ({d['skipped']})")
    elif d:
        lines.append(f"detector (YOLO-v5n, {d.get('runtime', 'torch')}): {d['images_per_s']:,.0f} images/s at {d['resolution']} "
                     f"({d['batch']} frames in batches of {d['detector_batch']}); "
                     f"rendering its frames {d['render_ms_per_frame']:.2f} ms each; "
                     f"share of a session's wall time (1 frame per env per second): "
                     f"{100 * d.get('session_share', 0):.0f}%")
    if "session" in r:
        t = r["session"]
        lines.append(f"default session, {t['duration_s']:g} s simulated, end to end with set-up and compile "
                     f"({t['compiles']} compile, {t['cache_hits']} cache hits): {t['env_steps_per_s']:,.0f} "
                     f"env-steps/s ({100 * t['share_of_full_step']:.0f}% of the full step); simulation alone "
                     f"{t['sim_env_steps_per_s']:,.0f}; compile {t['compile_s']:.1f} s of {t['wall_s']:.1f} s")
    if "memory_batch" in r:
        lines.append(f"peak memory at batch {r['memory_batch']}: {r['memory_batch_peak_gb']:.2f} GB")
    return "\n".join(lines)
