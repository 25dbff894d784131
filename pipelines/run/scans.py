"""An odometry log's scans as the localiser takes them: the odometry pose at each and its returns' end points."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from gslam.scan import Scan
from pipelines.errors import InputError
from pipelines.run.input_log import InputLog, OdomEvent, ScanEvent
from pipelines.run.odometry_check import ReversalCheck


def scan_stream(log: InputLog) -> Iterator[tuple[int, float, np.ndarray, np.ndarray, float]]:
    """(scan index, log time, the odometry pose then (the base's, fr079's reversal check applied), the
    scan's end points in the laser frame (K, 2), the scan's own stamp) for every scan of an odometry log."""
    reversal = ReversalCheck()
    odom = None
    for ev in log.events():
        if isinstance(ev, OdomEvent):
            odom = reversal.update(ev.pose, ev.tv_mps)
        elif isinstance(ev, ScanEvent):
            if odom is None:
                raise InputError(f"{log.path}: scan {ev.index} has no odometry before it")
            scan = Scan(ev.stamp_s, ev.ranges_m, ev.geometry or log.geometry, log.self_return_range_m)
            _, r, b = scan.return_polar()
            ends = np.column_stack([r * np.cos(b), r * np.sin(b)])
            yield ev.index, ev.t_s, np.asarray(odom, dtype=float), ends, ev.stamp_s
