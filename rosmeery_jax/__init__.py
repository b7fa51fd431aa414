"""rosmeery-jax: a batched, JAX-vectorised benchmark for robot semantic mapping.

Data flows one way: world -> step -> logs -> metrics -> results. This package's core
imports no torch; the detector lives in its own package.
"""

__version__ = "0.1.0"
