"""rosmeery-jax: a batched, JAX-vectorised benchmark for robot semantic mapping.

Data flows one way: world -> step -> logs -> metrics -> results. This package's core
imports no torch; the detector lives in its own package.
"""

__version__ = "0.1.0"


def __getattr__(name: str):
    # ``rosmeery_jax.make`` without importing jax / MuJoCo for CLI paths that never need them.
    if name == "make":
        from rosmeery_jax.env import make

        return make
    if name == "jit":
        from rosmeery_jax.core.xla import jit

        return jit
    raise AttributeError(f"module 'rosmeery_jax' has no attribute {name!r}")
