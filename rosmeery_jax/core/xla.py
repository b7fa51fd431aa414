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

import os
from pathlib import Path

import jax

COMPILER_OPTIONS = {"xla_cpu_prefer_vector_width": 512, "xla_cpu_experimental_ynn_fusion_type": ""}


def jit(fun, **kwargs):
    """``jax.jit(fun, **kwargs)`` compiled with :data:`COMPILER_OPTIONS` on a CPU backend."""
    options = COMPILER_OPTIONS if jax.default_backend() == "cpu" else None
    return jax.jit(fun, compiler_options=options, **kwargs)


def compilation_cache(enabled: bool) -> str | None:
    """Turn JAX's persistent compilation cache on (a rerun loads its compiled functions in
    seconds instead of compiling them again) in ``$JAX_COMPILATION_CACHE_DIR``, else
    ``$XDG_CACHE_HOME/rosmeery-jax/jax`` (``~/.cache/...``); or off. Returns the folder."""
    if not enabled:
        jax.config.update("jax_enable_compilation_cache", False)
        return None
    folder = os.environ.get("JAX_COMPILATION_CACHE_DIR") or str(
        Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "rosmeery-jax" / "jax")
    jax.config.update("jax_compilation_cache_dir", folder)
    return folder


def cores() -> int:
    """The CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def started() -> bool:
    """Whether JAX has started its backends (after which XLA_FLAGS is read no more)."""
    from jax._src import xla_bridge  # JAX has no public way to ask whether it has started

    return xla_bridge.backends_are_initialized()


def host_devices(n: int) -> None:
    """Let XLA make ``n`` devices of the CPU's cores, for ``devices`` on a machine without
    accelerators. XLA reads the flag when JAX starts, so once JAX has started (a notebook,
    a test run) the environment is left as it is: child processes would inherit it."""
    if started():
        return
    if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={n}".strip()


MEMORY_SHARE = 0.8  # of this machine's memory, what one run (batch, logs) may plan to take


def memory_bytes() -> float:
    """This machine's memory (8 GB where the system does not say)."""
    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 8e9
