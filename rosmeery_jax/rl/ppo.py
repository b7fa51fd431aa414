"""PPO for the exploration env (:mod:`rosmeery_jax.rl.env`), in the style of PureJaxRL: the
actor-critic, the rollout, GAE and the clipped update in one file, each update one jitted
call (rollout, advantages and every epoch and minibatch inside it).

    cfg = load_train_config("experiments/learned/ppo.toml")
    train(cfg, out="results/train")          # checkpoints, curve.csv, curve.png, policy.msgpack

The network and the policy file are in :mod:`.network`.

Files in the output folder: ``config.json`` (the run's whole configuration; ``--resume``
needs the same), ``checkpoint.msgpack`` (everything the next update needs: parameters,
optimiser, envs, keys, the curve so far; written atomically every ``checkpoint_every``
updates), ``curve.csv`` (the learning curve, at every checkpoint) and ``curve.png`` (drawn at most
every ``PICTURE_EVERY_S`` seconds, and at the end), ``policy.msgpack`` (the
parameters and the env settings the policy needs, for ``learned:PATH``). Checkpoints use
flax's msgpack serialization of the state's leaves (the env state holds MuJoCo arrays,
which orbax's and flax's pytree handlers do not know).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pandas as pd
from flax import serialization
from flax.training.train_state import TrainState
from tqdm import tqdm

from rosmeery_jax.core import config as config_loader
from rosmeery_jax.core import interrupt, overrides, xla
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import claim_folder, folder_lock, output_folder, require_same, write_atomic
from rosmeery_jax.core.specs import expand_ranges
from rosmeery_jax.core.xla import MEMORY_SHARE, memory_bytes
from rosmeery_jax.env import EnvConfig, world_bank
from rosmeery_jax.results.plots import learning_curve
from rosmeery_jax.rl.env import ExplorationEnv
from rosmeery_jax.rl.network import ActorCritic, save_policy
from rosmeery_jax.rl.task import RLConfig, check_rl

ENV_BYTES = 2.5e6  # one env's state, as a session's (docs/performance.md)
ROLLOUT_COPIES = 4  # a rollout's observations are held, shuffled and batched within one update
PICTURE_EVERY_S = 60.0  # curve.png is redrawn at a checkpoint at most this often (and at the end)
NO_EPISODE_NAN = ("return", "final_score")  # NaN in an update where no episode ended: not divergence


@dataclass(frozen=True)
class PPOConfig:
    num_envs: int = 16  # envs stepped together
    num_steps: int = 32  # decisions per env per update
    updates: int = 100
    update_epochs: int = 4
    minibatches: int = 4
    gamma: float = 0.97
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    lr: float = 3e-4
    anneal_lr: bool = True
    seed: int = 0
    checkpoint_every: int = 10


@dataclass(frozen=True)
class TrainConfig:
    """worlds: the training bank (names, paths or procedural ranges); env: EnvConfig
    overrides (``section__field``)."""

    worlds: tuple[str, ...] = ("procedural:office:0-15",)
    ppo: PPOConfig = PPOConfig()
    rl: RLConfig = RLConfig()
    env: dict = field(default_factory=dict)


def load_train_config(path: str | Path | None, **cli) -> TrainConfig:
    """The training configuration of a TOML file (``worlds``, tables ``[ppo]``, ``[rl]``,
    ``[env]``), with ``cli`` values (``ppo__updates=5``) on top; one InputError naming the
    file and field for anything wrong."""
    source = str(path) if path else "command line"
    cfg = config_loader.load(TrainConfig(), path or None, cli, prepare=_prepare)
    _check(cfg, source)
    return cfg


def _prepare(values: dict, source: str) -> dict:
    """``worlds`` (a list of names, as a tuple) and ``env`` (a free table), taken out of
    ``values`` as they are: :func:`_check` checks them."""
    given = {"env": values.pop("env", {})}
    if "worlds" in values:
        worlds = values.pop("worlds")
        given["worlds"] = tuple(worlds) if isinstance(worlds, list) else worlds
    return given


def _check(cfg: TrainConfig, source: str) -> None:
    if not isinstance(cfg, TrainConfig):
        raise TypeError(f"train takes a TrainConfig (load_train_config(path)), not {type(cfg).__name__}")
    if isinstance(cfg.worlds, str) or not cfg.worlds or not all(isinstance(w, str) and w for w in cfg.worlds):
        raise InputError(source, "worlds", f"{cfg.worlds!r} must be a non-empty list of world names")
    if not isinstance(cfg.env, dict):
        raise InputError(source, "env", f"{cfg.env!r} must be a table of EnvConfig overrides")
    overrides.check_fields(cfg.ppo, source, "ppo.")
    overrides.check_fields(cfg.rl, source, "rl.")
    EnvConfig.from_table(cfg.env, source)
    expand_ranges(cfg.worlds)  # a range refused by its size, before anything is built
    check_rl(cfg.rl, source)
    p = cfg.ppo
    for name in ("num_envs", "num_steps", "updates", "update_epochs", "minibatches", "checkpoint_every"):
        if getattr(p, name) < 1:
            raise InputError(source, f"ppo.{name}", f"{getattr(p, name)!r} must be a whole number >= 1")
    for name in ("lr", "clip_eps", "max_grad_norm"):
        if not 0 < getattr(p, name) < math.inf:
            raise InputError(source, f"ppo.{name}", f"{getattr(p, name)!r} must be a finite number > 0")
    for name in ("ent_coef", "vf_coef"):
        if not 0 <= getattr(p, name) < math.inf:
            raise InputError(source, f"ppo.{name}", f"{getattr(p, name)!r} must be a finite number >= 0")
    if (p.num_envs * p.num_steps) % p.minibatches:
        raise InputError(source, "ppo.minibatches", f"must divide num_envs x num_steps ({p.num_envs * p.num_steps})")
    for name in ("gamma", "gae_lambda"):
        if not 0 < getattr(p, name) <= 1:
            raise InputError(source, f"ppo.{name}", "must be in (0, 1]")
    _check_size(cfg, source)


def _check_size(cfg: TrainConfig, source: str) -> None:
    """Refuse a training batch that cannot fit in this machine's memory: the envs' states and
    one update's rollout of observations."""
    p, rl = cfg.ppo, cfg.rl
    obs = rl.obs_size * 4 + 64  # bytes of one observation and its transition
    need = float(p.num_envs) * (ENV_BYTES + p.num_steps * obs * ROLLOUT_COPIES)
    have = memory_bytes()
    if need > MEMORY_SHARE * have:
        raise InputError(source, "ppo.num_envs", f"{p.num_envs:,} envs x {p.num_steps} steps need about "
                         f"{need / 1e9:,.1f} GB, more than this machine's {have / 1e9:.1f} GB allows")


