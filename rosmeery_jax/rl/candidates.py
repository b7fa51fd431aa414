"""The learned explorer's choice: candidate targets on the robot's own map, and what the
neighbourhood of each one holds.

Every decision offers K + 1 candidate target poses (K = ``candidates``):

- slot 0 keeps the current target; it is offered (``valid``) only while the navigator is
  still driving to it;
- slots 1..K are drawn uniformly, with replacement, over the cells the robot can reach on
  its own map, each with a uniform yaw: the draw of the ``random`` walker, K times.

A policy that picks uniformly among the new slots is the random walker; a learned one
weighs them by what their surroundings hold. Each slot is described by :data:`FEATURES`,
all from the robot's own maps (nothing hidden): within a square of side 2 x ``radius``
around the candidate, the share of cells its occupancy map holds unknown; the share it
holds occupied, the share visited by the robot (the navigator's trail), and the observed
and labelled object surface per cell (:func:`surface_maps`, averaged), these four x 10 and
capped at 1 (they are sparse: walls and trails are lines); its distance and bearing from
the robot; whether
it is the kept target and whether it is offered. :data:`GLOBALS` describe the robot: whether
the navigator gave up on its last target and how much object surface it has observed.

Shapes: K + 1 slots, F features, P window cells a side, H x W the robot's grid.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from rosmeery_jax.core.grid import wrap_angle
from rosmeery_jax.sim import navigation, occupancy

FEATURES = ("valid", "keep", "distance", "ahead", "left", "unknown", "occupied", "surface", "labelled", "visited")
GLOBALS = ("gave_up", "observed")


class Offer(NamedTuple):
    """One decision's candidates: targets (K+1, 3) poses, features (K+1, F), globals (G,)."""

    targets: jax.Array
    features: jax.Array
    globals: jax.Array


def gave_up(state) -> jax.Array:
    """bool: the navigator gave up on its target (stuck, unreachable or timed out)."""
    return navigation.gave_up(state.nav)


def driving(state) -> jax.Array:
    """bool: the navigator is still working on its target (neither done with it nor idle)."""
    return ~navigation.needs_target(state.nav)


def offer(env, state, current: jax.Array, key: jax.Array, k: int, radius: float) -> Offer:
    """The K + 1 candidates (module docstring) for one env; ``current`` (3,) the target
    the robot drives to (slot 0)."""
    occ = env.occupancy(state)  # (H, W), classified once for the draw and the features
    drawn = env.navigator.draw_reachable(state.nav, state.pose, occ == occupancy.OCCUPIED, key, k)  # (K, 3)
    targets = jnp.concatenate([current[None].astype(jnp.float32), drawn])  # (K+1, 3)
    valid = jnp.ones(k + 1, bool).at[0].set(driving(state))
    keep = jnp.zeros(k + 1, bool).at[0].set(True)
    k_obs = env.labelled_knowledge(state)
    observed = jnp.sum(k_obs.seen.astype(jnp.float32)) / 1000.0
    return Offer(targets, describe(env, state, targets, valid, keep, radius, occ, k_obs),
                 jnp.stack([gave_up(state).astype(jnp.float32), observed]))


def describe(env, state, targets: jax.Array, valid: jax.Array, keep: jax.Array, radius: float,
             occ: jax.Array | None = None, k_obs=None) -> jax.Array:
    """(M, F) the :data:`FEATURES` of any M target poses (M, 3) for one env: ``valid`` (M,)
    which are offered, ``keep`` (M,) which is the kept target. ``occ`` and ``k_obs`` (the
    classified map and the labelled knowledge) are computed if not given."""
    occ = env.occupancy(state) if occ is None else occ
    k_obs = env.labelled_knowledge(state) if k_obs is None else k_obs
    near = _surroundings(env, state, occ, k_obs, targets, radius)
    return jnp.concatenate([_placement(state.pose, targets, valid, keep), near], -1)


def _placement(pose: jax.Array, targets: jax.Array, valid: jax.Array, keep: jax.Array) -> jax.Array:
    """(M, 5): valid, keep, distance / 10 m, and the bearing's cos and sin in the robot's frame."""
    d = targets[:, :2] - pose[:2]
    bearing = wrap_angle(jnp.arctan2(d[:, 1], d[:, 0]) - pose[2])
    return jnp.stack([valid.astype(jnp.float32), keep.astype(jnp.float32), jnp.linalg.norm(d, axis=-1) / 10.0,
                      jnp.cos(bearing), jnp.sin(bearing)], -1)


def _surroundings(env, state, occ: jax.Array, k_obs, targets: jax.Array, radius: float) -> jax.Array:
    """(M, 5): unknown, occupied, surface, labelled (fine grid) and visited (the
    navigator's coarse trail), each the mean over the window around the candidate (all
    but unknown x 10, capped at 1)."""
    grid = env.grid
    surface, labelled = surface_maps(env, k_obs)
    fine = jnp.stack([(occ == occupancy.UNKNOWN) & grid.inside(), occ == occupancy.OCCUPIED, surface, labelled],
                     -1).astype(jnp.float32)  # (H, W, 4)
    coarse = env.navigator.coarse
    near = window_means(fine, grid.cell(targets[:, :2]), max(1, round(radius / grid.resolution)))
    visited = window_means(state.nav.trail[..., None].astype(jnp.float32), coarse.cell(targets[:, :2]),
                           max(1, round(radius / coarse.resolution)))
    sparse = jnp.minimum(10.0 * jnp.concatenate([near[:, 1:], visited], -1), 1.0)
    return jnp.concatenate([near[:, :1], sparse], -1)


def window_means(maps: jax.Array, ij: tuple[jax.Array, jax.Array], half: int) -> jax.Array:
    """(K, L): the mean of each layer of ``maps`` (H, W, L) over the (2 half + 1)^2 cells
    centred on each of the K cells ``ij`` (rows (K,), cols (K,)); cells beyond the grid
    count as 0."""
    side = 2 * half + 1
    padded = jnp.pad(maps, ((half, half), (half, half), (0, 0)))

    def one(i, j):
        window = jax.lax.dynamic_slice(padded, (i, j, 0), (side, side, maps.shape[-1]))
        return window.mean((0, 1))

    return jax.vmap(one)(*ij)


def surface_maps(env, k) -> tuple[jax.Array, jax.Array]:
    """(H, W) each on the robot's grid, from its labelled knowledge ``k``: observed object
    samples per cell, and those of objects it holds a label for, divided by 10 and capped
    at 1. Only observed samples count (a sample's position is what the depth camera
    measured)."""
    table = env.sk.table
    seen = k.seen.astype(jnp.float32)
    held = seen * (k.label >= 0)[table.object]
    i, j = env.grid.cell(jnp.stack([table.points[0], table.points[1]], -1))
    h, w = env.grid.shape
    flat = i * w + j
    count = jax.ops.segment_sum(jnp.stack([seen, held], -1), flat, h * w)  # (H*W, 2)
    count = jnp.minimum(count / 10.0, 1.0).reshape(h, w, 2)
    return count[..., 0], count[..., 1]
