"""The decision task the exploration env poses, without gymnax: its settings
(:class:`RLConfig`), the observation's layout (:func:`flat_obs`, :func:`split_obs`) and the
reward quantity (:func:`score`). A session's learned policy and the Gymnasium env read these;
only the gymnax env (:mod:`.env`) and training (:mod:`.ppo`) import gymnax, so a session
does not pay its import.

Shapes: K candidates, F features per candidate, G robot features, S samples, N objects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.env import RobotEnv, State
from rosmeery_jax.env import world_data as wd
from rosmeery_jax.rl.candidates import FEATURES, GLOBALS, Offer
from rosmeery_jax.sim import coverage

REWARDS = ("ori", "cori", "coverage")
MAX_CANDIDATES = 256  # K: more would not fit a batch's observations
STEP_LIMIT = 2**31 - 1  # control steps are counted in int32
MAX_EPISODE_S = 1e6  # simulated seconds (11.6 days): the horizon counts control steps in int32


@dataclass(frozen=True)
class RLConfig:
    decide_every: int = 30  # at most this many control steps per decision (3 s)
    episode_s: float = 120.0  # simulated seconds per episode
    candidates: int = 16  # K: new candidate targets per decision (actions: K + 1, 0 keeps the target)
    radius: float = 1.5  # m: half the side of the window a candidate's features describe
    reward: str = "ori"
    reward_scale: float = 10.0
    fail_penalty: float = 0.05

    @property
    def actions(self) -> int:
        return self.candidates + 1

    @property
    def obs_size(self) -> int:
        return self.actions * len(FEATURES) + len(GLOBALS)

    def horizon(self, dt: float) -> int:
        """Control steps per episode."""
        steps = max(1, int(round(self.episode_s / dt)))
        if steps > STEP_LIMIT:
            raise ValueError(f"episode_s {self.episode_s:g} is {steps} control steps of {dt:g} s, more than "
                             f"{STEP_LIMIT} (int32)")
        return steps


def check_rl(rl: RLConfig, source: str, prefix: str = "rl.") -> None:
    """Every RL setting in range; one InputError naming ``source`` and the field."""
    for name, top in (("candidates", MAX_CANDIDATES), ("decide_every", STEP_LIMIT)):
        value = getattr(rl, name)
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= top:
            raise InputError(source, prefix + name, f"{value!r} must be a whole number in [1, {top}]")
    for name, top in (("episode_s", MAX_EPISODE_S), ("radius", math.inf)):
        value = getattr(rl, name)
        if not isinstance(value, (int, float)) or not math.isfinite(value) or not 0 < value <= top:
            raise InputError(source, prefix + name, f"{value!r} must be a finite number > 0"
                             + (f" and at most {top:g}" if top < math.inf else ""))
    for name in ("reward_scale", "fail_penalty"):
        value = getattr(rl, name)
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            raise InputError(source, prefix + name, f"{value!r} must be a finite number")
    if rl.reward not in REWARDS:
        raise InputError(source, prefix + "reward", f"{rl.reward!r} is not one of {', '.join(REWARDS)}")


class Obs(NamedTuple):
    """The observation's two parts (module docstring)."""

    candidates: jax.Array  # (..., K+1, F) float32
    robot: jax.Array  # (..., G) float32


def flat_obs(o: Offer) -> jax.Array:
    """(..., (K+1) * F + G) float32: an offer's observation as the env returns it."""
    lead = o.globals.shape[:-1]
    return jnp.concatenate([o.features.reshape(*lead, -1), o.globals], -1).astype(jnp.float32)


def split_obs(obs: jax.Array) -> Obs:
    """The parts of a flat observation (..., (K+1) * F + G)."""
    lead, g, f = obs.shape[:-1], len(GLOBALS), len(FEATURES)
    return Obs(obs[..., :-g].reshape(*lead, -1, f), obs[..., -g:])


def score(env: RobotEnv, state: State, kind: str) -> jax.Array:
    """The reward quantity (scalar float32) for one env: ORI or cORI over the world's real
    objects (padding objects left out, as the metrics do), or the observed share of all
    object samples."""
    k = env.labelled_knowledge(state)
    ps = coverage.per_object(k.seen, env.sk.table).astype(jnp.float32)
    ps_G = env.sk.ps_G
    real = ps_G < wd.NEVER
    if kind == "coverage":
        return jnp.sum(jnp.where(real, ps, 0.0)) / jnp.sum(jnp.where(real, ps_G, 0.0))
    weighted = ps * env.sk.right_confidence(k) if kind == "cori" else ps
    errors = jnp.where(real, jnp.abs(ps_G - weighted) / ps_G, 0.0)
    return 1.0 - jnp.minimum(1.0, jnp.sum(errors) / jnp.maximum(jnp.sum(real), 1))
