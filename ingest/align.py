"""Pair each scan with the odometry pose interpolated at the scan's stamp, as the messages stream in.

A robot's odometry and laser run on their own clocks and rates; the filter wants the odometry pose at
each scan (as a CARMEN FLASER line carries it). Scans wait in a short queue until an odometry sample
at or after their stamp arrives, then get the pose interpolated between the two samples around them
(heading along the shorter arc). Memory stays bounded: odometry older than the scans still waiting is
dropped, and a scan that cannot be bracketed within `max_gap_s` is dropped and counted.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

NS = 1_000_000_000


@dataclass(frozen=True)
class OdomSample:
    t_ns: int
    x_m: float
    y_m: float
    theta_rad: float
    tv_mps: float = math.nan
    rv_radps: float = math.nan


@dataclass
class AlignCounts:
    paired: int = 0
    before_odometry: int = 0  # scans older than the first odometry sample
    after_odometry: int = 0  # scans newer than the last odometry sample
    in_gaps: int = 0  # scans between two odometry samples more than max_gap_s apart
    odometry_backwards: int = 0  # odometry samples whose stamp did not increase (ignored)


def interpolate(a: OdomSample, b: OdomSample, t_ns: int) -> OdomSample:
    if b.t_ns == a.t_ns:
        return a
    f = (t_ns - a.t_ns) / (b.t_ns - a.t_ns)
    dth = math.remainder(b.theta_rad - a.theta_rad, 2 * math.pi)
    return OdomSample(
        t_ns,
        a.x_m + f * (b.x_m - a.x_m),
        a.y_m + f * (b.y_m - a.y_m),
        math.remainder(a.theta_rad + f * dth, 2 * math.pi),
        a.tv_mps + f * (b.tv_mps - a.tv_mps),
        a.rv_radps + f * (b.rv_radps - a.rv_radps),
    )


class ScanOdometryAligner:
    """Feed odometry samples and scans in arrival order; take (scan, odometry at its stamp) pairs out."""

    def __init__(self, max_gap_s: float = 1.0) -> None:
        self.max_gap_ns = int(max_gap_s * NS)
        self.odom: list[OdomSample] = []  # increasing t_ns
        self.odom_t: list[int] = []
        self.pending: deque[tuple[int, Any]] = deque()  # (scan t_ns, scan)
        self.newest_ns: int | None = None
        self.first_odom_ns: int | None = None
        self.counts = AlignCounts()

    def _seen(self, t_ns: int) -> None:
        self.newest_ns = t_ns if self.newest_ns is None else max(self.newest_ns, t_ns)

    def add_odometry(self, sample: OdomSample) -> None:
        self._seen(sample.t_ns)
        if self.odom_t and sample.t_ns <= self.odom_t[-1]:
            self.counts.odometry_backwards += 1
            return
        if self.first_odom_ns is None:
            self.first_odom_ns = sample.t_ns
        self.odom.append(sample)
        self.odom_t.append(sample.t_ns)

    def add_scan(self, t_ns: int, scan: Any) -> None:
        self._seen(t_ns)
        self.pending.append((t_ns, scan))

    def ready(self) -> Iterator[tuple[Any, OdomSample]]:
        """Pairs for the scans that can be decided now, in arrival order."""
        while self.pending:
            t_ns, scan = self.pending[0]
            if self.odom_t and self.odom_t[-1] >= t_ns:
                self.pending.popleft()
                pose = self._at(t_ns)
                if pose is not None:
                    self.counts.paired += 1
                    yield scan, pose
                continue
            # No odometry at or after this scan yet: wait, unless the stream has moved on so far that
            # none can come within the gap (this bounds the queue when odometry stops).
            if self.newest_ns is not None and self.newest_ns - t_ns > 2 * self.max_gap_ns:
                self.pending.popleft()
                self._count_unpaired(t_ns)
                continue
            break
        self._trim()

    def finish(self) -> Iterator[tuple[Any, OdomSample]]:
        """At the end of the stream: pairs still possible, then the rest dropped and counted."""
        yield from self.ready()
        while self.pending:
            t_ns, _ = self.pending.popleft()
            self._count_unpaired(t_ns)

    def _count_unpaired(self, t_ns: int) -> None:
        if self.first_odom_ns is None or t_ns < self.first_odom_ns:
            self.counts.before_odometry += 1
        elif self.odom_t and t_ns > self.odom_t[-1]:
            self.counts.after_odometry += 1
        else:
            self.counts.in_gaps += 1

    def _at(self, t_ns: int) -> OdomSample | None:
        i = bisect.bisect_left(self.odom_t, t_ns)
        if i < len(self.odom_t) and self.odom_t[i] == t_ns:
            return self.odom[i]
        if i == 0:
            self._count_unpaired(t_ns)
            return None
        a, b = self.odom[i - 1], self.odom[i]
        if b.t_ns - a.t_ns > self.max_gap_ns:
            self.counts.in_gaps += 1
            return None
        return interpolate(a, b, t_ns)

    def _trim(self) -> None:
        """Drop odometry no waiting (or slightly late) scan can need: keep one sample older than the
        oldest waiting scan's stamp minus the gap."""
        horizon = (self.pending[0][0] if self.pending else (self.newest_ns or 0)) - self.max_gap_ns
        i = bisect.bisect_right(self.odom_t, horizon) - 1
        if i > 0:
            del self.odom[:i]
            del self.odom_t[:i]
