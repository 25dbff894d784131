"""Steps 2 to 4 compiled and local to the scan (`gslam.mapupdate.windowed`), on constructed scans and a simulated
world."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gslam.config import FilterConfig
from gslam.filter import GSlamFilter
from gslam.mapupdate.windowed import UpdateWorkspace, WindowedUpdate, kernel_options, update_maps
from gslam.scan import Scan, ScanGeometry


def _update(xy, p, pose, scan, cfg, noise=None, workers=1):
    n_ret = int(scan.returns.sum())
    if noise is None:
        noise = np.zeros((1, n_ret, cfg.points_per_observation, 2))
    g = scan.geometry
    return update_maps(
        np.asarray(xy, dtype=float),
        np.asarray(p, dtype=float),
        np.array([0]),
        np.array([len(p)]),
        np.asarray(pose, dtype=float)[None],
        scan.occlusion_ranges_m,
        scan.returns,
        g.start_angle_rad,
        g.angle_increment_rad,
        g.max_range_m,
        noise,
        workspace=UpdateWorkspace(workers, cfg.max_points_per_cell),
        **kernel_options(cfg),
    )


def test_points_in_front_of_a_return_lose_probability_and_points_away_from_the_scan_are_untouched():
    # Three beams looking along +x, all returning at 5 m. A point at 2 m is in observed free space, one at
    # 5 m is hit, one far away (50, 50) is outside the scan's window and must come back unchanged.
    geom = ScanGeometry(3, -0.01, 0.01, 80.0)
    scan = Scan(0.0, np.array([5.0, 5.0, 5.0]), geom)
    cfg = FilterConfig(points_per_observation=1, max_points_per_cell=1, cell_size_m=0.1)
    xy = np.array([[2.0, 0.0], [5.0, 0.0], [50.0, 50.0]])
    p = np.array([0.6, 0.6, 0.42])
    out_xy, out_p, bounds = _update(xy, p, np.zeros(3), scan, cfg)
    a, b = bounds[0]
    got = {tuple(np.round(x, 6)): q for x, q in zip(out_xy[a:b], out_p[a:b], strict=True)}
    assert got[(50.0, 50.0)] == 0.42  # outside the window: copied as it was
    free = got.get((2.0, 0.0))
    assert free is not None and free < 0.6  # q = free_ratio < 1 in front of the return
    # The hit point's p rises (q = hit_ratio: 0.6 -> 0.818), and it stays as the most probable of its cell.
    assert got[(5.0, 0.0)] == pytest.approx(1 / (1 + (0.4 / 0.6) / cfg.hit_ratio))
    cells = np.floor(out_xy[a:b] / cfg.cell_size_m).astype(int)
    assert np.unique(cells, axis=0).shape[0] == b - a  # at most one point per cell


def test_a_beam_without_a_return_clears_free_space_only_as_far_as_no_return_free_m():
    """`no_return_free_m`: three beams along +x saw nothing within the sensor's 80 m; the middle one returns at
    30 m elsewhere in the scan's window. A point 10 m out on the empty beams is in free space all the way by
    default and loses p; with `no_return_free_m` 5 it lies beyond what those beams observe and keeps its p
    bit for bit, at 20 it loses it again. The numpy path (`wholemap.project`) observes the same points."""
    from dataclasses import replace

    from gslam.mapupdate.wholemap import project
    from gslam.pointmap import FlatMaps, PointMap

    geom = ScanGeometry(5, -0.02, 0.01, 80.0)
    scan = Scan(0.0, np.array([np.inf, np.inf, np.inf, np.inf, 30.0]), geom)
    xy = np.array([[10.0, 0.0]])
    p = np.array([0.6])
    flat = FlatMaps.of([PointMap(xy, p)])
    for free_m, cleared in ((None, True), (5.0, False), (20.0, True)):
        cfg = replace(FilterConfig(points_per_observation=1), no_return_free_m=free_m)
        out_xy, out_p, bounds = _update(xy, p, np.zeros(3), scan, cfg)
        a, b = bounds[0]
        kept = out_p[a:b][np.all(np.abs(out_xy[a:b] - xy[0]) < 1e-9, axis=1)]
        assert len(kept) == 1
        assert (kept[0] < 0.6) == cleared and (kept[0] == np.float32(0.6)) == (not cleared), (free_m, kept)
        observed = project(flat, np.zeros((1, 3)), scan, 0, free_m)[3]
        assert bool(observed[0]) == cleared


def test_new_points_are_drawn_around_returns_and_thinned_per_cell():
    geom = ScanGeometry(181, -math.pi / 2, math.pi / 180, 80.0)
    ranges = np.full(181, 4.0)
    scan = Scan(0.0, ranges, geom)
    cfg = FilterConfig(points_per_observation=10, max_points_per_cell=2, cell_size_m=0.25)
    rng = np.random.default_rng(0)
    noise = rng.standard_normal((1, 181, 10, 2))
    out_xy, out_p, bounds = _update(np.empty((0, 2)), np.empty(0), np.zeros(3), scan, cfg, noise)
    a, b = bounds[0]
    xy, p = out_xy[a:b], out_p[a:b]
    r = np.hypot(xy[:, 0], xy[:, 1])
    assert np.abs(r - 4.0).max() < 5 * cfg.range_sigma_m + 0.01  # on the circle of returns
    assert (p >= cfg.prune_threshold).all() and (p > cfg.prior_p0).all()  # new points at a return are hits
    cells = np.floor(xy / cfg.cell_size_m).astype(int)
    _, counts = np.unique(cells, axis=0, return_counts=True)
    assert counts.max() <= 2 and len(xy) > 100


def _simulated_run(threads: int, on_step=None) -> GSlamFilter:
    """G-SLAM (N 6, compiled update) over 8 s of the simulated car park; on_step(flt, k) after each scan."""
    from worlds import carpark_world, simulate_loop

    from gslam.motion import integrate_ackermann
    from gslam.vehicle import VEHICLE_PRESETS

    car = VEHICLE_PRESETS["carpark"]
    rng = np.random.default_rng(5)
    sim = simulate_loop(carpark_world(rng), car, rng, duration_s=8.0)
    geom = ScanGeometry(361, -math.pi / 2, math.pi / 360, 80.0)
    cfg = FilterConfig(particles=6, seed=1, min_travel_m=0.3)
    flt = GSlamFilter(cfg, sim.truth[0, 1:], threads=threads)
    t_prev = sim.scan_t[0]
    for k in range(1, len(sim.scan_t)):
        t = sim.scan_t[k]
        lo = np.searchsorted(sim.controls[:, 0], t_prev, side="right") - 1
        hi = np.searchsorted(sim.controls[:, 0], t, side="left")

        def predict(poses, g, u=sim.controls[lo:hi], t0=t_prev, t1=t, c=cfg):
            return integrate_ackermann(
                poses, u, t1, t0, car, g, c.speed_sigma_mps, c.speed_sigma_rel, c.steering_sigma_rad
            )

        flt.step(Scan(t, sim.ranges[k], geom), predict)
        t_prev = t
        if on_step is not None:
            on_step(flt, k)
    assert isinstance(flt.map_update, WindowedUpdate)
    return flt


def test_filter_results_do_not_depend_on_the_thread_count():
    """Workers take particles as they become free (gslam.workqueue): which worker takes which particle
    changes from run to run, the results do not; 3 workers on this machine's 2 threads included."""
    runs = []
    for threads in (1, 2, 3):
        flt = _simulated_run(threads)
        runs.append((flt.best_trajectory()[1], [m.p.copy() for m in flt.maps]))
    for other in runs[1:]:
        np.testing.assert_array_equal(runs[0][0], other[0])
        for a, b in zip(runs[0][1], other[1], strict=True):
            np.testing.assert_array_equal(a, b)


