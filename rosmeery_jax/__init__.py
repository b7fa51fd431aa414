"""rosmeery-jax: a batched, JAX-vectorised benchmark for robot semantic mapping.

The names a notebook needs, importable from the top (docs/api.md lists them)::

    import rosmeery_jax as rj
    env = rj.make("kitchen")                       # one robot in one world
    cfg = rj.SessionConfig(worlds=("kitchen",), duration=60.0, detector="oracle", out="results/try")
    out = rj.Session(cfg.validate()).run()         # worlds x policies x seeds, one batch
    df = rj.load_results(out)                      # the long metrics table

Data flows one way: world -> step -> logs -> metrics -> results. Each name is imported on
first use, so ``import rosmeery_jax`` stays quick and the command line loads only what it
runs; torch is imported only by the detector.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

# public name -> (module, attribute)
_API = {
    "make": ("rosmeery_jax.env", "make"),
    "RobotEnv": ("rosmeery_jax.env", "RobotEnv"),
    "EnvConfig": ("rosmeery_jax.env", "EnvConfig"),
    "State": ("rosmeery_jax.env", "State"),
    "world_bank": ("rosmeery_jax.env", "world_bank"),
    "WorldBank": ("rosmeery_jax.env", "WorldBank"),
    "load_world": ("rosmeery_jax.world", "load_world"),
    "world_names": ("rosmeery_jax.world", "world_names"),
    "Session": ("rosmeery_jax.session", "Session"),
    "SessionConfig": ("rosmeery_jax.session", "SessionConfig"),
    "load_config": ("rosmeery_jax.session", "load_config"),
    "load_results": ("rosmeery_jax.results.tables", "load"),
    "join_results": ("rosmeery_jax.session.join", "join"),
    "compute_metrics": ("rosmeery_jax.metrics.indices", "compute"),
    "register_metric": ("rosmeery_jax.metrics.indices", "register"),
    "summarize": ("rosmeery_jax.metrics.indices", "summarize"),
    "evaluate": ("rosmeery_jax.metrics.map_score", "evaluate"),
    "read_map": ("rosmeery_jax.metrics.map_score", "read_map"),
    "plot_results": ("rosmeery_jax.results.plots", "plot_results"),
    "Mapper": ("rosmeery_jax.mapping.protocol", "Mapper"),
    "MapState": ("rosmeery_jax.mapping.protocol", "MapState"),
    "Frame": ("rosmeery_jax.mapping.protocol", "Frame"),
    "DepthFrame": ("rosmeery_jax.mapping.protocol", "DepthFrame"),
    "Camera": ("rosmeery_jax.mapping.protocol", "Camera"),
    "Policy": ("rosmeery_jax.policies", "Policy"),
    "POLICIES": ("rosmeery_jax.policies", "POLICIES"),
    "make_policy": ("rosmeery_jax.policies", "make_policy"),
    "ExplorationEnv": ("rosmeery_jax.rl.env", "ExplorationEnv"),
    "RLConfig": ("rosmeery_jax.rl.task", "RLConfig"),
    "train": ("rosmeery_jax.rl.ppo", "train"),
    "load_train_config": ("rosmeery_jax.rl.ppo", "load_train_config"),
    "jit": ("rosmeery_jax.core.xla", "jit"),
    "InputError": ("rosmeery_jax.core.errors", "InputError"),
}
__all__ = sorted(_API)


def __getattr__(name: str):
    if name not in _API:
        raise AttributeError(f"module 'rosmeery_jax' has no attribute {name!r}")
    module, attr = _API[name]
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
