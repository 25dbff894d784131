"""The scan-matching proposal (open point 6) and the free-space guard of q, on constructed maps."""

from __future__ import annotations

import math

import numpy as np

from gslam.config import FilterConfig
from gslam.pointmap import FlatMaps, PointMap, point_likelihood_ratio, project, smooth_by_cells
from gslam.proposal import StackedMaps, match_scans
from gslam.scan import Scan, ScanGeometry, transform_points


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


def test_match_recovers_a_known_pose_offset_for_every_particle():
    rng = np.random.default_rng(0)
    world = _room(rng)
    m = PointMap(world[np.argsort(world[:, 0])], np.full(len(world), 0.9))
    truth = np.array([1.0, 0.5, 0.2])
    pts = _scan_points(world, truth)
    assert len(pts) > 100
    start = truth + np.array([[0.15, -0.10, math.radians(1.5)], [-0.12, 0.08, math.radians(-1.0)], [0.0, 0.0, 0.0]])
    maps = [m, m, PointMap.empty()]  # particles 0 and 1 share one map; particle 2 has none
    out, matched, score = match_scans(maps, start, pts, FilterConfig(match_levels=6))
    assert matched.tolist() == [True, True, False]
    for i in (0, 1):
        assert np.hypot(*(out[i, :2] - truth[:2])) < 0.02, out[i]
        assert abs(out[i, 2] - truth[2]) < math.radians(0.2)
        # Smoothing leaves one point per 0.25 m cell and shrinks the 0.1 m poles to their centres.
        assert score[i] > 0.6 * len(pts)
    np.testing.assert_array_equal(out[2], start[2])  # no map: the motion sample stands


def test_smoothing_puts_scattered_points_on_the_surface_centre_line():
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 10, 2000)
    y = 3.0 + rng.standard_normal(2000) * 0.05  # a wall at y = 3 with 5 cm of scatter
    owner = np.zeros(2000, dtype=np.int64)
    out = smooth_by_cells(owner, np.column_stack([x, y]), 0.25)
    assert np.abs(out[:, 1] - 3.0).max() < 0.05 and np.abs(y - 3.0).max() > 0.1
    assert np.abs(out[:, 0] - x).max() < 0.3  # along the wall, points stay in their neighbourhood
    # Another particle's points never mix in.
    two = smooth_by_cells(
        np.r_[owner, owner + 1], np.vstack([np.column_stack([x, y]), np.column_stack([x, y + 0.2])]), 0.25
    )
    np.testing.assert_allclose(two[:2000], out)


def test_stacked_maps_share_a_slot_per_distinct_map():
    a = PointMap(np.zeros((30, 2)), np.ones(30))
    b = PointMap(np.ones((25, 2)), np.ones(25))
    stacked = StackedMaps.of([a, b, a, b, b])
    assert stacked.slot.tolist() == [0, 1, 0, 1, 1]
    assert stacked.sizes.tolist() == [30, 25, 30, 25, 25]
    assert stacked.tree.n == 55
    # Windows: particle 0 and 2 (map a, at the origin) look far away; the union of 1, 3, 4 holds map b.
    far, near = [50.0, 50.0, 60.0, 60.0], [0.5, 0.5, 1.5, 1.5]
    windowed = StackedMaps.of([a, b, a, b, b], windows=np.array([far, near, far, far, far]))
    assert windowed.sizes.tolist() == [0, 25, 0, 25, 25]
    assert windowed.tree.n == 25


def test_match_score_peaks_at_the_truth():
    rng = np.random.default_rng(1)
    world = _room(rng)
    m = PointMap(world, np.full(len(world), 0.9))
    truth = np.array([0.0, 0.0, 0.0])
    pts = _scan_points(world, truth)
    stacked = StackedMaps.of([m])
    offsets = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, math.radians(1)]], dtype=float)
    s = stacked.scores(np.zeros(4, dtype=np.int64), truth + offsets, pts, 0.1)
    assert s.argmax() == 0 and s[0] > 0.9 * len(pts)


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
    import pytest

    with pytest.raises(ValueError, match="match_levels"):
        FilterConfig(match_levels=0)
    with pytest.raises(ValueError, match="match_sigma_m"):
        FilterConfig(match_sigma_m=0.0)
