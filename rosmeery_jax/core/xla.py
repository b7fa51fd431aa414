"""``jit``: ``jax.jit`` with the compiler options every compiled function of the project uses.

Two XLA CPU options, measured on the 2-core development machine (docs/performance.md):

- ``xla_cpu_prefer_vector_width=512``: LLVM may use the CPU's 512-bit vectors where it has
  them (XLA stops at 256 by default, for older CPUs that slow their clock on wide vectors).
  The ray casting and coverage kernels are long runs of element-wise float work. Results
  are bitwise those of the default; CPUs without 512-bit vectors ignore it.
- ``xla_cpu_experimental_ynn_fusion_type=""``: dots compiled by XLA itself rather than
  handed to the YNNPACK library, whose per-call cost outweighs the work on MJX's tiny
  per-robot matrices (3 DoF, a few contacts). This changes float rounding in the physics
  (not the model), so results differ from plain ``jax.jit`` in the last bits.

Use ``rosmeery_jax.jit`` for your own compiled loops to get a session's numbers and speed.
The options are passed only when JAX's default backend is the CPU.
"""

from __future__ import annotations

import jax

COMPILER_OPTIONS = {"xla_cpu_prefer_vector_width": 512, "xla_cpu_experimental_ynn_fusion_type": ""}


def jit(fun, **kwargs):
    """``jax.jit(fun, **kwargs)`` compiled with :data:`COMPILER_OPTIONS` on a CPU backend."""
    options = COMPILER_OPTIONS if jax.default_backend() == "cpu" else None
    return jax.jit(fun, compiler_options=options, **kwargs)
