"""Navigation that recovers, targets known enclosed at once, reachable random targets, and
where a run's time went (navigation.csv)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from conftest import SMALL_RUN, room_xml
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from rosmeery_jax.apps.cli import main
from rosmeery_jax.core import grid
from rosmeery_jax.env import make
from rosmeery_jax.policies.random_walk import RandomPolicy
from rosmeery_jax.results import time_use
from rosmeery_jax.sim import occupancy
from rosmeery_jax.sim.navigation import IDLE, MOVING, REACHED, RECOVERING, STATUS_NAMES, STUCK, UNREACHABLE
from rosmeery_jax.world import load_world

# A kerb 0.15 m high across the robot's way: below the laser's plane (0.3 m), so the robot's
# map never shows it, but high enough to stop the robot's body.
KERB = '<body name="kerb" pos="0 0 0"><geom type="box" pos="0 0 0.075" size="0.1 0.35 0.075"/></body>'


def _drive(env, state, target, steps):
    """Hold ``target`` for ``steps`` steps (one env, jitted); the final state and statuses (steps,)."""

    def body(s, _):
        s = env.step(s, target)
        return s, s.nav.status

    return jax.jit(lambda s: jax.lax.scan(body, s, None, length=steps))(state)


def test_robot_pushed_against_an_unseen_obstacle_backs_off_and_reaches_the_target_behind_it(write_world):
    world = load_world(str(write_world(room_xml(KERB, {"kerb": "boxes"}, spawn=(-0.35, 0.0, 0.0)))))
    env = make(world, start_yaw="spawn")
    target = jnp.array([1.0, 0.0, 0.0])
    final, status = _drive(env, env.reset(jax.random.PRNGKey(0)), target, 400)
    status = np.asarray(status)
    assert RECOVERING in status, [STATUS_NAMES[s] for s in np.unique(status)]
    first = int(np.argmax(status == RECOVERING))
    assert STATUS_NAMES[int(final.nav.status)] == "reached", [STATUS_NAMES[s] for s in status[first::20]]
    assert np.linalg.norm(np.asarray(final.pose[:2]) - [1.0, 0.0]) < env.config.nav.goal_tolerance + 0.02
    # The kerb is still missing from the map: what routed the robot round it was what it bumped into.
    assert np.asarray(env.occupancy(final))[env.grid.cell(jnp.zeros(2))] != occupancy.OCCUPIED
    assert np.asarray(final.nav.bumps).any()


def test_target_enclosed_on_the_map_is_unreachable_at_once():
    # A hand-drawn map: a closed square of occupied cells 1 m across, the robot outside it.
    env = make("small_office")
    nav, geo = env.navigator, env.grid
    occupied = np.zeros(geo.shape, bool)
    (i0, j0), (i1, j1) = (tuple(int(v) for v in geo.cell(jnp.array(p))) for p in ([1.0, 1.0], [2.0, 2.0]))
    occupied[i0:i1 + 1, [j0, j1]] = occupied[[i0, i1], j0:j1 + 1] = True
    occupied = jnp.asarray(occupied)
    pose = jnp.array([-0.5, 0.0, 0.0])
    step = jax.jit(lambda s, target, new: nav.step(nav.set_target(s, target, new), pose, occupied))
    state = nav.init()
    for _ in range(100):  # no target yet: the reachability flood runs to completion meanwhile
        state, _ = step(state, jnp.zeros(3), jnp.bool_(False))
    assert not np.asarray(state.reach)[nav.coarse.cell(jnp.array([1.5, 1.5]))]
    inside, _ = step(state, jnp.array([1.5, 1.5, 0.0]), jnp.bool_(True))
    assert STATUS_NAMES[int(inside.status)] == "unreachable"
    outside, cmd = step(state, jnp.array([0.5, 1.5, 0.0]), jnp.bool_(True))  # beside the square
    assert STATUS_NAMES[int(outside.status)] == "moving"
    # Off the map, or not a finite pose: unreachable at once, and the robot does not move. An
    # off-map goal was clipped to the map's edge and driven towards; a NaN one made the pose NaN.
    for target in ([1e10, 0.0, 0.0], [-1e38, 0.0, 0.0], [0.5, 2.5, 0.0], [jnp.inf, 0.0, 0.0],
                   [jnp.nan, 0.0, 0.0], [0.5, 1.5, jnp.nan]):
        off, cmd = step(state, jnp.array(target), jnp.bool_(True))
        assert STATUS_NAMES[int(off.status)] == "unreachable" and not np.asarray(cmd).any(), target


def _held(nav, pose, targets, new):
    """Statuses (T,) of the navigator for a robot held at ``pose`` (it never moves, whatever
    it is told) on an empty map; ``targets`` (T, 3) sent at the steps where ``new`` (T,) is set."""

    def body(s, x):
        s, _ = nav.step(nav.set_target(s, *x), pose, jnp.zeros(nav.geo.shape, bool))
        return s, s.status

    return np.asarray(jax.jit(lambda t, n: jax.lax.scan(body, nav.init(), (t, n))[1])(targets, new))


def test_a_robot_that_cannot_move_is_reported_stuck_within_ten_seconds():
    """Held in place, the navigator recovers once (the recovery could not back it off, so
    there is no second) and then says stuck: 2 s still, a recovery of at most 2.8 s, 2 s
    still. A policy that sends the target again every second (as the learned explorer
    does) gets its robot backed off all the same, a little later: each new target's plan
    takes a few steps to reach the robot."""
    nav = make("small_office").navigator
    t, pose = 150, jnp.array([-0.5, 0.0, 0.0])
    targets = jnp.broadcast_to(jnp.array([1.0, 0.0, 0.0]), (t, 3))
    status = _held(nav, pose, targets, jnp.arange(t) == 0).tolist()
    stuck = status.index(STUCK)
    assert 4.0 <= stuck * nav.dt <= 7.6, [STATUS_NAMES[s] for s in status[:stuck + 1]]
    assert set(status[stuck:]) == {STUCK}
    starts = [k for k in range(1, stuck) if status[k] == RECOVERING and status[k - 1] != RECOVERING]
    assert len(starts) == 1 < nav.cfg.recoveries and 2.0 <= starts[0] * nav.dt <= 2.5
    again = _held(nav, pose, targets, jnp.arange(t) % 10 == 0).tolist()
    assert RECOVERING in again and again.index(RECOVERING) * nav.dt <= 5.0, [STATUS_NAMES[s] for s in again[:40]]


def test_random_walker_targets_are_reachable_on_its_own_map():
    env = make("small_office")
    policy = RandomPolicy(env)

    def one(state, key):
        target, _ = policy.decide(state, jnp.zeros(3), key)
        return target

    state = env.reset(jax.random.PRNGKey(3))
    state, _ = _drive(env, state, jnp.array([1.0, 0.5, 0.0]), 50)  # a map with walls in it
    targets = np.asarray(jax.jit(jax.vmap(one, in_axes=(None, 0)))(state, jax.random.split(jax.random.PRNGKey(0), 200)))
    # Reachability by hand: SciPy's connected components of the navigator's open cells.
    nav = env.navigator
    open_, _ = nav.open_cells(state.nav, state.pose, env.occupancy(state) == occupancy.OCCUPIED)
    labels, _ = ndimage.label(np.asarray(open_), structure=np.ones((3, 3)))
    here = tuple(int(v) for v in nav.coarse.cell(state.pose[:2]))
    cells = np.asarray(jnp.stack(nav.coarse.cell(jnp.asarray(targets[:, :2])), -1))
    assert (labels[cells[:, 0], cells[:, 1]] == labels[here]).all()
    assert (~np.asarray(open_)).sum() > 0 and len({tuple(c) for c in cells}) > 100  # a real map, spread targets


@settings(max_examples=25, deadline=None)
@given(st.integers(3, 30), st.integers(3, 30), st.floats(0.3, 0.8), st.integers(0, 2**31 - 1))
def test_flood_is_the_connected_component(h, w, density, seed):
    rng = np.random.default_rng(seed)
    open_ = np.zeros((32, 32), bool)  # an h x w map in a closed 32 x 32 grid: one compile, any map
    open_[:h, :w] = rng.random((h, w)) < density
    start = np.zeros_like(open_)
    start[rng.integers(h), rng.integers(w)] = True
    labels, _ = ndimage.label(open_, structure=np.ones((3, 3)))
    want = np.isin(labels, labels[start & open_]) & open_ & (labels > 0)
    np.testing.assert_array_equal(np.asarray(grid.connected(jnp.asarray(start), jnp.asarray(open_))), want)
    # One pass of spread never claims a cell outside the component.
    assert not (np.asarray(grid.spread(jnp.asarray(start), jnp.asarray(open_))) & ~want).any()


def test_draw_by_hand_and_padding_draws_the_same_cells():
    """Cells are drawn in proportion to their weight, a cell of weight 0 never; the same
    weights padded with zero rows and columns (as a session pads a world) give the same
    cells, row and column for row and column."""
    w = jnp.asarray([[0.0, 1.0], [0.0, 3.0]])
    flat = np.asarray(grid.draw(jax.random.key(0), w, 40_000))
    assert set(flat.tolist()) == {1, 3}
    assert abs(np.mean(flat == 3) - 0.75) < 0.01
    padded = jnp.pad(w, ((0, 3), (0, 5)))
    again = np.asarray(grid.draw(jax.random.key(0), padded, 40_000))
    np.testing.assert_array_equal(np.unravel_index(flat, w.shape), np.unravel_index(again, padded.shape))


def test_account_by_hand():
    # 30 steps of 0.1 s: 10 moving 0.2 m each along x, 10 recovering in place, 5 stuck, 5 reached.
    status = np.array([IDLE] + [MOVING] * 10 + [RECOVERING] * 10 + [STUCK] * 5 + [REACHED] * 5)
    x = np.concatenate([0.2 * np.arange(11), np.full(20, 2.0)])
    poses = np.stack([x, np.zeros(31), np.zeros(31)], -1)
    row = time_use.account(status, poses, 0.1)
    assert row["moving_s"] == 1.0 and row["recovering_s"] == 1.0 and row["stuck_s"] == 0.5
    assert row["idle_s"] == 0.5 and row["unreachable_s"] == 0.0 and row["timeout_s"] == 0.0
    # Driving yet within 0.1 m of one spot: the last moving step and the 10 recovering ones.
    assert row["longest_stuck_s"] == 1.1
    assert row["still_s"] == 0.0  # 3 s: no whole 10 s window
    still = time_use.account(np.full(201, MOVING), np.zeros((201, 3)), 0.1)
    assert still["still_s"] == 20.0 and still["longest_stuck_s"] == 20.0
    three = time_use.account(np.array([IDLE] + [MOVING] * 3 + [UNREACHABLE] * 7), np.zeros((11, 3)), 0.1)
    assert three["moving_s"] == 0.3 and three["unreachable_s"] == 0.7  # not 0.30000000000000004, 0.7000000000000001


def test_session_names_a_cause_for_every_second(tmp_path, capsys):
    out = tmp_path / "run"
    assert main([*SMALL_RUN, "--seeds", "2", "--out", str(out)]) == 0  # the suite's shared 4 s program
    df = pd.read_csv(out / "navigation.csv")
    assert len(df) == 4 and set(df.policy) == {"random", "frontier"}
    causes = df[[f"{c}_s" for c in time_use.CAUSES]].sum(axis=1)
    np.testing.assert_allclose(causes, 4.0, atol=1e-9)
    assert (df.moving_s > 0).all()
    assert "navigation: moving" in capsys.readouterr().out