class Transition(NamedTuple):
    obs: jax.Array  # (..., (K+1) * F + G)
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    reward: jax.Array
    done: jax.Array
    info: dict


class Runner(NamedTuple):
    """Everything one update reads and writes (the checkpoint)."""

    train: TrainState
    env_state: Any
    obs: jax.Array  # (..., (K+1) * F + G)
    key: jax.Array


def make_env(cfg: TrainConfig) -> ExplorationEnv:

    return ExplorationEnv(world_bank(cfg.worlds, EnvConfig().with_overrides("config", **cfg.env)), cfg.rl)


def init_runner(cfg: TrainConfig, env: ExplorationEnv) -> Runner:
    p = cfg.ppo
    key = jax.random.key(p.seed)
    key, k_net, k_env = jax.random.split(key, 3)
    reset = xla.jit(jax.vmap(env.reset, in_axes=(0, None)))
    obs, state = reset(jax.random.split(k_env, p.num_envs), env.default_params)
    net = ActorCritic()
    params = net.init(k_net, jax.tree.map(lambda a: a[0], obs))
    steps_per_update = p.update_epochs * p.minibatches
    lr = (optax.linear_schedule(p.lr, 0.0, p.updates * steps_per_update) if p.anneal_lr else p.lr)
    tx = optax.chain(optax.clip_by_global_norm(p.max_grad_norm), optax.adam(lr, eps=1e-5))
    train = TrainState.create(apply_fn=net.apply, params=params, tx=tx)
    train = train.replace(step=jnp.array(0, jnp.int32))
    # Committed to the device, as an update's results are: else the second update compiles again.
    return jax.device_put(Runner(train, state, obs, key), jax.devices()[0])


