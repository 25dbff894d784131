"""The scan-matching proposal (open point 6) and the free-space guard of q, on constructed maps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gslam.config import FilterConfig
from gslam.mapupdate.wholemap import point_likelihood_ratio, project
from gslam.pointmap import FlatMaps, PointMap, distinct_maps
from gslam.scan import Scan, ScanGeometry, transform_points
from gslam.scanmatch import MatchWorkspace, match_and_weigh


def _room(rng: np.random.Generator) -> np.ndarray:
    """Points 2 cm apart on three walls and four poles, with 1 cm of scatter."""
    t = np.arange(0, 20, 0.02)
    walls = [
        np.column_stack([t - 5, np.full_like(t, 8.0)]),  # north wall
        np.column_stack([np.full_like(t, 12.0), t - 10]),  # east wall
        np.column_stack([t - 5, np.full_like(t, -6.0)]),  # south wall
    ]
    ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    poles = [
        np.column_stack([cx + 0.1 * np.cos(ang), cy + 0.1 * np.sin(ang)])
        for cx, cy in [(4, 3), (7, -2), (2, -4), (9, 5)]
    ]
    pts = np.vstack(walls + poles)
    return pts + rng.standard_normal(pts.shape) * 0.01


def _scan_points(world: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """The map points in front of the sensor at `pose`, in the sensor frame (a dense stand-in for a scan)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    d = world - pose[:2]
    local = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
    return local[local[:, 0] > 0.5][::7]


def _match(maps, poses, pts, cfg=None, **over):
    cfg = cfg or FilterConfig()
    xy, p, lo, hi = distinct_maps(maps)
    kw = dict(
        cell_m=cfg.match_cell_m,
        kernel=cfg.match_kernel,
        min_p=cfg.match_min_p,
        margin_m=cfg.match_window_margin_m,
        step_xy_m=cfg.match_step_xy_m,
        step_phi_rad=cfg.match_step_phi_rad,
        levels=cfg.match_levels,
        max_iterations=cfg.match_max_iterations,
        score_sigma_m=cfg.match_sigma_m,
        score_sigma_rad=0.0,
        like_sigma_m=cfg.weight_sigma_m,
        miss_m=cfg.weight_miss_m,
        line_pair_m=cfg.match_line_pair_m,
        workspace=MatchWorkspace(over.pop("workers", 1)),
    )
    kw.update(over)
    return match_and_weigh(xy, p, lo, hi, np.asarray(poses, dtype=float), pts, **kw)


def _room_scan() -> tuple[PointMap, np.ndarray, np.ndarray]:
    """The room as a map, a pose in it and the scan seen from there (sensor frame)."""
    world = _room(np.random.default_rng(5))
    truth = np.array([1.0, 0.5, 0.2])
    return PointMap(world, np.full(len(world), 0.9)), truth, _scan_points(world, truth)


def test_match_recovers_a_known_pose_offset_for_every_particle():
    rng = np.random.default_rng(0)
    world = _room(rng)
    m = PointMap(world, np.full(len(world), 0.9))
    truth = np.array([1.0, 0.5, 0.2])
    pts = _scan_points(world, truth)
    assert len(pts) > 100
    start = truth + np.array([[0.08, -0.06, math.radians(1.5)], [-0.07, 0.05, math.radians(-1.0)], [0.0, 0.0, 0.0]])
    maps = [m, m, PointMap.empty()]  # particles 0 and 1 share one map; particle 2 has none
    out, score, log_like, hits = _match(maps, start, pts)
    for i in (0, 1):
        assert np.hypot(*(out[i, :2] - truth[:2])) < 0.02, out[i]  # the room has 1 cm of scatter
        assert abs(out[i, 2] - truth[2]) < math.radians(0.2)
        assert hits[i] > 0.9 * len(pts) and score[i] > 0.8 * len(pts)
    np.testing.assert_array_equal(out[2], start[2])  # no map: the motion sample stands
    assert hits[2] == 0 and score[2] == 0
    # Every return misses on an empty map: the log-likelihood is the miss value for each of them.
    cfg = FilterConfig()
    assert log_like[2] == pytest.approx(-len(pts) * cfg.weight_miss_m**2 / (2 * cfg.weight_sigma_m**2))
    assert log_like[0] > 0.1 * log_like[2]


