"""Scan-odometry alignment (ingest.align): interpolation at the scan's stamp, drops counted, bounded queue."""

from __future__ import annotations

import math

import pytest

from ingest.align import NS, OdomSample, ScanOdometryAligner


def sample(t_s: float, x: float, theta: float = 0.0) -> OdomSample:
    return OdomSample(int(t_s * NS), x, 2 * x, theta)


def test_interpolates_at_the_scan_stamp_in_arrival_order():
    a = ScanOdometryAligner(max_gap_s=1.0)
    a.add_odometry(sample(0.0, 0.0))
    a.add_scan(int(0.25 * NS), "s1")  # waits: no odometry after it yet
    a.add_scan(int(0.5 * NS), "s2")
    assert list(a.ready()) == []
    a.add_odometry(sample(1.0, 4.0))
    pairs = list(a.ready())
    assert [s for s, _ in pairs] == ["s1", "s2"]
    assert [(p.x_m, p.y_m) for _, p in pairs] == [(1.0, 2.0), (2.0, 4.0)]
    assert a.counts.paired == 2


def test_exact_stamp_takes_the_sample_itself():
    a = ScanOdometryAligner()
    a.add_odometry(sample(1.0, 3.0, 0.5))
    a.add_scan(int(1.0 * NS), "s")
    ((_, p),) = list(a.ready())
    assert (p.x_m, p.theta_rad) == (3.0, 0.5)


def test_heading_interpolates_along_the_shorter_arc():
    a = ScanOdometryAligner()
    a.add_odometry(sample(0.0, 0.0, math.pi - 0.1))
    a.add_odometry(sample(1.0, 0.0, -math.pi + 0.1))
    a.add_scan(int(0.5 * NS), "s")
    ((_, p),) = list(a.ready())
    assert abs(math.remainder(p.theta_rad - math.pi, 2 * math.pi)) == pytest.approx(0.0, abs=1e-12)


def test_scans_outside_or_in_gaps_are_counted_not_paired():
    a = ScanOdometryAligner(max_gap_s=1.0)
    a.add_scan(int(0.5 * NS), "early")
    a.add_odometry(sample(1.0, 0.0))
    a.add_odometry(sample(1.5, 1.0))
    a.add_odometry(sample(4.0, 2.0))  # a 2.5 s gap
    a.add_odometry(sample(3.0, 9.0))  # goes backwards: ignored
    a.add_scan(int(2.0 * NS), "gap")
    a.add_scan(int(1.2 * NS), "ok")
    a.add_scan(int(5.0 * NS), "late")
    pairs = list(a.ready()) + list(a.finish())
    assert [s for s, _ in pairs] == ["ok"]
    c = a.counts
    assert (c.paired, c.before_odometry, c.in_gaps, c.after_odometry, c.odometry_backwards) == (1, 1, 1, 1, 1)


def test_queue_and_history_stay_bounded_when_odometry_stops():
    """Memory is flat: odometry that stopped does not make scans pile up, and old odometry is dropped."""
    a = ScanOdometryAligner(max_gap_s=1.0)
    for k in range(50):
        a.add_odometry(sample(k * 0.1, k * 0.1))
        a.add_scan(int((k * 0.1 + 0.05) * NS), k)
        list(a.ready())
    assert len(a.odom) <= 12  # about max_gap_s of 10 Hz odometry
    for k in range(2000):  # scans keep coming, odometry has stopped
        a.add_scan(int((5.0 + k * 0.1) * NS), k)
        list(a.ready())
        assert len(a.pending) <= 25  # 2 max_gap_s of 10 Hz scans
    list(a.finish())
    assert (a.counts.paired, a.counts.after_odometry) == (49, 2001)  # the 50th scan came after the last sample
