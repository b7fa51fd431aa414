"""The fused mapper on hand-built frames: depth rendered from planes by hand (rays against
axis-aligned rectangles), so each case's answer is known without a session."""

from __future__ import annotations

import numpy as np
import pytest

from rosmeery_jax.mapping.fused import FusedConfig, FusedMapper, plausible, weight
from rosmeery_jax.mapping.protocol import Camera, Frame
from rosmeery_jax.raycast.sensors import CameraConfig

CATS = ("chair", "table", "cabinet")
CAM = Camera.of(CameraConfig())
WALL = (2.0, (-5.0, 5.0), (0.0, 3.0))  # a face at x = 2 m: (x, y range, z range)
CUBE = (2.0, (-0.25, 0.25), (0.0, 0.5))  # a 0.5 m cube's near face, nothing behind it


def _render(robot, faces, rng=None, sigma=0.0) -> np.ndarray:
    """(H, W) depth along the optical axis of faces facing -x, seen from ``robot`` (x, y,
    yaw); 0 where no face is hit; Gaussian noise of ``sigma`` m."""
    pose = CAM.pose(np.asarray(robot, np.float64))
    k = CAM.intrinsics
    u, v = np.meshgrid(np.arange(CAM.width, dtype=np.float64), np.arange(CAM.height, dtype=np.float64))
    rays = np.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], np.ones_like(u)], -1) @ pose[:3, :3].T
    o = pose[:3, 3]
    depth = np.full(u.shape, np.inf)
    for x, (y0, y1), (z0, z1) in faces:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (x - o[0]) / rays[..., 0]  # along the optical axis: rays have unit z in the camera frame
        p = o + t[..., None] * rays
        on = (t > 0) & (p[..., 1] >= y0) & (p[..., 1] <= y1) & (p[..., 2] >= z0) & (p[..., 2] <= z1)
        depth = np.where(on, np.minimum(depth, t), depth)
    if rng is not None:
        depth = depth + rng.normal(0.0, sigma, depth.shape)
    return np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)


def _frame(i, robot, depth, labels=(0,), conf=0.9, camera_robot=None) -> Frame:
    """Frame ``i`` with one box over the whole image per label; its camera pose that of
    ``camera_robot`` (the robot's estimate) or of ``robot``."""
    boxes = np.tile(np.float32([0, 0, CAM.width - 1, CAM.height - 1]), (len(labels), 1))
    est = np.asarray(camera_robot if camera_robot is not None else robot, np.float64)
    return Frame(i, float(i), np.zeros((CAM.height, CAM.width, 3), np.uint8), depth, est.astype(np.float32),
                 CAM.pose(est), boxes, np.asarray(labels, np.int64), np.full(len(labels), conf, np.float32))


def test_a_wall_seen_from_two_poses_with_1_cm_noise_is_one_surface():
    rng = np.random.default_rng(0)
    m = FusedMapper(CAM, CATS)
    for i, robot in enumerate([(0.0, 0.0, 0.0), (0.3, 0.5, 0.2)] * 2):
        m.add(_frame(i, robot, _render(robot, [WALL], rng, 0.01)))
    s = m.semantic_map()
    assert len(s.label) == 1 and s.label[0] == 0  # one instance, a chair (its only votes)
    x = s.points[:, 0]  # the points of one surface at x = 2: spread as the noise, no second layer
    assert np.abs(x - 2.0).max() < 0.05 and 0.005 < x.std() < 0.015 and abs(x.mean() - 2.0) < 0.002
    assert len(s.points) > 1000  # the wall's face in view, a point per 2.5 cm half-voxel


def test_a_label_seen_three_times_as_chair_and_once_as_table_is_a_chair():
    m = FusedMapper(CAM, CATS)
    robot = (0.0, 0.0, 0.0)
    for i, label in enumerate([0, 1, 0, 0]):  # chair, table, chair, chair
        m.add(_frame(i, robot, _render(robot, [CUBE]), labels=(label,), conf=0.8))
    s = m.semantic_map()
    assert list(s.label) == [0] and len(np.unique(s.instance)) == 1
    # three votes of 0.8 against one: mass 0.8^3 0.2/2 / (... + 0.8 0.2^3/4 + ...) by Bayes per voxel
    assert 0.9 < s.confidence[0] <= 1.0


def test_a_3_cm_pose_offset_does_not_split_an_instance():
    m = FusedMapper(CAM, CATS)
    truth = np.array([0.0, 0.0, 0.0])
    for i, est in enumerate([truth, truth + [0.03, 0.03, 0.0], truth, truth + [0.03, 0.03, 0.0]]):
        m.add(_frame(i, truth, _render(truth, [CUBE]), camera_robot=est))  # depth from the truth, pose estimated
    s = m.semantic_map()
    assert len(np.unique(s.instance)) == 1 and len(s.label) == 1 and s.label[0] == 0
    assert 0.45 < np.ptp(s.points[:, 1]) < 0.5 + 0.035  # the cube's 0.5 m, up to the 3 cm offset


def test_what_depth_is_plausible():
    d = np.full((5, 6), 2.0, np.float32)
    d[2, 3] = 3.0  # a mixed pixel's jump: it and its 4 neighbours fail
    d[0, 0], d[4, 5], d[0, 5] = 0.0, np.nan, 9.0  # no return, NaN, beyond the range
    ok = plausible(d, 8.0, 0.05)
    assert not ok[2, 3] and not ok[1, 3] and not ok[3, 3] and not ok[2, 2] and not ok[2, 4]
    assert not ok[0, 0] and not ok[4, 5] and not ok[0, 5] and ok[4, 0]
    assert weight(np.array([0.5, 1.0]))[1] == 1.0 and weight(np.array([4.0]))[0] == pytest.approx(0.001884 / 0.025824)  # sigma(1 m), sigma(4 m)


def test_bad_frames_give_a_defined_map():
    m = FusedMapper(CAM, CATS)
    robot = (0.0, 0.0, 0.0)
    nan = np.full((CAM.height, CAM.width), np.nan, np.float32)
    m.add(_frame(0, robot, nan))  # every pixel invalid
    m.add(_frame(1, robot, np.zeros_like(nan)))
    assert len(m.semantic_map().points) == 0
    for i, jump in enumerate([(0.0, 0.0, 0.0), (10.0, 0.0, 0.0)] * 2):  # the estimate jumps 10 m between frames
        m.add(_frame(2 + i, robot, _render(robot, [CUBE]), camera_robot=jump))
    s = m.semantic_map()
    assert np.isfinite(s.points).all() and np.isfinite(s.confidence).all() and len(np.unique(s.instance)) == 2


@pytest.mark.parametrize("kw, needle", [({"voxel": 0.0}, "voxel must be > 0"), ({"voxel": -0.05}, "voxel must be > 0"),
                                        ({"truncation": 0.02}, "truncation at least the voxel"),
                                        ({"voxel": float("nan")}, "voxel must be a finite number")])
def test_bad_settings_are_one_line(kw, needle):
    with pytest.raises(ValueError, match=needle) as err:
        FusedConfig(**kw)
    assert "\n" not in str(err.value)