def test_a_buffer_is_written_again_only_when_nothing_else_holds_it():
    ws = UpdateWorkspace(1, 1)
    xy, p = ws.take(100)
    assert len(p) >= 100 and len(xy) == len(p)
    ws.release(xy, p)
    held = xy[3:10]  # a caller keeps a map that lives in the buffer
    del xy, p
    xy2, p2 = ws.take(100)
    assert xy2.base is None and held.base is not xy2  # a new buffer: the held map is left alone
    ws.release(xy2, p2)
    ident = id(xy2)
    del xy2, p2
    xy3, _ = ws.take(50)
    assert id(xy3) == ident  # nothing holds it: written again
    big, _ = ws.take(10_000)
    assert len(big) >= 10_000


def test_maps_a_caller_holds_do_not_change_under_later_updates():
    """The update writes new maps into the buffer of the update before the last when it is free: a map a
    caller kept (a view into that buffer) must make it not free, and stay as it was."""
    held = {}

    def keep(flt, k):
        if k in (5, 6, 7):
            xy, p = flt.map_points(0)
            held[k] = (xy, p, xy.copy(), p.copy())

    flt = _simulated_run(1, keep)
    assert flt.steps > 30 and len(held) == 3
    for xy, p, xy0, p0 in held.values():
        np.testing.assert_array_equal(xy, xy0)
        np.testing.assert_array_equal(p, p0)


@pytest.mark.parametrize(
    "hit_ratio, free_ratio", [(3.0, 0.9), (3.0, 0.5), (1e6, 0.1), (0.5, 0.9), (1.0, 1.0), (2.0, 0.0)]
)
def test_q_without_its_far_gaussian_is_the_same_bit_for_bit(hit_ratio, free_ratio):
    """Beyond far_z2 the bump is not computed; q must be exactly what computing it gives."""
    from gslam.mapupdate.windowed import _q, far_z2

    far = far_z2(hit_ratio, free_ratio)
    rng = np.random.default_rng(1)
    sigma = 0.2
    d = np.concatenate([rng.uniform(-100, 100, 20_000), rng.normal(0, 3 * sigma, 20_000)])
    edge = sigma * math.sqrt(max(far, 0.0))  # where the shortcut starts
    d = np.concatenate([d, np.outer([-edge, edge], [1 - 1e-9, 1.0, 1 + 1e-9]).ravel()])
    skipped = 0
    for x in d:
        a, b = _q(x, sigma, hit_ratio, free_ratio, far), _q(x, sigma, hit_ratio, free_ratio, math.inf)
        assert a == b and math.copysign(1, a) == math.copysign(1, b), (x, a, b)
        skipped += (x / sigma) ** 2 > far
    assert skipped > 10_000  # the shortcut was taken
    assert math.isnan(_q(math.nan, sigma, hit_ratio, free_ratio, far))


def test_bearing_wrap_is_pythons_modulo_bit_for_bit():
    from gslam.motion import wrap_angle_scalar

    rng = np.random.default_rng(2)
    two_pi = 2 * math.pi
    edges = np.array([-2 * two_pi, -two_pi, -math.pi, 0.0, math.pi, two_pi, 2 * two_pi]) - math.pi
    a = np.concatenate([rng.uniform(-4 * math.pi, 4 * math.pi, 50_000), rng.uniform(-50, 50, 5_000), edges])
    a = np.concatenate([a, np.nextafter(edges, np.inf), np.nextafter(edges, -np.inf), [-0.0, 0.0]])
    for x in a:
        want = (x + math.pi) % two_pi - math.pi
        got = wrap_angle_scalar(x)
        assert got == want and math.copysign(1, got) == math.copysign(1, want), (x, got, want)
