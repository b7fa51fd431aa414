"""A metric plugin: the share of objects the robot holds any label for, over time.

A metric is ``fn(log, truth) -> curve``: ``log`` an ObjectLog whose fields are (..., T, N)
(N objects), ``truth`` the ground-truth table (ps_G, P_G, category per object); the curve
is (..., T) floats, written with jax.numpy.

    rosmeery run --worlds small_office --metrics ori,examples/metric_plugin.py:labelled_share ...
"""

import jax.numpy as jnp


def labelled_share(log, truth):
    return jnp.mean((log.label >= 0).astype(jnp.float32), axis=-1)
