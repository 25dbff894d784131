"""The coarse start's deeper pyramid after a long travel (`match_coarse_deeper_travel_m`): a log whose scans lie
metres apart (a Radish log at 1 to 3 m a scan) meets a slip's error of a metre and more at one update, beyond
the 0.2 m raster's basin, and the matcher then also climbs from a raster of 0.8 m cells. Where the travel
between updates stays short (every log of the corpus) nothing changes.

A simulated robot drives the corridor loop (tests/worlds.py) with scans 1.6 m apart; its odometry reports
two steps at twice their length (a wheel slip), so two updates each follow 3.2 m of reported travel.
"""

from __future__ import annotations

import numpy as np
import pytest
from worlds import corridor_world, drive_filter, simulate_robot_loop

import gslam.filter
from gslam.config import FilterConfig
from gslam.filter import GSlamFilter, StepResult
from gslam.motion import apply_odometry, odometry_delta
from gslam.scan import ScanGeometry

SLIP = (7, 8)
"""The scans whose odometry step is reported at twice its length."""
MATCH_AND_WEIGH = gslam.filter.match_and_weigh


def _log(slip: tuple[int, ...]):
    sim = simulate_robot_loop(corridor_world(), np.random.default_rng(4), laps=1.0, speed_mps=8.0)
    odometry = [sim.odometry[0]]
    for k in range(1, len(sim.t_s)):
        d = odometry_delta(sim.odometry[k - 1], sim.odometry[k])
        if k in slip:
            d = (2 * d[0], 2 * d[1], d[2])
        odometry.append(apply_odometry(odometry[-1][None, :], d, None, (0, 0, 0, 0))[0])
    geom = ScanGeometry(len(sim.ranges[0]), sim.start_angle_rad, sim.angle_increment_rad, sim.max_range_m)
    return sim, np.array(odometry), geom


def _drive(sim, odometry, geom, monkeypatch, **options) -> tuple[list[StepResult], list[tuple[float, int]]]:
    """Each scan's step result, and each match's (travel since the last update, coarse pyramid depth)."""
    cfg = FilterConfig(particles=16, seed=0, **options)
    flt = GSlamFilter(cfg, sim.truth[0])
    calls: list[tuple[float, int]] = []

    def spy(*args, **kwargs):
        calls.append((flt._travel_m, kwargs["coarse_depth"]))
        return MATCH_AND_WEIGH(*args, **kwargs)

    monkeypatch.setattr(gslam.filter, "match_and_weigh", spy)
    results = list(drive_filter(flt, np.arange(len(sim.t_s), dtype=float), odometry, sim.ranges, geom))
    return results, calls


def test_the_deeper_pyramid_is_climbed_where_the_travel_reached_the_threshold(monkeypatch):
    sim, odometry, geom = _log(SLIP)
    deeper = FilterConfig().match_coarse_deeper_travel_m
    results, calls = _drive(sim, odometry, geom, monkeypatch)
    depth = FilterConfig().match_coarse_depth
    deep = [travel for travel, d in calls if d == depth + 1]
    assert len(deep) == len(SLIP), calls  # the two slipped steps, 3.2 m of reported travel each
    assert all(travel >= deeper for travel in deep)
    assert all(d == depth for travel, d in calls if travel < deeper)
    err = np.hypot(*(np.array([r.best_pose for r in results])[:, :2] - sim.truth[:, :2]).T)
    assert err.max() < 0.3, err  # the slips' 1.6 m errors recovered


@pytest.mark.parametrize("slip", [(), SLIP])
def test_off_or_never_reached_the_run_is_the_same(monkeypatch, slip):
    """Without a slip the travel stays at 1.6 m an update: the run is the very same as with the rule off.
    With the slip, only the two long updates climb the deeper pyramid."""
    sim, odometry, geom = _log(slip)
    on, on_calls = _drive(sim, odometry, geom, monkeypatch)
    off, off_calls = _drive(sim, odometry, geom, monkeypatch, match_coarse_deeper_travel_m=0.0)
    if not slip:
        assert [c[1] for c in on_calls] == [c[1] for c in off_calls]
        for a, b in zip(on, off, strict=True):
            np.testing.assert_array_equal(a.poses, b.poses)
    else:
        assert sum(d for _, d in on_calls) == sum(d for _, d in off_calls) + len(SLIP)
