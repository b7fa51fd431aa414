"""PNG images for the teleoperation page (OpenCV encodes them)."""

from __future__ import annotations

import cv2
import numpy as np

_MAP_COLORS = np.array([[150, 150, 150], [245, 245, 245], [30, 30, 30]], np.uint8)  # occupancy.UNKNOWN, FREE, OCCUPIED
MAP_SCALE = 3  # screen pixels per map cell


def map_png(env, occupancy: np.ndarray, pose: np.ndarray, trail: list | None = None) -> bytes:
    """The robot's own occupancy map (north up) with its pose drawn as a disc and heading."""
    g = env.grid
    origin = np.asarray(g.origin, float)
    img = _MAP_COLORS[np.clip(occupancy, 0, 2)][::-1]  # row 0 = south: flip so north is up
    img = cv2.resize(img, (img.shape[1] * MAP_SCALE, img.shape[0] * MAP_SCALE), interpolation=cv2.INTER_NEAREST)
    h = img.shape[0]

    def px(x, y):
        return (int((x - origin[0]) / g.resolution * MAP_SCALE), int(h - (y - origin[1]) / g.resolution * MAP_SCALE))

    for a, b in zip(trail or [], (trail or [])[1:]):
        cv2.line(img, px(*a), px(*b), (90, 160, 230), 1, cv2.LINE_AA)
    x, y, yaw = (float(v) for v in pose)
    r = max(3, int(env.config.robot.radius / g.resolution * MAP_SCALE))
    cv2.circle(img, px(x, y), r, (40, 90, 220), -1, cv2.LINE_AA)
    tip = px(x + 2.2 * env.config.robot.radius * np.cos(yaw), y + 2.2 * env.config.robot.radius * np.sin(yaw))
    cv2.line(img, px(x, y), tip, (20, 20, 160), 2, cv2.LINE_AA)
    return _png(img)


def rgb_png(img: np.ndarray) -> bytes:
    return _png(img)


def depth_png(depth: np.ndarray, max_range: float) -> bytes:
    """Depth (h, w) as a colour map, near = warm; no return = black."""
    d = np.clip(depth / max_range, 0, 1)
    img = cv2.applyColorMap((255 * (1 - d)).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
    img[depth >= max_range] = 0
    return _png(img)


def _png(rgb: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    assert ok
    return buf.tobytes()
