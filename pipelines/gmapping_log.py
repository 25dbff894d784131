"""An input MCAP as the GMapping harness's text log (`../shared/tools/gmapping`, its README): one line
`SCAN t x y theta angle_min angle_increment n r_1 ... r_n` per scan, so that OpenSLAM GMapping can be timed
beside gslam on a log that is not CARMEN (the Car Park). The pose on each line is the laser's odometry:
for a vehicle's controls (speed, steering), their dead reckoning with the log's vehicle model and no noise
(the filter's motion model, `gslam.motion.integrate_ackermann`, zero-order hold between samples), from
(0, 0, 0) at the first scan; for odometry poses, the last one before the scan (moved to the laser where
the log records a mount). Beams with no return are written at the sensor's maximum range, which the
harness's `--maxrange auto` then leaves out, as it does the CARMEN logs' no-return readings."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from gslam.motion import integrate_ackermann
from gslam.vehicle import vehicle_preset
from mcaplog.tempfiles import write_atomic

from .errors import InputError
from .source import ControlEvent, InputLog, OdomEvent, ScanEvent


def gmapping_scan_lines(log: InputLog) -> Iterator[str]:
    """The `SCAN` lines of `log` (see the module docstring), in the order of its scans."""
    geom = log.geometry
    vehicle = None
    if log.motion_model == "ackermann":
        vehicle = vehicle_preset(log.meta["vehicle"].get("preset", "carpark"))
    pose = np.zeros(3)
    controls: list[list[float]] = []
    held: list[float] | None = None  # the control in force since the previous scan
    t_prev: float | None = None
    odom: np.ndarray | None = None
    head = f"{geom.start_angle_rad:.9f} {geom.angle_increment_rad:.9f} {geom.beam_count}"
    for ev in log.events():
        if isinstance(ev, ControlEvent):
            controls.append([ev.t_s, ev.speed_mps, ev.steering_rad])
        elif isinstance(ev, OdomEvent):
            odom = ev.pose
        elif isinstance(ev, ScanEvent):
            if vehicle is not None:
                if t_prev is not None:
                    rows = ([held] if held is not None else []) + controls
                    if rows:
                        u = np.asarray(rows, dtype=float)
                        pose = integrate_ackermann(pose[None], u, ev.t_s, t_prev, vehicle)[0]
                if controls:
                    held = controls[-1]
                controls = []
                t_prev = ev.t_s
            else:
                if odom is None:
                    continue  # no odometry yet: GMapping could not place this scan either
                pose = odom if log.mount is None else log.mount.laser_of(odom)
            r = np.asarray(ev.ranges_m, dtype=float)
            r = np.where(np.isfinite(r) & (r < geom.max_range_m), r, geom.max_range_m)
            yield (
                f"SCAN {ev.t_s:.6f} {pose[0]:.6f} {pose[1]:.6f} {pose[2]:.6f} {head} " + " ".join(f"{v:.3f}" for v in r)
            )


def write_gmapping_log(input_path: Path, output_path: Path) -> int:
    """Write the GMapping text log of the input MCAP `input_path` to `output_path` (atomically); returns
    the number of scans written."""
    log = InputLog(input_path)
    lines = list(gmapping_scan_lines(log))
    if not lines:
        raise InputError(f"{input_path}: no scan with a pose to write for GMapping")
    write_atomic(Path(output_path), "\n".join(lines) + "\n")
    return len(lines)
