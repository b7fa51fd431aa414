"""The built-in worlds: the four paper worlds as MJCF files with their semantics, and the
notes on how each was authored (NOTES.md). Shipped in the package as
``rosmeery_jax.builtin_worlds``; loaded by name with ``rosmeery_jax.world.load_world``."""
