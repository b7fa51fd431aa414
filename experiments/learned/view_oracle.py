"""A ceiling for the learned explorer's kind of choice (docs/learned.md): at each decision it
takes, among the kept target and 32 targets of random's draw, the one from which the camera
would newly observe the most ground-truth surface samples (``view_oracle``), or the most per
metre of travel plus one (``view_oracle_pm``). It decides when learned does. Two more test
how far more search (``view_oracle_pm_wide``) and a view after the next
(``view_oracle_2step``, and ``view_oracle_ori_2step`` by ORI) take it. The ``view_oracle_ori``
family scores a view by the ORI it would add rather than by samples;
``view_oracle_ori_3step`` plans three views; ``view_oracle_ori_pm_kept`` and
``view_oracle_ori_2step_kept`` keep to a view or a plan until it is driven;
``view_oracle_ori_pm_path`` counts what the robot would see on its way; and
``view_oracle_ori_pm_objects`` adds candidates that are not random's draws (views facing
objects). They read the ground truth, so they are measures, not explorers."""

from typing import NamedTuple

import jax
import jax.numpy as jnp

from rosmeery_jax.policies.base import Policy
from rosmeery_jax.policies.learned import Choice  # learned's state: target and when it was chosen
from rosmeery_jax.policies.semantic_nbv import facing
from rosmeery_jax.rl.candidates import driving
from rosmeery_jax.sim import coverage, occupancy
from rosmeery_jax.core import grid
from rosmeery_jax.sim.coverage import FAR


def newly_observed(env, state, pose):
    """(N,) which ground-truth samples the camera would newly observe from ``pose`` (3,)."""
    sk = env.sk
    depth, _ = env.look(pose)
    return coverage.observed(sk.table, sk.cfg.coverage, sk.camera, pose, depth) & (state.knowledge.seen <= 0.5)


class ViewOracle(Policy):
    name = "view_oracle"
    draws = 32
    decide_every = 30  # control steps, as the shipped learned policy
    per_metre = False

    def init(self, key):
        return Choice(jnp.zeros(3, jnp.float32), jnp.int32(0))

    def gain(self, state, pose):
        """What the camera would newly observe from ``pose`` (3,) is worth."""
        return self.worth(newly_observed(self.env, state, pose))

    def worth(self, seen):
        """(...,) what views that would newly observe ``seen`` (..., S) are worth: samples."""
        return jnp.sum(seen.astype(jnp.float32), -1)

    def decide(self, state, ps, key):
        occupied = self.env.occupancy(state) == occupancy.OCCUPIED
        cands, ok = self.candidates(state, ps, occupied, key)
        score = jnp.where(ok, jax.vmap(lambda q: self.gain(state, q))(cands), -1.0)
        if self.per_metre:
            score = score / (jnp.linalg.norm(cands[:, :2] - state.pose[:2], axis=-1) + 1.0)
        return self.choose(state, ps, cands, score)

    def candidates(self, state, ps, occupied, key) -> tuple[jax.Array, jax.Array]:
        """(1 + draws, 3) the kept target first, then random's draws; (1 + draws,) which may
        be chosen (all)."""
        drawn = self.env.navigator.draw_reachable(state.nav, state.pose, occupied, key, self.draws)
        return jnp.concatenate([ps.target[None], drawn], 0), jnp.ones(1 + self.draws, bool)

    def choose(self, state, ps, cands, score):
        """The best of ``cands`` (1 + K, 3) by ``score`` (1 + K,), the kept target first and
        kept only while driving to it, when a choice is due; else the kept target."""
        score = score.at[0].set(jnp.where(driving(state), score[0], -1.0))
        due = ~driving(state) | (state.t - ps.chosen_at >= self.decide_every)
        target = jnp.where(due, cands[jnp.argmax(score)], ps.target)
        return target, Choice(target, jnp.where(due, state.t, ps.chosen_at))


class ViewOraclePerMetre(ViewOracle):
    name = "view_oracle_pm"
    per_metre = True


class ViewOracleWide(ViewOraclePerMetre):
    """More search: three times the draws, and a choice every second rather than every three."""
    name = "view_oracle_pm_wide"
    draws = 96
    decide_every = 10


