"""Python agents in sessions: ``--policies agent:FILE.py:Name`` runs a
:class:`rosmeery_jax.gym.Agent` (numpy, PyTorch, any Python) through the Gymnasium vector
env, one robot per seed, in the session's worlds, duration and decision period, and writes
the session's results files for it (metrics, objects, trajectories, maps), so its curves
sit beside the built-ins' in the tables and plots and ``--resume`` treats it like any run.

One host round trip per decision: the agent acts on the B robots' observations, the vector
env steps them in one compiled call. With the detector off, as the vector env has no
detector: the robots' labels are those they observe (``labels = "observed"``).
"""

from __future__ import annotations

import time

import jax
import numpy as np

from rosmeery_jax.core import interrupt, plugins
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.env import Track
from rosmeery_jax.gym import GymConfig, VectorEnv, agent_class
from rosmeery_jax.session.config import SessionConfig
from rosmeery_jax.session.outputs import RunResult
from rosmeery_jax.session.schedule import decisions, env_overrides, log_every


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
    return result, {"envs": cfg.seeds, "env_steps": steps, "sim_s": time.perf_counter() - t1,
                    "compile_s": t1 - t0, "wall_s": time.perf_counter() - t0, "compiles": 1}


def _checked(spec: str, actions, vec: VectorEnv) -> np.ndarray:
    """The agent's actions as (B, A) float32, or one line naming it."""
    want = (vec.num_envs, *vec.single_action_space.shape)
    try:
        a = np.asarray(actions, np.float32)
    except (TypeError, ValueError) as err:
        raise InputError("config", "policies", f"{spec!r}: act returned something that is not numbers ({err})") \
            from None
    if a.shape != want:
        raise InputError("config", "policies", f"{spec!r}: act returned actions of shape {a.shape}, not {want}")
    if not np.isfinite(a).all():
        raise InputError("config", "policies", f"{spec!r}: act returned actions that are not finite")
    return a


__all__ = ["run_agent"]
