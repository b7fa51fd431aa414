"""The learned explorer's network and its policy file.

The network: three stride-2 3x3 convolutions (16, 32, 32 channels) over the map crops
(C, C, 4), flattened, joined with the pose features, one 128-unit dense layer, then the
policy logits (G*G goal cells) and the value. Actions are sampled from the softmax.

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
from rosmeery_jax.rl.env import Obs, RLConfig

POLICY_FORMAT = "rosmeery-learned-1"


class ActorCritic(nn.Module):
    """(Obs with leading axes) -> (logits (..., A), value (...,))."""

    actions: int

    @nn.compact
    def __call__(self, obs: Obs):
        x = obs.maps
        for features in (16, 32, 32):
            x = nn.relu(nn.Conv(features, (3, 3), strides=2)(x))
        x = jnp.concatenate([x.reshape(*x.shape[:-3], -1), obs.pose], -1)
        x = nn.relu(nn.Dense(128)(x))
        logits = nn.Dense(self.actions, kernel_init=nn.initializers.orthogonal(0.01))(x)
        value = nn.Dense(1, kernel_init=nn.initializers.orthogonal(1.0))(x)[..., 0]
        return logits, value



def save_policy(path: str | Path, rl: RLConfig, env: dict, params) -> None:
    """The trained policy: parameters plus the env settings it was trained with."""
    blob = {"format": POLICY_FORMAT, "rl": json.dumps(asdict(rl)), "env": json.dumps(env),
            "params": serialization.to_state_dict(jax.tree.map(np.asarray, params))}
    write_atomic(path, serialization.msgpack_serialize(blob))


def load_policy(path: str | Path) -> tuple[RLConfig, dict, Any]:
    """(RLConfig, env overrides, params) of a policy file; one InputError if it is not one."""
    path = Path(path)
    try:
        saved = serialization.msgpack_restore(path.read_bytes())
        if saved.get("format") != POLICY_FORMAT:
            raise ValueError(f"format {saved.get('format')!r}, expected {POLICY_FORMAT!r}")
        rl = RLConfig(**json.loads(saved["rl"]))
        return rl, json.loads(saved["env"]), jax.tree.map(jnp.asarray, saved["params"])
    except FileNotFoundError:
        raise InputError(str(path), "file", "not found") from None
    except (OSError, KeyError, TypeError, ValueError, AttributeError) as err:
        raise InputError(str(path), "file", f"not a rosmeery-jax policy file ({err})") from None
