"""The GMapping harness's text log written from an input MCAP (pipelines.bench.gmapping_log), as its driver
reads it: `SCAN t x y theta angle_min angle_increment n r_1 ... r_n`."""

from __future__ import annotations

import numpy as np

from gslam.motion import integrate_ackermann
from gslam.vehicle import vehicle_preset
from pipelines.bench.gmapping_log import write_gmapping_log
from pipelines.run.input_log import ControlEvent, InputLog, ScanEvent


def _parse(path):
    rows = []
    for line in path.read_text().splitlines():
        f = line.split()
        assert f[0] == "SCAN"
        n = int(f[7])
        assert len(f) == 8 + n, "the driver reads exactly n ranges after n"
        pose, ranges = np.array(f[2:5], dtype=float), np.array(f[8:], dtype=float)
        rows.append((float(f[1]), pose, float(f[5]), float(f[6]), ranges))
    return rows


def test_the_car_parks_scans_with_their_dead_reckoned_laser_poses(carpark_mcap, tmp_path):
    out = tmp_path / "carpark.gmapping.txt"
    count = write_gmapping_log(carpark_mcap, out)
    log = InputLog(carpark_mcap)
    geom = log.geometry
    rows = _parse(out)
    assert count == len(rows) == log.scan_count
    assert {(a, b) for _, _, a, b, _ in rows} == {(round(geom.start_angle_rad, 9), round(geom.angle_increment_rad, 9))}
    # no-return beams at the maximum range (GMapping's `--maxrange auto` leaves them out), the rest as read
    ranges = np.array([r for *_, r in rows])
    assert ranges.max() == geom.max_range_m and ranges.min() >= 0
    assert 0 < (ranges == geom.max_range_m).mean() < 0.9
    # the poses are the vehicle model's dead reckoning from (0, 0, 0): recompute them independently, in
    # one pass over all the controls, and compare at the scan times
    vehicle = vehicle_preset(log.meta["vehicle"].get("preset", "carpark"))
    events = list(log.events())
    scans = [e for e in events if isinstance(e, ScanEvent)]
    controls = np.array([[e.t_s, e.speed_mps, e.steering_rad] for e in events if isinstance(e, ControlEvent)])
    t = np.array([s.t_s for s in scans])
    assert np.allclose([r[0] for r in rows], t, atol=1e-6)
    poses = np.array([p for _, p, *_ in rows])
    assert np.allclose(poses[0], 0.0)
    k = len(t) // 2
    before = controls[controls[:, 0] <= t[0]]
    u = np.vstack([before[-1:], controls[(controls[:, 0] > t[0]) & (controls[:, 0] <= t[k])]])
    mid = integrate_ackermann(np.zeros((1, 3)), u, t[k], t[0], vehicle)[0]
    # within 1 cm: the export integrates scan to scan, which splits the controls' Euler steps at the scans
    # (here 1.6 mm apart after ~half the drive); the heading does not depend on the split
    assert np.allclose(poses[k, :2], mid[:2], atol=0.01), (poses[k], mid)
    assert abs(poses[k, 2] - mid[2]) < 1e-5
    travelled = np.hypot(*np.diff(poses[:, :2], axis=0).T).sum()
    assert travelled > 50, "the Car Park drive is a few hundred metres"