def test_coarse_to_fine_start_recovers_an_offset_beyond_the_fine_basin():
    # A motion sample 0.7 m and 4 deg off (a wheel slip, a sign error when backing up): the fine raster's
    # returns find the map within a cell or two only, so its climb stops short; the coarse-to-fine start
    # (cells, reach and steps 4 times larger, then the fine raster) reaches the pose, and with its clearly
    # higher fine score it is the match. A start already at the pose is left where the fine climb puts it.
    m, truth, pts = _room_scan()
    start = truth + np.array([[0.56, -0.42, math.radians(4.0)], [-0.42, 0.56, math.radians(-4.0)], [0.01, 0.0, 0.0]])
    fine, fine_score, _, _ = _match([m] * 3, start, pts)
    both, both_score, _, _ = _match([m] * 3, start, pts, coarse_factor=4)
    for i in (0, 1):
        assert np.hypot(*(fine[i, :2] - truth[:2])) > 0.1, fine[i]  # stuck outside the fine basin
        assert np.hypot(*(both[i, :2] - truth[:2])) < 0.02, both[i]
        assert abs(both[i, 2] - truth[2]) < math.radians(0.2)
        assert both_score[i] > fine_score[i]
    assert both_score[2] >= fine_score[2] and np.hypot(*(both[2, :2] - truth[:2])) < 0.02


def test_a_deeper_pyramid_widens_the_basin_to_a_metre():
    # Motion samples up to 1.2 m and 7 deg off (a slip that doubles a metre-long step): the fine climb alone
    # recovers almost none; one coarse level (0.2 m cells) recovers most; a second level above it (0.8 m
    # cells, its result descending through the first) recovers nearly all.
    m, truth, pts = _room_scan()
    offsets = np.random.default_rng(1).uniform(-1.2, 1.2, (40, 3)) * [1, 1, 0.1]
    recovered = {}
    for name, over in {
        "fine": {},
        "one level": dict(coarse_factor=4, coarse_levels=3, coarse_depth=1),
        "two levels": dict(coarse_factor=4, coarse_levels=3, coarse_depth=2),
    }.items():
        r, _, _, _ = _match([m] * len(offsets), truth + offsets, pts, coarse_min_gain=0.05, **over)
        recovered[name] = int((np.hypot(*(r[:, :2] - truth[:2]).T) < 0.05).sum())
    assert recovered["fine"] <= 4, recovered
    assert recovered["one level"] >= 30, recovered
    assert recovered["two levels"] >= 36 and recovered["two levels"] > recovered["one level"], recovered


def test_coarse_start_is_tried_only_where_the_fine_match_fits_worse_than_the_reference():
    # The gate (match_coarse_gate 0.9): a particle whose fine match fits as well as the best one has nothing
    # to recover and is not tried; the two stuck ones fit far worse than the particle at the truth and are
    # recovered as without the gate.
    m, truth, pts = _room_scan()
    start = truth + np.array([[0.56, -0.42, math.radians(4.0)], [-0.42, 0.56, math.radians(-4.0)], [0.01, 0.0, 0.0]])
    every = _match([m] * 3, start, pts, coarse_factor=4, coarse_min_gain=0.05)
    gated = _match([m] * 3, start, pts, coarse_factor=4, coarse_min_gain=0.05, coarse_gate=0.9)
    for a, b in zip(every, gated, strict=True):
        np.testing.assert_array_equal(a, b)
    # Every particle stuck alike (a slip that takes them all out of the fine basin): measured against one
    # another they fit alike and none is tried; against the previous update's median fit (the reference the
    # filter passes) all are, and all are recovered.
    alike = truth + np.array([[0.56, -0.42, math.radians(4.0)]] * 2)
    fine, fine_score, _, _ = _match([m] * 2, alike, pts)
    alone, _, _, _ = _match([m] * 2, alike, pts, coarse_factor=4, coarse_min_gain=0.05, coarse_gate=0.9)
    np.testing.assert_array_equal(alone, fine)
    assert (fine_score / len(pts) < 0.8).all()
    caught, _, _, _ = _match(
        [m] * 2, alike, pts, coarse_factor=4, coarse_min_gain=0.05, coarse_gate=0.9, coarse_reference=0.95
    )
    assert (np.hypot(*(caught[:, :2] - truth[:2]).T) < 0.02).all(), caught


def test_match_result_does_not_depend_on_the_number_of_workers():
    rng = np.random.default_rng(3)
    world = _room(rng)
    maps = [PointMap(world + rng.standard_normal(world.shape) * 0.01, np.full(len(world), 0.9)) for _ in range(5)]
    truth = np.array([0.5, -0.5, 0.1])
    pts = _scan_points(world, truth)
    start = truth + rng.standard_normal((5, 3)) * [0.05, 0.05, 0.02]
    one = _match(maps, start, pts, workers=1)
    two = _match(maps, start, pts, workers=2)
    for a, b in zip(one, two, strict=True):
        np.testing.assert_array_equal(a, b)


