"""A log's scans as the localiser and the start search take them: the robot's pose by its odometry (or, for an
Ackermann log, by its controls) at each, and its returns' end points."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from gslam.motion import integrate_ackermann
from gslam.scan import Scan
from gslam.vehicle import AckermannVehicle
from pipelines.errors import InputError
from pipelines.run.input_log import ControlEvent, InputLog, OdomEvent, ScanEvent
from pipelines.run.odometry_check import ReversalCheck

ScanRow = tuple[int, float, np.ndarray, np.ndarray, float]
"""(scan index, log time, the pose by the motion then, the scan's end points in the laser frame (K, 2), the
scan's own stamp)."""


def scan_stream(log: InputLog, vehicle: AckermannVehicle | None = None) -> Iterator[ScanRow]:
    """Every scan of the log (`ScanRow`). An odometry log: the odometry pose (the base's, fr079's reversal check
    applied). An Ackermann log: the laser's pose dead-reckoned from the controls with `vehicle` (default: the
    log's own, `InputLog.vehicle`) without noise (zero-order hold, as the filter's motion model), from
    (0, 0, 0) at the first control; only the motion between scans means anything there, as with odometry."""
    if log.motion_model != "odometry":
        yield from _dead_reckoned(log, vehicle or log.vehicle())
        return
    reversal = ReversalCheck()
    odom = None
    for ev in log.events():
        if isinstance(ev, OdomEvent):
            odom = reversal.update(ev.pose, ev.tv_mps)
        elif isinstance(ev, ScanEvent):
            if odom is None:
                raise InputError(f"{log.path}: scan {ev.index} has no odometry before it")
            yield ev.index, ev.t_s, np.asarray(odom, dtype=float), _ends(log, ev), ev.stamp_s


def _dead_reckoned(log: InputLog, vehicle: AckermannVehicle) -> Iterator[ScanRow]:
    pose = np.zeros((1, 3))
    held: list[float] | None = None  # the control in force: (t_s, speed, steering)
    t = 0.0  # the time `pose` is at

    def move_to(t_next: float) -> None:
        nonlocal pose, t
        if held is not None and t_next > t:
            pose = integrate_ackermann(pose, np.array([held]), t_next, t, vehicle)
        t = max(t, t_next)

    for ev in log.events():
        if isinstance(ev, ControlEvent):
            if held is None:
                t = ev.t_s
            move_to(ev.t_s)
            held = [ev.t_s, ev.speed_mps, ev.steering_rad]
        elif isinstance(ev, ScanEvent):
            if held is None:
                raise InputError(f"{log.path}: scan {ev.index} has no odometry before it")
            move_to(ev.t_s)
            yield ev.index, ev.t_s, pose[0].copy(), _ends(log, ev), ev.stamp_s


def _ends(log: InputLog, ev: ScanEvent) -> np.ndarray:
    scan = Scan(ev.stamp_s, ev.ranges_m, ev.geometry or log.geometry, log.self_return_range_m)
    _, r, b = scan.return_polar()
    return np.column_stack([r * np.cos(b), r * np.sin(b)])
