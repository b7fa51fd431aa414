"""Sensor and actuation noise (rosmeery_jax.sim.noise): each model's statistics from many
samples, determinism per robot, the options' checks."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from rosmeery_jax.apps.cli import main
from rosmeery_jax.sim import noise
from rosmeery_jax.sim.noise import NoiseConfig

KEY = jax.random.key(0)


@pytest.mark.parametrize("z", [1.0, 2.0, 4.0])
def test_depth_error_follows_the_axial_model(z):
    cfg = NoiseConfig(depth_sigma0=0.0012, depth_sigma2=0.0019, depth_z0=0.4)
    out = np.asarray(noise.depth(KEY, jnp.full((300, 300), z, jnp.float32), cfg, 500.0))
    want = 0.0012 + 0.0019 * (z - 0.4) ** 2
    assert abs(out.mean() - z) < 3 * want / 300
    assert out.std() == pytest.approx(want, rel=0.1)


def test_disparity_quantisation_puts_depth_on_its_steps():
    cfg = NoiseConfig(disparity_step=0.125, disparity_focal=580.0, disparity_baseline=0.075)
    z = jnp.linspace(0.5, 6.0, 4000, dtype=jnp.float32).reshape(40, 100)
    out = np.asarray(noise.depth(KEY, z, cfg, 500.0)).astype(np.float64)
    disparity = 580.0 * 0.075 / out / 0.125
    np.testing.assert_allclose(disparity, np.round(disparity), atol=1e-3)
    assert np.abs(out - np.asarray(z)).max() <= 6.0 ** 2 / (580 * 0.075) * 0.125 / 2 * 1.01  # half a step at 6 m


def test_depth_drops_edges_and_grazing_returns_and_keeps_holes():
    z = np.full((50, 50), 2.0, np.float32)
    z[:, 25:] = 4.0  # an edge
    z[0, 0] = 0.0  # a hole stays a hole
    cfg = NoiseConfig(edge_jump=0.5, edge_dropout=1.0)
    out = np.asarray(noise.depth(KEY, jnp.asarray(z), cfg, 50.0))
    assert (out[:, 24:26] == 0).all() and out[0, 0] == 0 and (out[1:, :23] == 2.0).all()
    ramp = np.tile(np.linspace(1.0, 6.0, 50, dtype=np.float32), (50, 1))  # a wall turning away from the camera
    out = np.asarray(noise.depth(KEY, jnp.asarray(ramp), NoiseConfig(max_incidence=math.radians(60)), 50.0))
    grazing = (5.0 / 49) * 50.0 / ramp > math.tan(math.radians(60))  # depth step per pixel footprint z / f
    assert grazing[:, 1:-1].any() and not grazing.all()
    assert (out[:, 1:-1][grazing[:, 1:-1]] == 0).all() and (out[~grazing] == ramp[~grazing]).all()
    flat = np.asarray(noise.depth(KEY, jnp.full((50, 50), 2.0), NoiseConfig(max_incidence=math.radians(60)), 50.0))
    assert (flat == 2.0).all()


@pytest.mark.parametrize("dropout", [0.0, 0.5, 1.0])
def test_edge_pixels_drop_with_the_edge_probability_not_as_grazing_returns(dropout):
    """A box face at 2 m before a wall at 4 m, both facing the camera: only the edge test may
    drop the pixels at the jump (the grazing test judges each pixel's own surface), so they
    drop with probability ``edge_dropout``; flat pixels never drop."""
    z = np.full((240, 320), 4.0, np.float32)
    z[60:180, 80:240] = 2.0
    cfg = NoiseConfig(edge_jump=0.1, edge_dropout=dropout, max_incidence=math.radians(80))
    out = np.asarray(noise.depth(KEY, jnp.asarray(z), cfg, 277.0))
    edge = np.zeros_like(z, bool)
    for axis in (0, 1):
        jump = np.abs(np.diff(z, axis=axis)) > 0.1
        lo = [slice(None), slice(None)]
        hi = [slice(None), slice(None)]
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        edge[tuple(lo)] |= jump
        edge[tuple(hi)] |= jump
    assert edge.sum() == 2 * (120 + 160) + 2 * (120 + 160) - 4  # a ring each side of the jump (inner corners once)
    assert (out[~edge] == z[~edge]).all()
    assert (out[edge] == 0).mean() == pytest.approx(dropout, abs=0.05)


def test_laser_rgb_and_actuation_noise_have_their_statistics():
    r = jnp.full(200_000, 5.0)
    out = np.asarray(noise.ranges(KEY, r, NoiseConfig(laser_sigma=0.01, laser_dropout=0.05), 0.2, 15.0))
    dropped = out == 15.0
    assert dropped.mean() == pytest.approx(0.05, abs=0.003)
    assert out[~dropped].std() == pytest.approx(0.01, rel=0.05)
    assert (np.asarray(noise.ranges(KEY, jnp.full(10, 15.0), NoiseConfig(laser_sigma=0.5), 0.2, 15.0)) == 15.0).all()
    img = jnp.full((200, 200, 3), 128, jnp.uint8)
    assert np.asarray(noise.rgb(KEY, img, NoiseConfig(rgb_sigma=3.0))).astype(float).std() == pytest.approx(3.0,
                                                                                                           rel=0.05)
    cfg = NoiseConfig(motion_a1=0.01, motion_a2=0.001, motion_a3=0.002, motion_a4=0.01)
    keys = jax.random.split(KEY, 50_000)
    cmds = np.asarray(jax.vmap(lambda k: noise.command(k, jnp.array([0.5, 1.0]), cfg))(keys))
    assert cmds[:, 0].std() == pytest.approx(math.sqrt(0.01 * 0.25 + 0.001), rel=0.05)
    assert cmds[:, 1].std() == pytest.approx(math.sqrt(0.002 * 0.25 + 0.01), rel=0.05)
    assert cmds.mean(0) == pytest.approx([0.5, 1.0], abs=0.003)


def test_off_is_the_exact_sensors():
    cfg = noise.PRESETS["off"]
    assert not (cfg.depth or cfg.laser or cfg.rgb or cfg.actuation)
    real = noise.PRESETS["realistic"]
    assert real.depth and real.laser and real.rgb and real.actuation


ARGS = ["run", "--worlds", "small_office", "--policies", "frontier", "--detector", "off", "--duration", "6",
        "--noise", "realistic", "--quiet"]


def test_noisy_runs_are_reproducible_per_seed_whatever_their_batch(tmp_path):
    """Seed 1 beside seed 0, and alone: the same noisy run, bit for bit; seed 0 differs."""
    assert main([*ARGS, "--seeds", "2", "--out", str(tmp_path / "two")]) == 0
    assert main([*ARGS, "--seeds", "1", "--first-seed", "1", "--out", str(tmp_path / "one")]) == 0
    two, one = (pd.read_csv(tmp_path / d / "trajectories.csv") for d in ("two", "one"))
    pd.testing.assert_frame_equal(two[two.seed == 1].reset_index(drop=True), one.reset_index(drop=True))
    m2, m1 = (pd.read_csv(tmp_path / d / "metrics.csv") for d in ("two", "one"))
    pd.testing.assert_frame_equal(m2[m2.seed == 1].reset_index(drop=True), m1.reset_index(drop=True))


@pytest.mark.parametrize("extra, field, toml", [
    (["--noise", "foggy"], "noise", ""),
    (["--noise", "realistic", "--config", "{cfg}"], "noise.laser_sigma", "[env.noise]\nlaser_sigma = -0.01\n"),
    (["--config", "{cfg}"], "noise.laser_sigma", "[env]\nnoise__laser_sigma = 0.02\n[env.noise]\nlaser_sigma = 0.05\n"),
])
def test_bad_noise_is_one_line_naming_the_field(tmp_path, capsys, extra, field, toml):
    """An unknown preset, a negative parameter, one parameter spelt twice (which wins?)."""
    cfg = tmp_path / "c.toml"
    cfg.write_text(toml)
    args = ["run", "--worlds", "small_office", "--policies", "random", "--detector", "off", "--duration", "2",
            "--quiet", "--out", str(tmp_path / "out"), *[a.replace("{cfg}", str(cfg)) for a in extra]]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and field in err[0], err
    assert not (tmp_path / "out").exists()


def test_odometry_without_noise_follows_the_true_motion_and_drifts_with_it():
    from rosmeery_jax.sim import localisation

    rng = np.random.default_rng(0)
    truth = [np.array([0.0, 0.0, 0.3])]
    for _ in range(200):  # forward, reversing and turning on the spot
        p = truth[-1]
        v, w = rng.choice([rng.uniform(-0.2, 0.5), 0.0]), rng.uniform(-0.8, 0.8)
        yaw = (p[2] + w * 0.1 + np.pi) % (2 * np.pi) - np.pi
        truth.append(np.array([p[0] + 0.1 * v * np.cos(p[2]), p[1] + 0.1 * v * np.sin(p[2]), yaw]))
    truth = jnp.asarray(np.array(truth), jnp.float32)

    def run(cfg):
        est = truth[0]
        for k in range(len(truth) - 1):
            est = localisation.odometry(noise.key(KEY, k, noise.ODOMETRY), truth[k], truth[k + 1], est, cfg)
        return np.asarray(est)

    np.testing.assert_allclose(run(NoiseConfig()), truth[-1], atol=1e-5)
    drifted = run(noise.PRESETS["realistic"])
    assert np.hypot(*(drifted[:2] - np.asarray(truth[-1][:2]))) > 1e-3


def test_the_robot_localises_itself_scan_matching_better_than_dead_reckoning(tmp_path):
    """trajectories.csv holds the estimate beside the truth; the scan matcher keeps it
    closer than the odometry alone (a 20 s run of two seeds, realistic noise: medians of
    about 2 cm against 22 cm on 2026-12-08)."""
    errors = {}
    for mode in ("dead_reckoning", "scan_matching"):
        out = tmp_path / mode
        assert main(["run", "--worlds", "small_office", "--policies", "frontier", "--detector", "off", "--seeds", "2",
                     "--duration", "20", "--noise", "realistic", "--localisation", mode, "--quiet",
                     "--out", str(out)]) == 0
        t = pd.read_csv(out / "trajectories.csv")
        errors[mode] = np.hypot(t.x - t.est_x, t.y - t.est_y)
        assert errors[mode].iloc[0] == 0.0  # the start is known
    assert errors["scan_matching"].median() < min(0.1, errors["dead_reckoning"].median())


def _room_scan(pose, angles, lo=(0.0, 0.0), hi=(4.0, 3.0)):
    """Ranges (K,) from ``pose`` inside an empty rectangular room (walls at lo and hi)."""
    d = np.stack([np.cos(pose[2] + angles), np.sin(pose[2] + angles)], 1)
    with np.errstate(divide="ignore"):
        t = np.stack([(np.where(d[:, a] > 0, hi[a], lo[a]) - pose[a]) / d[:, a] for a in (0, 1)], 1)
    return np.min(np.where(t > 0, t, np.inf), 1).astype(np.float32)


def test_the_scan_matcher_pulls_an_offset_back_and_only_runs_while_the_robot_moves():
    """A room whose walls lie on cell boundaries (as the worlds' do), mapped from the true
    pose: a prediction 4 cm and 3 cm off is pulled back to within half a cell (the bilinear
    score's resolution); the matcher runs only when the odometry moves."""
    from rosmeery_jax.sim import localisation, occupancy

    geo = occupancy.GridGeometry(jnp.array([-0.5, -0.5], jnp.float32), jnp.array([80, 100], jnp.int32), 0.05,
                                 (80, 100))
    cfg = occupancy.MapConfig()
    angles = jnp.linspace(-np.pi, np.pi, 180, endpoint=False)
    truth = np.array([1.3, 1.1, 0.2], np.float32)
    ranges = jnp.asarray(_room_scan(truth, np.asarray(angles)))
    logodds = occupancy.empty_map(geo)
    for _ in range(5):
        logodds = occupancy.update(logodds, geo, cfg, jnp.asarray(truth[:2]), truth[2] + angles, ranges,
                                   jnp.zeros(180, jnp.int32))
    off = truth + np.array([0.04, -0.03, 0.0], np.float32)
    back = np.asarray(localisation.match(logodds, geo, jnp.asarray(off), angles, ranges, 15.0))
    assert np.abs(back[:2] - truth[:2]).max() <= 0.025 + 1e-6
    assert not localisation.moved(jnp.asarray(truth), jnp.asarray(truth))
    assert localisation.moved(jnp.asarray(truth), jnp.asarray(truth + np.array([0.002, 0, 0], np.float32)))
    assert localisation.moved(jnp.asarray(truth), jnp.asarray(truth + np.array([0, 0, 0.002], np.float32)))


def test_a_robot_at_rest_keeps_its_estimate_under_realistic_noise(write_world):
    """Standing still for 3 s with noisy laser and scan matching: the estimate stays the true
    pose, to an ulp of the heading (the matcher waits for motion; it moved such a robot by 2-3 cm)."""
    import dataclasses

    from conftest import room_xml

    import rosmeery_jax as rj

    body = '<body name="box_1" pos="1.0 0.7 0"><geom type="box" pos="0 0 0.3" size="0.3 0.2 0.3"/></body>'
    path = write_world(room_xml(body, {"box_1": "cabinet"}, spawn=(-0.4, -0.3, 0.3)))
    over = {f"noise__{k}": v for k, v in dataclasses.asdict(noise.PRESETS["realistic"]).items()}
    env = rj.make(str(path), localisation="scan_matching", action_mode="velocity", start_yaw="spawn", **over)
    state = env.reset(KEY)
    final, errors = jax.lax.scan(lambda s, _: ((n := env.step(s, jnp.zeros(2))), n.pose - n.truth), state, None, 30)
    assert np.abs(np.asarray(errors)).max() < 1e-6