class ViewOracleTwoSteps(ViewOraclePerMetre):
    """Choosing with the views after it in mind, a plan of ``legs`` views: each candidate
    (the kept target and 32 draws, as ``view_oracle_pm``'s) is followed by the best of 32
    more draws for each later leg, the one that adds the most to what the plan would newly
    observe so far, per metre of the legs so far plus one, and is scored by its whole plan.
    With two legs that is the best pair it starts."""
    name = "view_oracle_2step"
    legs = 2

    def decide(self, state, ps, key):
        legs, score = self.plans(state, ps, key)
        return self.choose(state, ps, legs[:, 0], score)

    def plans(self, state, ps, key) -> tuple[jax.Array, jax.Array]:
        """(A, legs, 3) a plan from each of the A = 1 + draws candidates, and (A,) what each
        plan would newly observe, worth per metre of its legs plus one."""
        occupied = self.env.occupancy(state) == occupancy.OCCUPIED
        keys = jax.random.split(key, self.legs)
        first, _ = self.candidates(state, ps, occupied, keys[0])  # (A, 3)
        seen = jax.vmap(lambda q: newly_observed(self.env, state, q))(first)  # (A, S)
        at, metres = [first], jnp.linalg.norm(first[:, :2] - state.pose[:2], axis=-1)  # legs so far, (A,)
        for k in keys[1:]:  # greedy, one leg at a time: every later leg's best for each plan
            nxt = self.env.navigator.draw_reachable(state.nav, state.pose, occupied, k, self.draws)  # (B, 3)
            view = jax.vmap(lambda q: newly_observed(self.env, state, q))(nxt)  # (B, S)
            through = metres[:, None] + jnp.linalg.norm(nxt[None, :, :2] - at[-1][:, None, :2], axis=-1)  # (A, B)
            best = jnp.argmax(self.together(seen, view) / (through + 1.0), -1)  # (A,)
            seen, metres = seen | view[best], jnp.take_along_axis(through, best[:, None], 1)[:, 0]
            at.append(nxt[best])
        return jnp.stack(at, 1), self.worth(seen) / (metres + 1.0)

    def together(self, a, b):
        """(A, B) what views a (A, S) and b (B, S), which samples each newly observes, are
        worth together."""
        return self.worth(a[:, None] | b[None])


def ori_weights(env):
    """(S,) what observing each ground-truth sample adds to ORI, times N: 1 / its object's
    sample count (paper Eq. 3 weighs every object the same)."""
    sk = env.sk
    return 1.0 / jnp.maximum(sk.ps_G[jnp.clip(sk.table.object, 0, sk.table.num_objects - 1)], 1.0)


class ByORI:
    """Scored by ORI itself (mixed in before a view oracle): each newly observed sample counts
    1 / its object's sample count, so every object weighs the same, as in ORI (paper Eq. 3);
    ``view_oracle`` counts samples, so large objects weigh more."""

    def worth(self, seen):
        """(...,) the ORI views that would newly observe ``seen`` (..., S) add, times N: the
        sum over those samples of 1 / ps_G."""
        return jnp.sum(jnp.where(seen, ori_weights(self.env), 0.0), -1)


class ViewOracleORI(ByORI, ViewOracle):
    name = "view_oracle_ori"


class ViewOracleORIPerMetre(ByORI, ViewOraclePerMetre):
    name = "view_oracle_ori_pm"


class ViewOracleORIWide(ByORI, ViewOracleWide):
    name = "view_oracle_ori_pm_wide"


class ViewOracleORITwoSteps(ByORI, ViewOracleTwoSteps):
    """``view_oracle_2step`` judged by the ORI its plan would add."""
    name = "view_oracle_ori_2step"


class ViewOracleORIThreeSteps(ViewOracleORITwoSteps):
    name = "view_oracle_ori_3step"
    legs = 3


class AlongThePath:
    """Views scored with what the robot would see on the way (mixed in before a view
    oracle): the samples newly observed from the view and from ``stops`` poses evenly
    spaced on the straight line to it, each facing along the line as the robot drives, those
    on cells it cannot reach on its own map left out (the navigator's path bends around
    them; the line is its cheap stand-in)."""

    stops = 2

    def gain(self, state, pose):
        nav = self.env.navigator
        reach = nav.reachable(state.nav, state.pose, self.env.occupancy(state) == occupancy.OCCUPIED)
        f = jnp.arange(1, self.stops + 1, dtype=jnp.float32) / (self.stops + 1)
        xy = state.pose[:2] + f[:, None] * (pose[:2] - state.pose[:2])  # (stops, 2)
        yaw = jnp.broadcast_to(facing(pose[:2], state.pose[:2]), (self.stops,))
        i, j = nav.coarse.cell(xy)
        seen = jax.vmap(lambda q: newly_observed(self.env, state, q))(jnp.concatenate([xy, yaw[:, None]], -1))
        on_way = jnp.any(seen & (reach[i, j] & nav.coarse.inside()[i, j])[:, None], 0)  # (S,)
        return self.worth(newly_observed(self.env, state, pose) | on_way)


