"""Python agents in sessions: ``--policies agent:FILE.py:Name`` runs a
:class:`rosmeery_jax.gym.Agent` (numpy, PyTorch, any Python) through the Gymnasium vector
env, one robot per seed, in the session's worlds, duration and decision period, and writes
the session's results files for it (metrics, objects, trajectories, maps), so its curves
sit beside the built-ins' in the tables and plots and ``--resume`` treats it like any run.

One host round trip per decision: the agent acts on the B robots' observations, the vector
env steps them in one compiled call. With the detector off, as the vector env has no
detector: the robots' labels are those they observe (``labels = "observed"``).

With task "objectnav" the agent's ``seek`` then runs the world's episodes (docs/tasks.md):
each episode for the B robots at once, put at its start with their maps kept, until the
agent stops a robot or the episode's time runs out (``task_attempts`` times the
navigator's timeout, the most the built-in search can take).
"""

from __future__ import annotations

import math
import time

import jax
import numpy as np
import pandas as pd

from rosmeery_jax.core import interrupt, plugins
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.env import Track
from rosmeery_jax.gym import GymConfig, VectorEnv, agent_class
from rosmeery_jax.session import objectnav
from rosmeery_jax.session.config import SessionConfig
from rosmeery_jax.session.outputs import RunResult
from rosmeery_jax.session.schedule import decisions, env_overrides, log_every
from rosmeery_jax.world import episodes as episodes_


def run_agent(cfg: SessionConfig, world: str, spec: str, bar) -> tuple[RunResult, dict]:
    """Run the agent entry ``spec`` in ``world`` for every seed; its result and timing."""
    t0 = time.perf_counter()
    cls = agent_class(spec)
    vec = VectorEnv([world], cfg.seeds, GymConfig(cfg.duration, cfg.decide_every, camera=cls.camera,
                                                     env=env_overrides(cfg)),
                    log_every(cfg))
    with plugins.raised_by(spec, "policies", "its constructor"):
        agent = cls(vec)
    obs, _ = vec.reset(seed=cfg.first_seed)  # robot k is seed first_seed + k, as in the engine
    logs = [jax.tree.map(lambda a: np.asarray(a)[:, None], vec.log())]
    track = [jax.tree.map(lambda a: np.asarray(a)[:, None], Track.of(vec.state))]
    t1 = None
    for k in range(decisions(cfg)):
        interrupt.check()
        with plugins.raised_by(spec, "policies", f"act (decision {k})"):
            actions = agent.act(obs)
        obs, *_ = vec.step(_checked(spec, actions, vec))
        logs.append(jax.tree.map(np.asarray, vec.last_logs))
        track.append(jax.tree.map(np.asarray, vec.last_track))
        bar.update(cfg.decide_every * vec.bank.env.dt)
        t1 = t1 or time.perf_counter()  # the first decision compiled the step
    logs = jax.tree.map(lambda *a: np.concatenate(a, axis=1), *logs)
    result = RunResult(vec.bank.env, agent.name, logs, jax.tree.map(lambda *a: np.concatenate(a, axis=1), *track),
                       jax.tree.map(np.asarray, vec.knowledge()), None, log_every(cfg), cfg.seed_range)
    steps = cfg.seeds * (decisions(cfg) - 1) * cfg.decide_every  # timed: the decisions after the first
    timing = {"envs": cfg.seeds, "env_steps": steps, "sim_s": time.perf_counter() - t1, "compile_s": t1 - t0}
    if cfg.task == "objectnav":
        t2 = time.perf_counter()
        result = result._replace(tasks=seek_episodes(cfg, vec, agent, spec))
        timing["task_s"] = time.perf_counter() - t2
    return result, {**timing, "wall_s": time.perf_counter() - t0, "compiles": 1}


