"""The benchmark session: worlds x policies x seeds x duration.

Every unfinished (world, policy) pair of a session is simulated in one batch per env
configuration (:mod:`.batch`: worlds as padded data; :mod:`.program`: one compiled chunk
function; :mod:`.engine` steps it, :mod:`.worker` detects and maps beside it), and each
*run* (one world and policy, all its seeds) is then written atomically (:mod:`.outputs`),
or each run is sent to a Ray worker (:mod:`.cluster`).

Everything is validated before anything is written (:mod:`.config`). ``--resume`` skips
finished runs and refuses a changed configuration or changed input files (:mod:`.folder`);
without it an existing results folder is refused rather than overwritten. A seed's curves
are bitwise the same whatever runs beside it (batch: blocks) and whatever ``chunk_s`` is.
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import jax
import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from rosmeery_jax.core import specs, xla
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import LOCK, folder_lock, output_folder, write_atomic
from rosmeery_jax.detector.detections import make_detector
from rosmeery_jax.results import manifest, tables
from rosmeery_jax.session import batch, cluster, engine, objectnav
from rosmeery_jax.session.agents import run_agent
from rosmeery_jax.session.config import SessionConfig
from rosmeery_jax.session.folder import check_out, versions
from rosmeery_jax.session.outputs import (RunResult, finished, merge, run_damage, run_manifest, run_name, sum_timing,
                                          write_run)
from rosmeery_jax.session.schedule import Plan


class Session:
    """``cluster``: None to simulate here, or a Ray address (:mod:`.cluster`) to send each
    unfinished run to a worker; ``cache``: the workers' persistent compilation cache."""

    def __init__(self, cfg: SessionConfig, progress: bool = True, cluster: str | None = None, cache: bool = True,
                 checked: bool = False):
        """``cfg`` is validated unless it was (``checked``: a part of a config that was)."""
        if not isinstance(cfg, SessionConfig):
            raise TypeError(f"Session takes a SessionConfig, not {type(cfg).__name__} (rj.SessionConfig(...) or "
                            "rj.load_config(path))")
        cfg = cfg if cfg.validated or checked else cfg.validate()
        self.cfg, self.progress, self.cluster, self.cache = cfg, progress, cluster, cache
        if cluster is not None and cfg.devices > 1:
            raise InputError("command line", "--devices", "not with --cluster: each Ray worker runs its shard on "
                             "one device")
        if cluster is None:  # a cluster's workers make their own
            prepare_devices(cfg)

    def run(self, resume: bool = False) -> Path:
        """Run every unfinished (world, policy) pair in one batch per env configuration, or
        one Ray task each, write each run's files, then the merged tables and plots."""
        if not isinstance(resume, (bool, np.bool_)):
            raise TypeError(f"Session.run: resume takes True or False, not {resume!r}")
        cfg = self.cfg
        out = Path(cfg.out)
        if self.cluster is not None:  # before anything is written
            cluster.require_ray()
            cluster.check_address(self.cluster)
        check_out(cfg, resume)  # refused here, before the folder is made
        with output_folder(out), folder_lock(out):
            claim = check_out(cfg, resume)  # again under the lock: another command may have started
            write_atomic(out / "config.json", json.dumps({**claim.record, "versions": versions()}, indent=2))
            try:
                self._run(out)
            except BaseException:
                if claim.fresh and not finished(out):
                    _empty(out)  # nothing finished: a corrected command starts afresh in the same folder
                raise
        return out

    def _run(self, out: Path) -> None:
        """Simulate every unfinished run (here or on the cluster), then merge."""
        cfg = self.cfg
        todo = [(w, p) for w in cfg.worlds for p in cfg.policies if not _done(out, w, p)]
        t_start = time.perf_counter()
        parts, extra = [], {}
        if todo and self.cluster is not None:
            bar = _bar(len(todo) * cfg.duration, self.progress)
            parts = cluster.simulate_on_cluster(cfg, todo, out, self.cluster, bar, self.cache, run_shard)
            bar.close()
            extra = {"cluster": self.cluster, "shards": len(parts)}
        elif todo:
            parts = self._simulate_here(todo, out)
        merge(out)
        if parts:
            timing = {**sum_timing(parts, t_start), **extra, "groups": [g for p in parts for g in p.get("groups", [p])]}
            write_atomic(out / "timing.json", json.dumps(timing, indent=2))

    def _simulate_here(self, todo: list[tuple[str, str]], out: Path) -> list[dict]:
        """Simulate the runs in this process; returns each group's timing."""
        cfg = self.cfg
        agents = [(w, p) for w, p in todo if specs.kind(p) == "agent"]
        groups = batch.build_groups([r for r in todo if r not in agents], cfg)
        plan = Plan.of(cfg)
        bar = _bar((len(groups) + len(agents)) * cfg.duration, self.progress)
        timings = []
        for world, spec in agents:  # host-side agents, one run at a time through the vector env
            result, timing = run_agent(cfg, world, spec, bar)
            timings.append(timing)
            write_run(cfg, result, run_name(world, spec), out, timing)
        for group in groups:
            clock = engine.CompileClock()
            t0 = time.perf_counter()
            sim = engine.simulate(group, plan, _detectors(cfg, group), bar, clock)
            driven, t1 = {}, time.perf_counter()
            if plan.drives is not None:
                driven = objectnav.for_group(group, plan.drives, sim, cfg.mappers, [p.name for p in group.policies])
            timing = {**sim.timing, "compile_s": clock.seconds, "wall_s": time.perf_counter() - t0,
                      "devices": group.devices, **({"task_s": time.perf_counter() - t1} if driven else {})}
            timings.append(timing)
            for run in group.runs:
                write_run(cfg, _result(group, run, sim)._replace(tasks=driven.get(run.name)), run.name, out, timing)
        bar.close()
        return timings


