"""The learned explorer's network and its policy file.

The network scores each candidate of the observation (:func:`~rosmeery_jax.rl.task.split_obs`)
alone: its features, joined with the robot's, pass through two 64-unit dense layers shared
by every candidate to one logit; a candidate not on offer gets a logit of -1e9. The value
reads the mean of the offered candidates' hidden features and the robot's features (one
64-unit layer). So the network does not depend on the number of candidates, and a
network that has learned nothing picks uniformly among them: the random walker. Actions are
sampled from the softmax.

A policy file (``policy.msgpack``) holds the parameters and the settings the policy needs
(its :class:`RLConfig` and env overrides), in flax's msgpack serialization; the trainer
(:mod:`.ppo`) writes it and the ``learned`` policy reads it.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import write_atomic
from rosmeery_jax.rl.candidates import FEATURES
from rosmeery_jax.rl.task import RLConfig, check_rl, split_obs

POLICY_FORMAT = "rosmeery-learned-2"  # 1: the goal-grid network, no longer read


class ActorCritic(nn.Module):
    """Flat observations (..., (K+1) * F + G) -> (logits (..., K+1), value (...,))."""

    @nn.compact
    def __call__(self, flat: jax.Array):
        obs = split_obs(flat)
        k = obs.candidates.shape[-2]
        robot = jnp.broadcast_to(obs.robot[..., None, :], (*obs.robot.shape[:-1], k, obs.robot.shape[-1]))
        x = jnp.concatenate([obs.candidates, robot], -1)  # (..., K+1, F + G)
        for _ in range(2):
            x = nn.relu(nn.Dense(64)(x))
        offered = obs.candidates[..., FEATURES.index("valid")] > 0.5  # (..., K+1)
        logits = nn.Dense(1, kernel_init=nn.initializers.orthogonal(0.01))(x)[..., 0]
        logits = jnp.where(offered, logits, -1e9)
        w = offered.astype(x.dtype)[..., None]
        pooled = (x * w).sum(-2) / jnp.maximum(w.sum(-2), 1.0)
        v = nn.relu(nn.Dense(64)(jnp.concatenate([pooled, obs.robot], -1)))
        value = nn.Dense(1, kernel_init=nn.initializers.orthogonal(1.0))(v)[..., 0]
        return logits, value


def save_policy(path: str | Path, rl: RLConfig, env: dict, params) -> None:
    """The trained policy: parameters plus the env settings it was trained with."""
    blob = {"format": POLICY_FORMAT, "rl": json.dumps(asdict(rl)), "env": json.dumps(env),
            "params": serialization.to_state_dict(jax.tree.map(np.asarray, params))}
    write_atomic(path, serialization.msgpack_serialize(blob))


def load_policy(path: str | Path) -> tuple[RLConfig, dict, Any]:
    """(RLConfig, env overrides, params as numpy arrays) of a policy file, checked whole:
    its settings in range, its network's shapes those the settings imply, every parameter
    finite. One InputError naming the file for anything else."""
    path = Path(path)
    try:
        saved = serialization.msgpack_restore(path.read_bytes())
        if not isinstance(saved, dict) or saved.get("format") != POLICY_FORMAT:
            raise ValueError(f"format {saved.get('format') if isinstance(saved, dict) else None!r}, expected "
                             f"{POLICY_FORMAT!r}")
        rl = RLConfig(**json.loads(saved["rl"]))
        env = json.loads(saved["env"])
        params = jax.tree.map(np.asarray, saved["params"])
    except FileNotFoundError:
        raise InputError(str(path), "file", "not found") from None
    except (OSError, KeyError, TypeError, ValueError, AttributeError, RecursionError) as err:
        raise InputError(str(path), "file", f"not a rosmeery-jax policy file ({err})") from None
    check_rl(rl, str(path))
    if not isinstance(env, dict):
        raise InputError(str(path), "env", "must be a table of EnvConfig overrides")
    _check_params(path, rl, params)
    return rl, env, params


def _check_params(path: Path, rl: RLConfig, params) -> None:
    """The parameters have the network's structure and shapes for ``rl`` and are finite."""
    blank = jax.ShapeDtypeStruct((rl.obs_size,), jnp.float32)
    want = jax.eval_shape(ActorCritic().init, jax.random.key(0), blank)
    got = jax.tree.map(lambda a: jax.ShapeDtypeStruct(np.shape(a), np.asarray(a).dtype), params)
    if jax.tree.structure(got) != jax.tree.structure(want):
        raise InputError(str(path), "params", "are not those of the learned explorer's network")
    for (where, w), g in zip(jax.tree_util.tree_flatten_with_path(want)[0], jax.tree.leaves(got)):
        name = jax.tree_util.keystr(where)
        if g.shape != w.shape:
            raise InputError(str(path), f"params{name}", f"shape {g.shape}, but the network needs {w.shape}")
        if not np.issubdtype(g.dtype, np.floating):
            raise InputError(str(path), f"params{name}", f"dtype {g.dtype} is not a float")
    bad = next((jax.tree_util.keystr(k) for k, a in jax.tree_util.tree_flatten_with_path(params)[0]
                if not np.isfinite(a).all()), None)
    if bad is not None:
        raise InputError(str(path), f"params{bad}", "holds NaN or infinite values (a diverged training run?)")