def make_update(cfg: TrainConfig, env: ExplorationEnv):
    """The jitted ``update(runner) -> (runner, stats)``: one rollout of ``num_steps``
    decisions in every env, GAE, then ``update_epochs`` x ``minibatches`` clipped PPO steps."""
    p = cfg.ppo
    params_env = env.default_params
    step_env = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def rollout(runner: Runner, _):
        train, state, obs, key = runner
        key, k_act, k_step = jax.random.split(key, 3)
        logits, value = train.apply_fn(train.params, obs)
        action = jax.random.categorical(k_act, logits)
        log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), action[:, None], -1)[:, 0]
        next_obs, state, reward, done, info = step_env(jax.random.split(k_step, p.num_envs), state, action, params_env)
        return Runner(train, state, next_obs, key), Transition(obs, action, log_prob, value, reward, done, info)

    def advantages(traj: Transition, last_value):
        """GAE over the rollout (T, B), reversed scan."""

        def back(carry, t):
            gae, next_value = carry
            delta = t.reward + p.gamma * next_value * (1 - t.done) - t.value
            gae = delta + p.gamma * p.gae_lambda * (1 - t.done) * gae
            return (gae, t.value), gae

        _, adv = jax.lax.scan(back, (jnp.zeros_like(last_value), last_value), traj, reverse=True)
        return adv, adv + traj.value

    def loss(params, apply_fn, batch: Transition, adv, target):
        logits, value = apply_fn(params, batch.obs)
        logp_all = jax.nn.log_softmax(logits)
        logp = jnp.take_along_axis(logp_all, batch.action[:, None], -1)[:, 0]
        value_clipped = batch.value + jnp.clip(value - batch.value, -p.clip_eps, p.clip_eps)
        value_loss = 0.5 * jnp.maximum((value - target) ** 2, (value_clipped - target) ** 2).mean()
        ratio = jnp.exp(logp - batch.log_prob)
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        actor = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - p.clip_eps, 1 + p.clip_eps) * adv).mean()
        entropy = -(jnp.exp(logp_all) * logp_all).sum(-1).mean()
        total = actor + p.vf_coef * value_loss - p.ent_coef * entropy
        return total, (value_loss, actor, entropy)

    def epoch(carry, _):
        train, traj, adv, target, key = carry
        key, sub = jax.random.split(key)
        n = p.num_envs * p.num_steps
        flat = jax.tree.map(lambda a: a.reshape(n, *a.shape[2:]), (traj, adv, target))
        order = jax.random.permutation(sub, n)
        mini = jax.tree.map(lambda a: a[order].reshape(p.minibatches, n // p.minibatches, *a.shape[1:]), flat)

        def minibatch(train, batch):
            (total, parts), grads = jax.value_and_grad(loss, has_aux=True)(train.params, train.apply_fn, *batch)
            return train.apply_gradients(grads=grads), (total, *parts)

        train, losses = jax.lax.scan(minibatch, train, mini)
        return (train, traj, adv, target, key), losses

    @xla.jit
    def update(runner: Runner):
        runner, traj = jax.lax.scan(rollout, runner, None, length=p.num_steps)
        _, last_value = runner.train.apply_fn(runner.train.params, runner.obs)
        adv, target = advantages(traj, last_value)
        key, sub = jax.random.split(runner.key)
        (train, *_), losses = jax.lax.scan(epoch, (runner.train, traj, adv, target, sub), None,
                                           length=p.update_epochs)
        finished = traj.done.sum()
        stats = {"episodes": finished, "env_steps": traj.info["steps"].sum(),
                 "return": jnp.where(finished > 0, traj.info["return"].sum() / jnp.maximum(finished, 1), jnp.nan),
                 "final_score": jnp.where(finished > 0, traj.info["score"].sum() / jnp.maximum(finished, 1), jnp.nan),
                 "reward": traj.reward.mean(), "loss": losses[0].mean(), "value_loss": losses[1].mean(),
                 "actor_loss": losses[2].mean(), "entropy": losses[3].mean()}
        return runner._replace(train=train, key=key), stats

    return update


# --- Checkpoints and the policy file -------------------------------------------------


def _to_host(tree) -> dict:
    """The pytree's leaves as numpy arrays (PRNG keys as their raw data), keyed by index."""
    def host(a):
        a = jnp.asarray(a)
        return np.asarray(jax.random.key_data(a) if jnp.issubdtype(a.dtype, jax.dtypes.prng_key) else a)

    return {str(i): host(a) for i, a in enumerate(jax.tree.leaves(tree))}


def _from_host(template, saved: dict):
    leaves, treedef = jax.tree.flatten(template)
    if len(saved) != len(leaves):
        raise ValueError("the checkpoint does not match this configuration")
    out = []
    for i, t in enumerate(leaves):
        a = saved[str(i)]
        t = jnp.asarray(t)
        if jnp.issubdtype(t.dtype, jax.dtypes.prng_key):
            out.append(jax.random.wrap_key_data(jnp.asarray(a), impl=jax.random.key_impl(t)))
        else:
            if a.shape != t.shape or a.dtype != t.dtype:
                raise ValueError("the checkpoint does not match this configuration")
            out.append(jnp.asarray(a))
    return jax.device_put(jax.tree.unflatten(treedef, out), jax.devices()[0])


def save_checkpoint(path: Path, runner: Runner, done: int, curve: list[dict]) -> None:
    blob = serialization.msgpack_serialize({"update": done, "curve": json.dumps(curve), "state": _to_host(runner)})
    write_atomic(path, blob)


def load_checkpoint(path: Path, template: Runner) -> tuple[Runner, int, list[dict]]:
    try:
        saved = serialization.msgpack_restore(path.read_bytes())
        return _from_host(template, saved["state"]), int(saved["update"]), json.loads(saved["curve"])
    except (KeyError, TypeError, ValueError) as err:
        raise InputError(str(path), "file", f"not a checkpoint of this configuration ({err})") from None


# --- The training loop ---------------------------------------------------------------


def train(cfg: TrainConfig, out: str | Path, resume: bool = False, progress: bool = True) -> Path:
    """Train to ``cfg.ppo.updates`` updates, writing into ``out`` (module docstring); ``cfg``
    is checked first (:func:`load_train_config` checks a file's, a TrainConfig built in Python is
    checked here)."""
    _check(cfg, "config")
    out = Path(out)
    record = json.loads(json.dumps(asdict(cfg)))
    fresh = _check_out(out, record, resume)
    with output_folder(out), folder_lock(out):
        _check_out(out, record, resume)  # again under the lock: another command may have started
        write_atomic(out / "config.json", json.dumps(record, indent=2))
        try:
            with interrupt.deferred():
                _train(cfg, out, resume, progress)
        except BaseException:
            if fresh and not (out / "checkpoint.msgpack").exists():
                (out / "config.json").unlink(missing_ok=True)  # nothing trained: the same command starts afresh
            raise
    return out


def _train(cfg: TrainConfig, out: Path, resume: bool, progress: bool) -> None:
    """The update loop: checkpoints every ``checkpoint_every`` updates, then the policy."""
    env = make_env(cfg)
    runner = init_runner(cfg, env)
    done, curve = 0, []
    if resume and (out / "checkpoint.msgpack").exists():
        runner, done, curve = load_checkpoint(out / "checkpoint.msgpack", runner)
    update = make_update(cfg, env)
    p = cfg.ppo
    bar = tqdm(total=p.updates, initial=done, disable=not progress, unit="update")
    t0 = drawn = time.perf_counter()
    steps = start = curve[-1]["env_steps"] if curve else 0
    for u in range(done, p.updates):
        interrupt.check()  # Ctrl-C stops between updates; the last checkpoint resumes
        runner, stats = update(runner)
        stats = {k: float(v) for k, v in stats.items()}
        _check_finite(out, u + 1, stats, runner.train.params)  # before anything of this update is saved
        elapsed = time.perf_counter() - t0
        steps += int(stats.pop("env_steps"))  # control steps the decisions took, summed over envs
        curve.append({"update": u + 1, "env_steps": steps, **stats, "wall_s": elapsed})
        bar.update(1)
        bar.set_postfix_str(f"{_last_return(curve)}, {(steps - start) / elapsed:,.0f} env-steps/s")
        if (u + 1) % p.checkpoint_every == 0 or u + 1 == p.updates:
            save_checkpoint(out / "checkpoint.msgpack", runner, u + 1, curve)
            # the last update's picture is drawn once, below
            picture = u + 1 < p.updates and time.perf_counter() - drawn >= PICTURE_EVERY_S
            _write_curve(out, curve, picture)
            drawn = time.perf_counter() if picture else drawn
    bar.close()
    save_policy(out / "policy.msgpack", cfg.rl, cfg.env, runner.train.params)
    _write_curve(out, curve, picture=True)


def _last_return(curve: list[dict]) -> str:
    """The progress bar's return: the latest update's where an episode ended in it, else the
    last one that had one, named by its update (an update where none ended has no return)."""
    for row in reversed(curve):
        if math.isfinite(row["return"]):
            latest = row is curve[-1]
            return f"return {row['return']:.3f}" + ("" if latest else f" (update {row['update']})")
    return "return - (no episode ended yet)"


def _check_finite(out: Path, update: int, stats: dict, params) -> None:
    """Stop a diverged run with one line, before its NaN state is saved: the last checkpoint
    and curve stay those of the last good update."""
    bad = next((k for k, v in stats.items() if k not in NO_EPISODE_NAN and not math.isfinite(v)), None)
    if bad is None and not all(bool(jnp.isfinite(a).all()) for a in jax.tree.leaves(params)):
        bad = "the parameters"
    if bad is not None:
        raise InputError(str(out), f"update {update}", f"training diverged ({bad} not finite): stopped, the last "
                         "good checkpoint kept (a smaller ppo.lr or max_grad_norm?)")


def _check_out(out: Path, record: dict, resume: bool) -> bool:
    """Check the training folder; returns whether it is new."""
    old = claim_folder(out, resume, holds="a training run")
    if old is not None:
        require_same(out / "config.json", old, record, ("worlds", "ppo", "rl", "env"))
    return old is None


def read_curve(out: str | Path):
    """The learning curve of a training folder (pandas DataFrame)."""
    return pd.read_csv(Path(out) / "curve.csv")


def _write_curve(out: Path, curve: list[dict], picture: bool) -> None:
    """curve.csv, and with ``picture`` curve.png (drawing it takes a quarter second: short
    updates would spend more time drawing than training)."""
    table = pd.DataFrame(curve)
    write_atomic(out / "curve.csv", table.to_csv(index=False))
    if picture:
        learning_curve(table, out / "curve.png")
