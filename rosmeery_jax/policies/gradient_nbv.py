"""``gradient_nbv``: next-best views refined by gradient ascent on expected soft coverage.

Everything it uses is the robot's own: its occupancy map, the object surface its camera
has observed, the labels it holds, and its current depth frame. No ground truth.

**Belief.** On a coarse grid (``resolution``), a *belief point* stands at every cell within
``object_radius`` of surface the robot has observed on an object it holds a label for, that
its map shows occupied (the laser saw something there) or has not resolved at all (the
object's unseen sides and back lie in space its sensors have not reached yet), at
``point_height``. Cells the map shows free hold none. Its weight is what the robot believes
is still unseen of it: one minus its *viewed* probability, the largest of any view so far:
of the real depth frame at every decision (soft coverage,
:func:`rosmeery_jax.sim.coverage.observed_soft`, with a depth tolerance of 1.5 cells since a
point stands at its cell's centre) and, when a view target is reached, of what that view
was expected to show; zero where the camera has observed object surface in that cell.

**Expected gain of a view** q = (x, y, yaw): the soft coverage of the belief points from q,
weighted, with the depth the camera would see there *rendered from the robot's own map*: a
differentiable raycast per image column through the map's soft opacity (the share of each
cell the map shows occupied; ``belief_opacity`` for an unresolved cell holding a belief
point, since the robot believes an object is there; other cells clear), as an expected
first-hit depth. Without that, a view would promise the far side of an object through its
unresolved near side.

**Refinement.** ``candidates`` views start ``ring_radius`` from belief points drawn by
weight (each from its own direction of a ring), facing them; ``iterations`` steps of Adam
(optax, ``learning_rate``) climb gain - ``distance_cost`` x travel - ``blocked_cost`` x
opacity under the robot, by gradients through the coverage and the rendered depth. The
best refined view, by gain per metre of travel (as ``semantic_nbv`` scores), on a cell the
map shows free and clear, becomes the navigator's target until it is reached or given up;
with no view worth ``min_gain`` samples it explores like ``frontier``. ``min_gain`` is
0.01: with 1 sample, its first setting, views of a little unseen surface were refused and the
robot stood still once the frontier was exhausted (docs/learned.md).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from rosmeery_jax.core import grid
from rosmeery_jax.policies.base import needs_target
from rosmeery_jax.policies.frontier import FrontierState, ViewPolicy, blocked_within
from rosmeery_jax.policies.semantic_nbv import facing
from rosmeery_jax.rl.candidates import surface_maps
from rosmeery_jax.sim import coverage, occupancy
from rosmeery_jax.sim.coverage import CoverageConfig, SampleTable


class GradientNBVState(NamedTuple):
    target: jax.Array  # (3,)
    viewed: jax.Array  # (Hc * Wc,) probability each coarse cell's belief point was viewed
    frontier: FrontierState
    exploring: jax.Array  # bool: the current target came from the frontier fallback


class GradientNBVPolicy(ViewPolicy):
    name = "gradient_nbv"

    def __init__(self, env, resolution: float = 0.2, object_radius: float = 0.6, point_height: float = 0.4,
                 candidates: int = 8, ring_radius: float = 1.5, iterations: int = 12, learning_rate: float = 0.08,
                 distance_cost: float = 0.02, blocked_cost: float = 5.0, min_gain: float = 0.01,
                 clearance: float = 0.3, march: float = 0.15, belief_opacity: float = 0.5):
        super().__init__(env)
        self.f = max(1, int(round(resolution / env.grid.resolution)))
        self.grow_object = max(1, int(round(object_radius / (env.grid.resolution * self.f))))
        self.grow_clear = max(1, int(round(clearance / env.grid.resolution)))
        self.height, self.iterations = point_height, iterations
        self.ring_radius, self.lr = ring_radius, learning_rate
        self.distance_cost, self.blocked_cost, self.min_gain = distance_cost, blocked_cost, min_gain
        self.belief_opacity = belief_opacity
        cam = env.config.camera
        self.cam = cam
        # A belief point stands at a cell's centre, up to a cell from the surface it stands
        # for: a depth tolerance of about a cell's diagonal, and no facing test (no normals).
        self.cov = CoverageConfig(soft=True, min_facing=-1.0, temperature=0.05, abs_tol=1.5 * resolution)
        f = cam.focal(cam.width)
        self.column_angles = jnp.asarray(np.arctan((cam.width / 2 - (np.arange(cam.width) + 0.5)) / f), jnp.float32)
        steps = int(np.ceil(env.config.mapping.max_range / march))
        self.steps = jnp.asarray((np.arange(steps) + 0.5) * march, jnp.float32)
        self.far = float(self.steps[-1] + march)
        ang = np.arange(candidates) * 2 * np.pi / candidates
        self.ring = jnp.asarray(np.stack([np.cos(ang), np.sin(ang)], -1) * ring_radius, jnp.float32)
        self.shape = env.grid.coarse(self.f).shape

    @property
    def coarse(self):
        return self.env.grid.coarse(self.f)

    def init(self, key):
        return GradientNBVState(jnp.zeros(3, jnp.float32), jnp.zeros(self.shape[0] * self.shape[1], jnp.float32),
                                self.frontier.init(key), jnp.bool_(True))

    # --- What the robot believes ----------------------------------------------------

    def opacity(self, state) -> jax.Array:
        """(Hc, Wc) in [0, 1]: the share of each coarse cell the robot's map shows occupied."""
        occ = (self.env.occupancy(state) == occupancy.OCCUPIED).astype(jnp.float32)
        h, w = occ.shape
        hc, wc = self.shape
        occ = jnp.pad(occ, ((0, hc * self.f - h), (0, wc * self.f - w)))
        return occ.reshape(hc, self.f, wc, self.f).mean(axis=(1, 3))

    def belief(self, state) -> tuple[SampleTable, jax.Array]:
        """Belief points (a SampleTable of Hc * Wc points, one per coarse cell) and which
        cells hold one (Hc * Wc,) float: weight them by ``1 - viewed``."""
        surface, labelled = surface_maps(self.env, self.env.labelled_knowledge(state))  # (H, W) observed / labelled object surface
        near = grid.block_any(labelled > 0, self.f)
        for _ in range(self.grow_object):
            near = grid.grow(near)
        seen_here = grid.block_any(surface > 0, self.f)
        occ = self.env.occupancy(state)
        free = grid.block_any(occ == occupancy.FREE, self.f) & ~grid.block_any(occ == occupancy.OCCUPIED, self.f)
        held = (~free & near & ~seen_here & self.coarse.inside()).reshape(-1).astype(jnp.float32)
        return self.belief_points(), held

    def belief_points(self) -> SampleTable:
        """Hc * Wc points, one at each coarse cell's centre, ``point_height`` up."""
        xy = self.coarse.centers().reshape(-1, 2)
        points = jnp.concatenate([xy.T, jnp.full((1, xy.shape[0]), self.height, jnp.float32)], 0)
        return SampleTable(points, jnp.zeros_like(points), jnp.zeros(xy.shape[0], jnp.int32), 1)

    # --- The differentiable view model ----------------------------------------------

    def render(self, opacity: jax.Array, pose: jax.Array) -> jax.Array:
        """(h, w) expected depth along the optical axis from ``pose`` through the map's
        opacity: per column, the expected first-hit range of a ray marched in ``steps``."""
        origin = pose[:2] + self.cam.mount_x * jnp.stack([jnp.cos(pose[2]), jnp.sin(pose[2])])
        angle = pose[2] + self.column_angles  # (w,)
        pts = origin + self.steps[:, None, None] * jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1)  # (K, w, 2)
        alpha = bilinear(opacity, self.coarse, pts)  # (K, w)
        clear = jnp.cumprod(1.0 - alpha, axis=0)
        before = jnp.concatenate([jnp.ones_like(clear[:1]), clear[:-1]], 0)
        ranges = jnp.sum(before * alpha * self.steps[:, None], 0) + clear[-1] * self.far
        depth = ranges * jnp.cos(self.column_angles)
        return jnp.broadcast_to(depth[None], (self.cam.height, self.cam.width))

    def gain(self, opacity, table, weight, pose) -> jax.Array:
        """Expected belief samples newly seen from ``pose`` (3,): differentiable in it."""
        p = coverage.observed_soft(table, self.cov, self.cam, pose, self.render(opacity, pose))
        return jnp.sum(weight * p)

    def refine(self, opacity, table, weight, state, starts) -> tuple[jax.Array, jax.Array]:
        """Adam on each start (M, 3); returns the refined views (M, 3) and their gains (M,)."""
        opt = optax.adam(self.lr)

        def objective(q):
            travel = jnp.sqrt(jnp.sum((q[:2] - state.pose[:2]) ** 2) + 1e-6)
            under = bilinear(opacity, self.coarse, q[None, :2])[0]
            return self.gain(opacity, table, weight, q) - self.distance_cost * travel - self.blocked_cost * under

        def one(q):
            def body(carry, _):
                q, s = carry
                g = jax.grad(objective)(q)
                updates, s = opt.update(-g, s)  # ascent
                return (optax.apply_updates(q, updates), s), None

            (q, _), _ = jax.lax.scan(body, (q, opt.init(q)), None, length=self.iterations)
            return q, self.gain(opacity, table, weight, q)

        return jax.vmap(one)(starts)

    # --- Deciding ---------------------------------------------------------------------

    def views(self, state, opacity, table, weight, key) -> tuple[jax.Array, jax.Array]:
        """The refined views (M, 3) and their expected gains (M,): each start looks at a
        belief point drawn by :meth:`start_weights`, from its own ring direction."""
        pick = grid.draw(key, self.start_weights(weight), self.ring.shape[0])
        centre = table.points[:2, pick].T  # (M, 2)
        xy = centre + self.ring
        views, gains = self.refine(opacity, table, weight, state, jnp.concatenate([xy, facing(centre, xy)[:, None]], 1))
        return views.at[:, 2].set(grid.wrap_angle(views[:, 2])), gains

    def start_weights(self, weight: jax.Array) -> jax.Array:
        """(P,) how often each belief point is a start's centre: its weight, floored over the
        world's cells (for when every weight is spent)."""
        return jnp.where(self.coarse.inside().reshape(-1), weight + 1e-9, 0.0)

    def believed_opacity(self, held: jax.Array) -> jax.Array:
        """(Hc, Wc) the opacity the belief adds: its held cells, ``belief_opacity`` each."""
        return self.belief_opacity * held.reshape(self.shape)

    def decide(self, state, ps: GradientNBVState, key):
        env = self.env
        table, held = self.belief(state)
        opacity = jnp.maximum(self.opacity(state), self.believed_opacity(held))
        now = coverage.observed_soft(table, self.cov, self.cam, state.pose, state.depth)  # the real frame
        # A view reached counts as seen as predicted, so the same view is not chosen again.
        arrived = needs_target(state) & ~ps.exploring
        promised = jnp.where(arrived, coverage.observed_soft(table, self.cov, self.cam, ps.target,
                                                             self.render(opacity, ps.target)), 0.0)
        # The best view so far, not a noisy-or: frames from one pose are not independent
        # evidence (a robot standing still would otherwise 'see' everything in time).
        viewed = jnp.maximum(ps.viewed, jnp.maximum(now, promised))
        weight = held * (1.0 - viewed)
        views, gains = self.views(state, opacity, table, weight, key)
        occ = env.occupancy(state)
        blocked = blocked_within(occ == occupancy.OCCUPIED, self.grow_clear)
        i, j = env.grid.cell(views[:, :2])
        ok = (occ[i, j] == occupancy.FREE) & ~blocked[i, j] & occupancy.in_extent(env.grid, views[:, :2])
        ok = ok & (gains >= self.min_gain)
        dist = jnp.linalg.norm(views[:, :2] - state.pose[:2], axis=-1)
        score = jnp.where(ok, gains / (dist + 1.0), -1.0)
        best = jnp.argmax(score)
        have_view = score[best] > 0

        target, f_state, exploring, _ = self.choose(state, ps, key, have_view, views[best])
        return target, GradientNBVState(target, viewed, f_state, exploring)


def bilinear(values: jax.Array, geo, xy: jax.Array) -> jax.Array:
    """Bilinear interpolation of a (H, W) grid at world points (..., 2) (cell values at cell
    centres; zero beyond the grid): differentiable in ``xy``."""
    u = (xy[..., 0] - geo.origin[0]) / geo.resolution - 0.5
    v = (xy[..., 1] - geo.origin[1]) / geo.resolution - 0.5
    j0, i0 = jnp.floor(u), jnp.floor(v)
    fu, fv = u - j0, v - i0
    h, w = values.shape

    def at(i, j):
        inside = (i >= 0) & (i < h) & (j >= 0) & (j < w)
        return jnp.where(inside, values[jnp.clip(i, 0, h - 1).astype(jnp.int32), jnp.clip(j, 0, w - 1).astype(jnp.int32)], 0.0)

    return ((1 - fu) * (1 - fv) * at(i0, j0) + fu * (1 - fv) * at(i0, j0 + 1)
            + (1 - fu) * fv * at(i0 + 1, j0) + fu * fv * at(i0 + 1, j0 + 1))
