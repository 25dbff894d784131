"""The adaptive heading noise (`motion_noise_adaptive`): the filter narrows the motion model's heading noise
when the scan matches show the odometry's heading is better than the model says, and keeps it when not.

A simulated robot drives a loop of corridors (tests/worlds.py). Its odometry has a 2 % scale error and a
yaw drift of 0.01 rad/m, plus per-scan heading noise: 0.003 rad per scan interval (good wheels: about
0.005 rad per 0.5 m update, against the model's 0.1 rad) or 0.08 rad (poor: above the model's).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from worlds import corridor_world, drive_filter, simulate_robot_loop

from gslam.config import FilterConfig
from gslam.filter import GSlamFilter
from gslam.scan import ScanGeometry


def _drive(heading_sigma_rad: float, **options) -> tuple[GSlamFilter, list[float], np.ndarray, np.ndarray]:
    sim = simulate_robot_loop(corridor_world(), np.random.default_rng(3), odom_sigma_rad=heading_sigma_rad)
    geom = ScanGeometry(len(sim.ranges[0]), sim.start_angle_rad, sim.angle_increment_rad, sim.max_range_m)
    cfg = FilterConfig(particles=16, seed=0, **options)
    flt = GSlamFilter(cfg, sim.odometry[0])
    scales = [flt.heading_noise_scale for r in drive_filter(flt, sim.t_s, sim.odometry, sim.ranges, geom) if r.updated]
    _, traj = flt.best_trajectory()
    return flt, scales, traj, sim.truth


@pytest.fixture(scope="module")
def good():
    return _drive(0.003)


def test_good_odometry_narrows_the_heading_noise(good):
    """The matches find heading errors a few hundredths of the model's sd. The running mean starts at the
    model (1) and needs evidence: the first ~45 updates keep the model, then the noise narrows
    (measured: 0.56 at the 82nd and last update, on its way to the floor 0.2). The path stays on the
    truth (mean error measured 0.013 m)."""
    flt, scales, traj, truth = good
    assert scales[:30] == [1.0] * 30  # the model holds until the matches show otherwise
    assert scales[-1] < 0.7, scales[-1]
    assert scales[-1] < scales[-30] - 0.2, scales[-30:]  # still falling
    assert flt.heading_noise_scale >= flt.cfg.motion_noise_min_scale
    err = np.hypot(*(traj[:, :2] - truth[:, :2]).T)
    assert err.mean() < 0.1, err.mean()


def test_poor_odometry_keeps_the_model():
    """Heading noise of 0.08 rad per scan (about 0.14 rad per 0.5 m update, above the model's 0.1): the
    matches see errors of the model's size, and the noise is never narrowed."""
    _, scales, _, _ = _drive(0.08)
    assert min(scales) > 0.9, min(scales)


def test_adaptation_off_leaves_the_model_alone():
    flt, scales, _, _ = _drive(0.003, motion_noise_adaptive=False)
    assert set(scales) == {1.0}


def test_options_are_validated():
    with pytest.raises(ValueError, match="motion_noise_min_scale"):
        FilterConfig(motion_noise_min_scale=1.5)
    with pytest.raises(ValueError, match="motion_noise_window"):
        FilterConfig(motion_noise_window=0)
    assert math.isclose(FilterConfig().motion_noise_safety, 3.0)


def _feed(flt: GSlamFilter, ratios: list[float], model_sd: float = 0.1) -> list[float]:
    """Feed the estimator updates whose matched heading error is `ratio` x the model's drawn noise (sd
    `model_sd` over the particles); returns the scale after each."""
    n = flt.cfg.particles
    drawn = np.where(np.arange(n) % 2 == 0, model_sd, -model_sd)  # sd model_sd exactly
    scales = []
    for ratio in ratios:
        flt._filled = np.zeros((n, 3))
        flt.poses = np.zeros((n, 3))
        flt.poses[:, 2] = ratio * model_sd
        flt._heading_noise = drawn.copy()
        flt._adapt_heading_noise()
        scales.append(flt.heading_noise_scale)
    return scales


def test_one_slip_does_not_reopen_a_narrowed_model():
    """Good odometry (errors 0.02 x the model) has narrowed the noise to its floor; then one update's match
    finds a slip of 1.5 x the model's sd (the matcher corrected it). The robust update (clip 3) moves the
    scale by a bounded step (to 0.25 at most) where the plain running mean of squares reopens the model
    (to 1, then some 60 updates to narrow again). Errors that stay at the model's size still bring it
    back to 1 within a dozen updates."""
    good = [0.02] * 150
    robust = GSlamFilter(FilterConfig(particles=8), np.zeros(3))
    plain = GSlamFilter(FilterConfig(particles=8, motion_noise_clip=0.0), np.zeros(3))
    assert _feed(robust, good)[-1] == pytest.approx(0.2)
    assert _feed(plain, good)[-1] == pytest.approx(0.2)
    assert _feed(robust, [1.5])[-1] <= 0.25
    assert _feed(plain, [1.5])[-1] == pytest.approx(1.0)
    back = _feed(robust, [1.0] * 15)
    assert back[-1] == pytest.approx(1.0), back
    assert back.index(1.0) <= 12, back