def _result(group, run, sim) -> RunResult:
    """One run's part of its group's simulation (``sim`` holds the real envs in row order)."""
    rows = np.searchsorted(np.flatnonzero(group.real), run.rows)
    pick = lambda tree: jax.tree.map(lambda a: np.asarray(a)[rows], tree)  # noqa: E731
    mapped = {spec: [per_env[r] for r in rows] for spec, per_env in sim.mapped.items()} if sim.mapped else None
    digests = None
    if sim.digests is not None:
        span = sim.log_every * (sim.logs.ps.shape[1] - 1) / len(sim.digests)  # steps per chunk
        env = group.envs[run.world]
        digests = pd.DataFrame([{"seed": seed, "chunk": c, "time_s": float(tables.seconds((c + 1) * span * env.dt)),
                                 **{k: v[r] for k, v in part.items()}}
                                for seed, r in zip(run.seeds, rows) for c, part in enumerate(sim.digests)])
    return RunResult(group.envs[run.world], group.policies[run.policy].name, pick(sim.logs), pick(sim.track),
                     pick(sim.knowledge), mapped, sim.log_every, run.seeds, digests,
                     pick(sim.stamps) if sim.stamps is not None else None)


def prepare_devices(cfg: SessionConfig) -> None:
    """Make the devices ``cfg.devices`` asks for (host devices from the CPU's cores, while
    JAX has not started), and refuse more than there are."""
    if cfg.devices != 1:
        # With YOLO, torch needs a core of its own: on the 2-core machine two host devices
        # beside it made the paper session slower (docs/cluster.md).
        xla.host_devices(cfg.devices or max(1, xla.cores() - (cfg.detector == "yolo")))
    if cfg.devices > 1 and len(jax.devices()) < cfg.devices:
        raise InputError("config", "devices", f"{cfg.devices} asked, {len(jax.devices())} "
                         f"{jax.devices()[0].platform} device(s) available (host devices are made "
                         "from the CPU's cores only if JAX has not started yet)")


def run_shard(cfg: SessionConfig, world: str, policy: str, cache: bool) -> tuple[dict[str, bytes], dict]:
    """On a Ray worker: simulate one run in a scratch folder and return ({relative path:
    bytes}, timing) for the driver to write."""
    xla.compilation_cache(cache)
    with tempfile.TemporaryDirectory(prefix="rosmeery-shard-") as tmp:
        out = Session(replace(cfg, worlds=(world,), policies=(policy,), out=tmp), progress=False, checked=True).run()
        name = run_name(world, policy)
        files = sorted(p for p in (out / "runs").glob(f"{name}.*")) + sorted((out / "maps").glob(f"{name}__seed*"))
        timing = json.loads((out / "timing.json").read_text()) if (out / "timing.json").exists() else {}
        return {str(p.relative_to(out)): p.read_bytes() for p in files}, timing


def _done(out: Path, world: str, policy: str) -> bool:
    """Whether a run's files are all there as recorded. A run whose files were damaged since
    (or that an interrupt left without its record) is simulated again, and says so."""
    name = run_name(world, policy)
    record = run_manifest(out, name)
    if not record.exists() and not (out / "runs" / f"{name}.metrics.csv").exists():
        return False  # never finished: nothing to say
    err = run_damage(out, name)
    if err is None:
        return True
    print(f"rosmeery: {err}: simulating {name} again", file=sys.stderr)
    record.unlink(missing_ok=True)
    return False


def _empty(out: Path) -> None:
    """Remove what this invocation wrote into the folder it found empty (no run finished)."""
    for p in out.iterdir():
        if p.name != LOCK:
            shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()


def _detectors(cfg: SessionConfig, group) -> dict | None:
    """{world index: detector} for the group's worlds, or None with the detector off."""
    if cfg.detector == "off":
        return None
    return {w: make_detector(cfg.detector, env.world, cfg.conf_threshold, cfg.weights or None, cfg.detector_runtime)
            for w, env in enumerate(group.envs)}


def _bar(total: float, enabled: bool):
    return tqdm(total=total, unit="sim-s", disable=not enabled, bar_format=(
        "{l_bar}{bar}| {n:.0f}/{total:.0f} simulated s [{elapsed}<{remaining}{postfix}]"))
