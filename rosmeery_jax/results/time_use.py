"""Where a run's time went: every control step of a robot named by its navigator's status.

One row per seed (``navigation.csv``): seconds spent

- ``moving_s``: driving to a target (including the final turn to its yaw);
- ``recovering_s``: backing off and turning after no progress (``sim.navigation``);
- ``idle_s``: nothing to drive to: before the first target, or a target reached and the
  policy not yet deciding again (a frontier explorer with nothing left stays here);
- ``stuck_s``, ``unreachable_s``, ``timeout_s``: the navigator gave up on a target, and the
  robot waits for the policy's next decision;

which add up to the run's duration; and two measures of standing still:

- ``still_s``: the seconds of 10 s windows (0-10, 10-20, ...) in which the robot stayed
  within 0.1 m of where the window began, whatever the cause;
- ``longest_stuck_s``: the longest stretch in which the navigator was driving (moving or
  recovering) yet the robot stayed within 0.1 m of where the stretch began.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rosmeery_jax.results.tables import seconds
from rosmeery_jax.sim.navigation import IDLE, MOVING, REACHED, RECOVERING, STUCK, TIMEOUT, UNREACHABLE

CAUSES = {"moving": (MOVING,), "recovering": (RECOVERING,), "idle": (IDLE, REACHED), "stuck": (STUCK,),
          "unreachable": (UNREACHABLE,), "timeout": (TIMEOUT,)}
WINDOW_S = 10.0
STILL_M = 0.1


def account(status: np.ndarray, poses: np.ndarray, dt: float) -> dict[str, float]:
    """One robot: status (T + 1,) and poses (T + 1, 3) at steps 0..T (step 0 the reset).
    Entry k >= 1 is the status the navigator reported for the control period ending at
    step k, so the causes' seconds sum to T * dt."""
    period = np.asarray(status[1:])
    row = {f"{name}_s": float(seconds(np.isin(period, codes).sum() * dt)) for name, codes in CAUSES.items()}
    xy = np.asarray(poses[:, :2], np.float64)
    row["still_s"] = _still(xy, dt)
    row["longest_stuck_s"] = _longest_stuck(xy, np.isin(period, (MOVING, RECOVERING)), dt)
    return row


def _still(xy: np.ndarray, dt: float) -> float:
    """Seconds of whole 10 s windows in which the robot stayed within 0.1 m of the window's start."""
    w = int(round(WINDOW_S / dt))
    n = (len(xy) - 1) // w
    if n == 0:
        return 0.0
    spans = xy[:n * w].reshape(n, w, 2)
    far = np.linalg.norm(spans - spans[:, :1], axis=-1).max(axis=1)
    return float((far < STILL_M).sum() * WINDOW_S)


def _longest_stuck(xy: np.ndarray, driving: np.ndarray, dt: float) -> float:
    """The longest run of driving periods within 0.1 m of the run's first position."""
    best, anchor = 0, -1
    x, y = xy[1:, 0].tolist(), xy[1:, 1].tolist()
    for k, d in enumerate(driving.tolist()):
        if not d:
            anchor = -1
            continue
        if anchor < 0 or (x[k] - x[anchor]) ** 2 + (y[k] - y[anchor]) ** 2 > STILL_M ** 2:
            anchor = k
        best = max(best, k - anchor + 1)
    return float(seconds(best * dt))


def frame(status: np.ndarray, poses: np.ndarray, dt: float, seeds, **tags) -> pd.DataFrame:
    """Rows of :func:`account` for every seed: status (S, T + 1), poses (S, T + 1, 3); seeds
    (S,) their numbers."""
    return pd.DataFrame([{**tags, "seed": s, **account(status[i], poses[i], dt)} for i, s in enumerate(seeds)])


def summary(df: pd.DataFrame) -> str:
    """One line: the share of all robots' time per cause, the still share, the longest stuck stretch."""
    total = df[[f"{c}_s" for c in CAUSES]].to_numpy().sum()
    parts = ", ".join(f"{c} {100 * df[f'{c}_s'].sum() / total:.1f} %" for c in CAUSES)
    return (f"navigation: {parts}; still {100 * df.still_s.sum() / total:.1f} % of the time; "
            f"longest stuck {df.longest_stuck_s.max():.1f} s")