def test_match_score_peaks_at_the_truth_and_likelihood_falls_off_it():
    rng = np.random.default_rng(1)
    world = _room(rng)
    m = PointMap(world, np.full(len(world), 0.9))
    truth = np.array([0.0, 0.0, 0.0])
    pts = _scan_points(world, truth)
    offsets = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, math.radians(1)]], dtype=float)
    _, s, like, _ = _match([m] * 4, truth + offsets, pts, max_iterations=0)  # no climbing: the pose's score
    assert s.argmax() == 0 and s[0] > 0.9 * len(pts)
    assert like.argmax() == 0
    # Points below match_min_p are not part of the map the matcher sees.
    faint = PointMap(world, np.full(len(world), 0.4))
    _, s, _, hits = _match([faint], truth[None], pts, max_iterations=0)
    assert s[0] == 0 and hits[0] == 0


def test_a_surface_smeared_along_the_beams_is_matched_at_its_middle():
    """A wall whose points spread 3 cm either side of the surface (pose error and range noise at the
    times they were drawn) is matched at its middle, from starts 3 cm either side. GMapping's rule of
    skipping a cell whose neighbour towards the sensor is occupied matches only the front of the spread:
    with it the pose ended 0.005 to 0.029 m back from the wall; without it within 0.005 m."""
    x = np.arange(-3.0, 3.0, 0.02) + 0.007
    depth = np.arange(-0.03, 0.0301, 0.01)
    wall = np.column_stack([np.tile(x, len(depth)), np.repeat(2.0 + depth, len(x))])  # the surface at y = 2
    m = PointMap(wall, np.full(len(wall), 0.9))
    pts = np.column_stack([np.full(41, 2.0), np.linspace(-2, 2, 41)])  # sensor frame: x ahead, wall at 2 m
    up = np.pi / 2  # heading +y: the returns land on the wall from below
    errors = []
    for start_y in (-0.03, 0.0, 0.03):
        poses, _, _, _ = _match([m], [[0.0, start_y, up]], pts)
        errors.append(poses[0, 1])
    assert np.max(np.abs(errors)) < 0.01, errors


def test_free_space_guard_spares_points_beside_a_nearer_return():
    # Beam 1 sees a wall at 10 m; its neighbour beam 0 sees an edge at 6 m. A point at 8 m on beam 1 lies in
    # front of its own return but behind the neighbour's: with the guard it is left as occluded.
    geom = ScanGeometry(3, -0.01, 0.01, 80.0)
    scan = Scan(0.0, np.array([6.0, 10.0, 10.0]), geom)
    cfg = FilterConfig(free_ratio=0.5)
    flat = FlatMaps(np.array([[8.0, 0.0], [3.0, 0.0]]), np.array([0.5, 0.5]), np.zeros(2, dtype=np.int64))
    poses = np.zeros((1, 3))
    r, j, z, observed, free = project(flat, poses, scan, free_space_beams=0)
    assert j.tolist() == [1, 1] and free.tolist() == [10.0, 10.0]
    q = point_likelihood_ratio(r, z, observed, cfg, free)
    assert q[0] < 1 and q[1] < 1  # both in free space without the guard
    r, j, z, observed, free = project(flat, poses, scan, free_space_beams=1)
    assert free.tolist() == [6.0, 6.0]
    q = point_likelihood_ratio(r, z, observed, cfg, free)
    assert q[0] == 1.0  # behind the neighbour's return: unchanged
    assert q[1] < 1  # in front of every return nearby: free
    # The scan end points transform back onto the world frame the matcher uses.
    np.testing.assert_allclose(
        transform_points(np.array([1.0, 2.0, math.pi / 2]), np.array([[1.0, 0.0]])), [[1.0, 3.0]]
    )


def test_matcher_options_are_validated():
    with pytest.raises(ValueError, match="match_levels"):
        FilterConfig(match_levels=0)
    with pytest.raises(ValueError, match="match_sigma_m"):
        FilterConfig(match_sigma_m=0.0)
    with pytest.raises(ValueError, match="match_polish_iterations"):
        FilterConfig(match_polish_iterations=-1)
    with pytest.raises(ValueError, match="match_climb_stride"):
        FilterConfig(match_climb_stride=0)


def _room_and_two_starts(seed: int):
    """The room (its scatter drawn from `seed`) as a map, the true pose, the scan from there and two motion
    samples a few centimetres and a degree or so off it."""
    world = _room(np.random.default_rng(seed))
    truth = np.array([1.0, 0.5, 0.2])
    start = truth + np.array([[0.08, -0.06, math.radians(1.5)], [-0.07, 0.05, math.radians(-1.0)]])
    return PointMap(world, np.full(len(world), 0.9)), truth, _scan_points(world, truth), start


