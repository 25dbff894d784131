"""A simulated world with known obstacles: points end on the obstacles and free space stays empty."""

from __future__ import annotations

import math

import numpy as np
import pytest
from worlds import carpark_world, simulate_loop

from gslam.config import FilterConfig
from gslam.filter import GSlamFilter
from gslam.motion import integrate_ackermann
from gslam.scan import Scan, ScanGeometry
from gslam.vehicle import VEHICLE_PRESETS
from pipelines.demo.world import World, distance_to_obstacles, ray_cast

CAR = VEHICLE_PRESETS["carpark"]


def test_ray_cast_by_hand():
    world = World(np.array([[5.0, 0.0, 1.0]]), np.array([[0.0, 3.0, 10.0, 3.0]]))
    r = ray_cast(world, np.zeros(2), np.array([0.0, math.pi / 2, math.pi, math.atan2(3, 3)]), 80.0)
    assert r[0] == pytest.approx(4.0)  # pole surface at x = 4
    assert r[1] == pytest.approx(3.0)  # wall at y = 3
    assert math.isinf(r[2])  # nothing behind
    assert r[3] == pytest.approx(math.hypot(3, 3))


@pytest.fixture(scope="module", params=["motion", "scan_match"])
def run(request):
    rng = np.random.default_rng(7)
    world = carpark_world(rng)
    sim = simulate_loop(world, CAR, rng, duration_s=30.0)
    geom = ScanGeometry(361, -math.pi / 2, math.pi / 360, 80.0)
    if request.param == "motion":
        # Pinned options (measured with these): the world is small and symmetric, so results vary with them.
        cfg = FilterConfig(
            particles=8, seed=3, proposal="motion", weighting="beam_sum", weight_tempering=0.3, weight_sigma_m=0.3
        )
    else:
        cfg = FilterConfig(particles=8, seed=3)  # the defaults: scan matching against each particle's map
    flt = GSlamFilter(cfg, sim.truth[0, 1:])
    dead = sim.truth[0:1, 1:].copy()
    dr = [dead[0].copy()]
    t_prev = sim.scan_t[0]
    for k in range(1, len(sim.scan_t)):
        t = sim.scan_t[k]
        lo = np.searchsorted(sim.controls[:, 0], t_prev, side="right") - 1
        hi = np.searchsorted(sim.controls[:, 0], t, side="left")
        u = sim.controls[lo:hi]

        def predict(poses, g, u=u, t0=t_prev, t1=t):
            return integrate_ackermann(
                poses, u, t1, t0, CAR, g, cfg.speed_sigma_mps, cfg.speed_sigma_rel, cfg.steering_sigma_rad
            )

        flt.step(Scan(t, sim.ranges[k], geom), predict)
        dead = integrate_ackermann(dead, u, t, t_prev, CAR)
        dr.append(dead[0].copy())
        t_prev = t
    return world, sim, flt, np.array(dr)


def test_points_gather_on_obstacles(run):
    world, _, flt, _ = run
    m = flt.maps[flt.best_particle()]
    d = distance_to_obstacles(world, m.xy)
    mass_near = m.p[d < 1.0].sum() / m.p.sum()
    assert len(m) > 200
    # Measured (seed 3): median 0.24 m with the motion proposal (the map inherits the pose error), 0.022 m
    # with scan matching (0.11 m with bearing noise 0.25 deg for new points; docs/CHOICES.md).
    assert np.median(d) < (0.4 if flt.cfg.proposal == "motion" else 0.1)
    assert mass_near > 0.9, f"only {mass_near:.2f} of the probability mass within 1 m of an obstacle"
    # Free space (farther than 1.5 m from every obstacle) holds almost no points.
    assert np.mean(d > 1.5) < 0.02


def test_trajectory_beats_dead_reckoning(run):
    _, sim, flt, dr = run
    _, traj = flt.best_trajectory()
    truth = sim.truth[1:, 1:3]
    err = np.hypot(*(traj[:, :2] - truth).T).mean()
    err_dr = np.hypot(*(dr[1:, :2] - truth).T).mean()
    assert err < 0.5 * err_dr, (err, err_dr)
    if flt.cfg.proposal == "scan_match":
        # Measured with the defaults (N 8), seeds 3 / 4 / 5: 0.100 / 0.013 / 0.012 m against 1.0 m for dead
        # reckoning; 0.098 at seed 3 with float64 maps and without the coarse start (an earlier matcher
        # measured 0.017 at seed 3: this small symmetric world is sensitive to the seed).
        assert err < 0.15, err
    assert err < 0.5


@pytest.mark.parametrize("usable_range_m", [None, 4.0])
def test_returns_beyond_the_usable_range_are_not_mapped(usable_range_m):
    """A robot standing between a wall 2 m to its right and one 6 m to its left: with usable_range_m 4 only
    the near wall is mapped (GMapping's maxUrange); by default both are."""
    geom = ScanGeometry(181, -math.pi / 2, math.pi / 180, 30.0)
    bearings = geom.bearings_rad
    right, left = bearings < -0.2, bearings > 0.2
    ranges = np.full(181, np.inf)
    ranges[right] = 2.0 / np.abs(np.sin(bearings[right]))  # the wall y = -2
    ranges[left] = 6.0 / np.abs(np.sin(bearings[left]))  # the wall y = +6
    ranges[ranges > 25.0] = np.inf
    cfg = FilterConfig(particles=2, seed=1, update_schedule="every_scan", usable_range_m=usable_range_m)
    flt = GSlamFilter(cfg, np.zeros(3))
    for k in range(5):
        flt.step(Scan(0.1 * k, ranges, geom))
    xy, p = flt.map_points(flt.best_particle())
    strong = xy[p > 0.5]
    near, far = np.abs(strong[:, 1] + 2.0) < 0.3, np.abs(strong[:, 1] - 6.0) < 0.3
    assert near.sum() > 30
    if usable_range_m is None:
        assert far.sum() > 30
    else:
        assert far.sum() == 0 and np.hypot(*xy.T).max() < usable_range_m + 0.5
