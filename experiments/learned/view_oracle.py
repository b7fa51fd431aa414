"""A ceiling for the learned explorer's kind of choice (docs/learned.md): at each decision it
takes, among the kept target and 32 targets of random's draw, the one from which the camera
would newly observe the most ground-truth surface samples (``view_oracle``), or the most per
metre of travel plus one (``view_oracle_pm``). It decides when learned does. It reads the
ground truth, so it is a measure, not an explorer."""

import jax
import jax.numpy as jnp

from rosmeery_jax.policies.base import Policy
from rosmeery_jax.policies.learned import Choice  # learned's state: target and when it was chosen
from rosmeery_jax.rl.candidates import driving
from rosmeery_jax.sim import coverage, occupancy


class ViewOracle(Policy):
    name = "view_oracle"
    draws = 32
    decide_every = 30  # control steps, as the shipped learned policy
    per_metre = False

    def init(self, key):
        return Choice(jnp.zeros(3, jnp.float32), jnp.int32(0))

    def gain(self, state, pose):
        """Ground-truth samples the camera would newly observe from ``pose`` (3,)."""
        sk = self.env.sk
        depth, _ = self.env.look(pose)
        new = coverage.observed(sk.table, sk.cfg.coverage, sk.camera, pose, depth) & (state.knowledge.seen <= 0.5)
        return jnp.sum(new.astype(jnp.float32))

    def decide(self, state, ps, key):
        occupied = self.env.occupancy(state) == occupancy.OCCUPIED
        drawn = self.env.navigator.draw_reachable(state.nav, state.pose, occupied, key, self.draws)
        cands = jnp.concatenate([ps.target[None], drawn], 0)  # (1 + draws, 3): the kept target first
        score = jax.vmap(lambda q: self.gain(state, q))(cands)
        if self.per_metre:
            score = score / (jnp.linalg.norm(cands[:, :2] - state.pose[:2], axis=-1) + 1.0)
        score = score.at[0].set(jnp.where(driving(state), score[0], -1.0))  # kept only while driving to it
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