def test_gauss_newton_polish_refines_the_climb_to_the_truth():
    # Two step halvings leave the climb on a lattice of 1.25 cm and 0.7 deg; the Gauss-Newton steps on the
    # same score (match_polish_iterations) take it from there to the optimum: a higher score, and on this
    # room (1 cm of scatter on its points) within 1 cm and 0.05 deg of the truth (the full climb of five
    # halvings: 1.4 and 1.6 cm, 0.07 and 0.1 deg).
    m, truth, pts, start = _room_and_two_starts(0)
    coarse, coarse_score, _, _ = _match([m, m], start, pts, levels=2)
    out, score, _, hits = _match([m, m], start, pts, levels=2, polish_iterations=5)
    full, full_score, _, _ = _match([m, m], start, pts)
    for i in range(2):
        assert score[i] > coarse_score[i]
        assert score[i] >= 0.999 * full_score[i]
        assert np.hypot(*(out[i, :2] - truth[:2])) < 0.01, out[i]
        assert abs(out[i, 2] - truth[2]) < math.radians(0.05)
        assert np.hypot(*(out[i, :2] - truth[:2])) < np.hypot(*(coarse[i, :2] - truth[:2]))


def test_climb_on_every_second_return_then_the_finish_on_all():
    # match_climb_stride 2: the climb walks on every second return, exactly as a climb given only those;
    # the score it reports, and the Gauss-Newton finish after it, are over all the returns.
    m, truth, pts, start = _room_and_two_starts(2)
    half, _, _, _ = _match([m, m], start, pts[::2])
    out, score, _, _ = _match([m, m], start, pts, climb_stride=2)
    np.testing.assert_array_equal(out, half)
    # With no climbing step the pose stays and the score is the same as scoring every return there.
    _, still, _, _ = _match([m, m], start, pts, climb_stride=2, max_iterations=0)
    _, all_returns, _, _ = _match([m, m], start, pts, max_iterations=0)
    np.testing.assert_array_equal(still, all_returns)
    assert np.all(score > all_returns)
    finished, finished_score, _, _ = _match([m, m], start, pts, climb_stride=2, polish_iterations=5)
    for i in range(2):
        assert finished_score[i] >= score[i]
        assert np.hypot(*(finished[i, :2] - truth[:2])) < 0.01, finished[i]
        assert abs(finished[i, 2] - truth[2]) < math.radians(0.05)


def test_the_climbs_finest_steps_on_thinner_returns_then_the_finish_on_all():
    # match_fine_stride 2: the climb's last three step sizes on every second of the climb's returns; the
    # finish on all of them still lands within 1 cm and 0.05 deg of the truth. Stride 1, or no fine
    # levels, is the climb as before.
    m, truth, pts, start = _room_and_two_starts(3)
    plain, plain_score, _, _ = _match([m, m], start, pts, climb_stride=2, polish_iterations=5)
    for off in ({"fine_stride": 1, "fine_levels": 3}, {"fine_stride": 2, "fine_levels": 0}):
        same, same_score, _, _ = _match([m, m], start, pts, climb_stride=2, polish_iterations=5, **off)
        np.testing.assert_array_equal(same, plain)
        np.testing.assert_array_equal(same_score, plain_score)
    thin, _, _, _ = _match([m, m], start, pts, climb_stride=2, fine_stride=2, fine_levels=3)
    climbed, _, _, _ = _match([m, m], start, pts, climb_stride=2)
    assert not np.array_equal(thin, climbed)  # the finest steps did walk on other returns
    out, score, _, _ = _match([m, m], start, pts, climb_stride=2, fine_stride=2, fine_levels=3, polish_iterations=5)
    for i in range(2):
        assert score[i] >= 0.999 * plain_score[i]
        assert np.hypot(*(out[i, :2] - truth[:2])) < 0.01, out[i]
        assert abs(out[i, 2] - truth[2]) < math.radians(0.05)


def test_gauss_newton_polish_leaves_a_pose_without_map_alone():
    # No returns near any map point: nothing constrains the pose, the normal equations are singular and the
    # motion sample stands.
    world = _room(np.random.default_rng(1))
    m = PointMap(world, np.full(len(world), 0.9))
    far = np.array([[100.0, 100.0, 0.0]])
    out, score, _, hits = _match([m], far, _scan_points(world, np.array([1.0, 0.5, 0.2])), polish_iterations=5)
    np.testing.assert_array_equal(out[0], far[0])
    assert hits[0] == 0 and score[0] == 0