def seek_episodes(cfg: SessionConfig, vec: VectorEnv, agent, spec: str) -> pd.DataFrame:
    """The agent's task phase (module docstring) in ``vec``'s world: tasks.csv's rows."""
    world, env = vec.bank.worlds[0], vec.bank.env
    judge = objectnav.Judge(world)
    limit = math.ceil(cfg.task_attempts * env.config.nav.timeout / (cfg.decide_every * env.dt))
    ended = []
    for ep in episodes_.generated(world, cfg.task_episodes):
        copies = [objectnav.Copy(b, "own", ep, np.zeros((1, 3), np.float32), np.full(1, -1), None)
                  for b in range(vec.num_envs)]
        ended += _seek(vec, agent, spec, ep, limit, judge, copies)
    return objectnav.frame(ended, judge, world.name, agent.name, dict(enumerate(cfg.seed_range)), env.dt)


def _seek(vec: VectorEnv, agent, spec: str, ep, limit: int, judge, copies) -> list:
    """One episode for the B robots: each ends where the agent stops it, or at ``limit``
    decisions (timed out, a failure as in Habitat, where only a stop succeeds)."""
    b = vec.num_envs
    obs = vec.place(np.repeat(np.asarray(ep.start, np.float32)[None], b, 0))
    pose = np.repeat(np.asarray(ep.start, np.float32)[None], b, 0)  # true poses
    path, steps, stopped = np.zeros(b), np.zeros(b, np.int64), np.zeros(b, bool)
    for k in range(limit):
        interrupt.check()
        with plugins.raised_by(spec, "policies", f"seek (episode {ep.id}, decision {k})"):
            actions, stop = _sought(spec, agent.seek(obs, ep.goal), vec)
        stopped |= stop
        if stopped.all():
            break
        obs = vec.advance(actions)
        track = np.concatenate([pose[:, None], np.asarray(vec.last_track.pose)], 1)  # (B, 1 + steps, 3)
        moving = ~stopped
        path += np.where(moving, np.hypot(*np.diff(track[..., :2], axis=1).transpose(2, 0, 1)).sum(1), 0.0)
        steps += np.where(moving, track.shape[1] - 1, 0)
        pose = np.where(moving[:, None], track[:, -1], pose)
    return [objectnav.Ended(c, 1, pose[r], float(path[r]), int(steps[r]),
                            bool(stopped[r]) and judge.success(ep.goal, pose[r, :2]),
                            "stopped" if stopped[r] else "timeout") for r, c in enumerate(copies)]


def _sought(spec: str, out, vec: VectorEnv) -> tuple[np.ndarray, np.ndarray]:
    """``seek``'s return as (actions (B, A), stop (B,) bool), or one line naming the agent."""
    try:
        actions, stop = out
        stop = np.asarray(stop)
    except (TypeError, ValueError):
        raise InputError("config", "policies", f"{spec!r}: seek must return (actions, stop)") from None
    if stop.shape != (vec.num_envs,) or stop.dtype != bool:
        raise InputError("config", "policies", f"{spec!r}: seek's stop must be {vec.num_envs} booleans, not "
                         f"{stop.dtype} of shape {stop.shape}")
    return _checked(spec, actions, vec, "seek"), stop


def _checked(spec: str, actions, vec: VectorEnv, method: str = "act") -> np.ndarray:
    """The agent's actions as (B, A) float32, or one line naming it."""
    want = (vec.num_envs, *vec.single_action_space.shape)
    try:
        a = np.asarray(actions, np.float32)
    except (TypeError, ValueError) as err:
        raise InputError("config", "policies", f"{spec!r}: {method} returned something that is not numbers "
                         f"({err})") from None
    if a.shape != want:
        raise InputError("config", "policies", f"{spec!r}: {method} returned actions of shape {a.shape}, not {want}")
    if not np.isfinite(a).all():
        raise InputError("config", "policies", f"{spec!r}: {method} returned actions that are not finite")
    return a


__all__ = ["run_agent"]
