"""Tie a run's frame to GPS at the start: first fix position, heading fitted over the first seconds."""

from __future__ import annotations

import numpy as np

from gslam.motion import integrate_ackermann
from gslam.vehicle import AckermannVehicle


def dead_reckoning(
    controls: np.ndarray, start_pose: np.ndarray, t_start_s: float, times_s: np.ndarray, vehicle: AckermannVehicle
) -> np.ndarray:
    """Noise-free Ackermann dead reckoning from `start_pose` at t_start_s, sampled at `times_s` (sorted)."""
    out = np.empty((len(times_s), 3))
    pose = np.asarray(start_pose, dtype=float)[None, :]
    t = t_start_s
    for k, t_next in enumerate(times_s):
        lo = max(int(np.searchsorted(controls[:, 0], t, side="right")) - 1, 0)
        hi = int(np.searchsorted(controls[:, 0], t_next, side="left"))
        pose = integrate_ackermann(pose, controls[lo : max(hi, lo + 1)], t_next, t, vehicle)
        out[k] = pose[0]
        t = t_next
    return out


def fit_initial_heading(
    controls: np.ndarray, gps: np.ndarray, vehicle: AckermannVehicle, window_s: float = 5.0
) -> np.ndarray:
    """Initial laser pose (x, y, phi) at the first GPS fix: the fix's position, and the heading that
    makes noise-free dead reckoning best match GPS (least squares) over the first `window_s` seconds.

    controls: (K, 3) t_s, speed, steering; gps: (G, 3) t_s, x, y.
    """
    t0 = gps[0, 0]
    sel = (gps[:, 0] > t0) & (gps[:, 0] <= t0 + window_s)
    if sel.sum() < 2:
        raise ValueError(f"need at least 2 GPS fixes in the first {window_s} s to fit the initial heading")
    dr = dead_reckoning(controls, np.zeros(3), t0, gps[sel, 0], vehicle)[:, :2]
    target = gps[sel, 1:3] - gps[0, 1:3]
    # Rotation about the start that best maps dr onto target: angle = atan2(sum cross, sum dot).
    cross = np.sum(dr[:, 0] * target[:, 1] - dr[:, 1] * target[:, 0])
    dot = np.sum(dr[:, 0] * target[:, 0] + dr[:, 1] * target[:, 1])
    return np.array([gps[0, 1], gps[0, 2], float(np.arctan2(cross, dot))])
