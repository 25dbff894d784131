"""An input MCAP as the GMapping harness's text log (`../shared/tools/gmapping`, its README): one line
`SCAN t x y theta angle_min angle_increment n r_1 ... r_n` per scan, so that OpenSLAM GMapping can be timed
beside gslam on a log that is not CARMEN (the Car Park). The pose on each line is the laser's odometry:
for a vehicle's controls (speed, steering), their dead reckoning with the log's vehicle model and no noise
(the filter's motion model, `gslam.initialisation.dead_reckoning`, zero-order hold between samples),
from (0, 0, 0) at the first scan; for odometry poses, the last one before the scan (moved to the laser where
the log records a mount). Beams with no return are written at the sensor's maximum range, which the
harness's `--maxrange auto` then leaves out, as it does the CARMEN logs' no-return readings."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from gslam.initialisation import dead_reckoning
from mcaplog.tempfiles import write_atomic
from pipelines.errors import InputError
from pipelines.run.input_log import ControlEvent, InputLog, OdomEvent, ScanEvent


def gmapping_scan_lines(log: InputLog) -> Iterator[str]:
    """The `SCAN` lines of `log` (see the module docstring), in the order of its scans."""
    geom = log.geometry
    head = f"{geom.start_angle_rad:.9f} {geom.angle_increment_rad:.9f} {geom.beam_count}"
    controls: list[list[float]] = []
    odom: np.ndarray | None = None
    scans: list[tuple[ScanEvent, np.ndarray | None]] = []  # with the last odometry pose before each
    for ev in log.events():
        if isinstance(ev, ControlEvent):
            controls.append([ev.t_s, ev.speed_mps, ev.steering_rad])
        elif isinstance(ev, OdomEvent):
            odom = ev.pose
        elif isinstance(ev, ScanEvent):
            scans.append((ev, odom))
    if log.motion_model == "ackermann":
        if not scans:
            return
        vehicle = log.vehicle()
        times = np.array([ev.t_s for ev, _ in scans])
        u = np.asarray(controls, dtype=float).reshape(-1, 3)
        poses = list(dead_reckoning(u, np.zeros(3), float(times[0]), times, vehicle))
    else:  # a scan before any odometry is left out: GMapping could not place it either
        scans = [(ev, o) for ev, o in scans if o is not None]
        poses = [o if log.mount is None else log.mount.laser_of(o) for _, o in scans]
    for (ev, _), pose in zip(scans, poses, strict=True):
        r = np.asarray(ev.ranges_m, dtype=float)
        r = np.where(np.isfinite(r) & (r < geom.max_range_m), r, geom.max_range_m)
        own = ev.geometry if ev.geometry is not None else geom
        beams = head if own is geom else f"{own.start_angle_rad:.9f} {own.angle_increment_rad:.9f} {own.beam_count}"
        yield f"SCAN {ev.t_s:.6f} {pose[0]:.6f} {pose[1]:.6f} {pose[2]:.6f} {beams} " + " ".join(f"{v:.3f}" for v in r)


def write_gmapping_log(input_path: Path, output_path: Path) -> int:
    """Write the GMapping text log of the input MCAP `input_path` to `output_path` (atomically); returns
    the number of scans written."""
    log = InputLog(input_path)
    lines = list(gmapping_scan_lines(log))
    if not lines:
        raise InputError(f"{input_path}: no scan with a pose to write for GMapping")
    write_atomic(Path(output_path), "\n".join(lines) + "\n")
    return len(lines)