class ViewOracleORIAlongThePath(AlongThePath, ByORI, ViewOraclePerMetre):
    name = "view_oracle_ori_pm_path"


class Plan(NamedTuple):
    """A plan the robot keeps to: target (3,), the legs after it (legs - 1, 3) and how many
    of them are still to drive, int32."""

    target: jax.Array
    after: jax.Array
    left: jax.Array


class KeptPlans(ViewOracleORITwoSteps):
    """Plans the robot keeps to, rather than choosing afresh every 3 s: it chooses only when
    the navigator is done with its target (reached it, or gave up on it), then drives the
    chosen plan's legs one after the other, and chooses again when all are driven. Plans
    are ``view_oracle_ori_2step``'s; with one leg, a view is ``view_oracle_ori_pm``'s."""
    name = "view_oracle_ori_2step_kept"

    def init(self, key):
        return Plan(jnp.zeros(3, jnp.float32), jnp.zeros((self.legs - 1, 3), jnp.float32), jnp.int32(0))

    def decide(self, state, ps, key):
        legs, score = self.plans(state, ps, key)
        best = legs[jnp.argmax(score.at[0].set(-1.0))]  # (legs, 3); the kept target is done with
        done = ~driving(state)
        fresh, on = done & (ps.left == 0), done & (ps.left > 0)
        following = ps.after[jnp.clip(self.legs - 1 - ps.left, 0, self.legs - 2)] if self.legs > 1 else ps.target
        target = jnp.where(fresh, best[0], jnp.where(on, following, ps.target))
        after = jnp.where(fresh, best[1:], ps.after)
        left = jnp.where(fresh, self.legs - 1, ps.left - on.astype(jnp.int32))
        return target, Plan(target, after, left)


class KeptViews(KeptPlans):
    name = "view_oracle_ori_pm_kept"
    legs = 1


class ObjectViews:
    """Candidates that are not random's draws (mixed in before a view oracle): beside the
    kept target and the draws, ``views`` poses drawn uniformly among those on a ring
    (``radii`` x 8 directions) around each ground-truth object's surface centroid, facing it,
    on a cell the robot can reach on its own map, for objects with surface still unseen."""

    views = 32
    radii = (1.0, 2.0)

    def candidates(self, state, ps, occupied, key):
        """(1 + draws + views, 3) the view oracle's candidates, then the object views;
        which may be chosen."""
        k_draw, k_view = jax.random.split(key)
        cands, ok = super().candidates(state, ps, occupied, k_draw)
        views, allowed = self.object_views(state, occupied, k_view)
        return jnp.concatenate([cands, views], 0), jnp.concatenate([ok, allowed])

    def object_views(self, state, occupied, key) -> tuple[jax.Array, jax.Array]:
        """(views, 3) poses facing objects, drawn among the allowed ring views, and (views,)
        which are allowed (none may be: then the draw is any, and all are refused)."""
        nav, table = self.env.navigator, self.env.sk.table
        n, real = table.num_objects, (table.points[0] < FAR / 2).astype(jnp.float32)  # padding stands at FAR
        count = jax.ops.segment_sum(real, table.object, n)
        centroid = jnp.stack([jax.ops.segment_sum(real * table.points[a], table.object, n) for a in (0, 1)], -1)
        centroid = centroid / jnp.maximum(count, 1.0)[:, None]  # (N, 2)
        unseen = jax.ops.segment_sum(real * (state.knowledge.seen <= 0.5), table.object, n) > 0
        ang = jnp.arange(8) * 2 * jnp.pi / 8
        ring = jnp.concatenate([r * jnp.stack([jnp.cos(ang), jnp.sin(ang)], -1) for r in self.radii])  # (V, 2)
        at = centroid[:, None] + ring[None]  # (N, V, 2)
        i, j = nav.coarse.cell(at)
        reach = nav.reachable(state.nav, state.pose, occupied)
        ok = (reach[i, j] & nav.coarse.inside()[i, j] & unseen[:, None] & (count > 0)[:, None]).reshape(-1)
        pick = grid.draw(key, ok.astype(jnp.float32) + 1e-12, self.views)  # (views,) into N * V
        xy = at.reshape(-1, 2)[pick]
        yaw = facing(centroid[pick // ring.shape[0]], xy)
        return jnp.concatenate([xy, yaw[:, None]], -1), ok[pick]


class ViewOracleORIObjects(ObjectViews, ByORI, ViewOraclePerMetre):
    name = "view_oracle_ori_pm_objects"
