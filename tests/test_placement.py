"""Every scan placed by the final map (`gslam.placement`): a simulated room with known truth."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest

from gslam.placement import (
    BETWEEN,
    NO_RETURNS,
    PLACED,
    between_matched,
    dead_reckoned,
    place_scans,
    raster_shifts,
)
from gslam.scanmatch import MatchSettings
from gslam.se2 import compose, inverse

WALLS = [  # a 10 x 8 m room with a 2 x 1 m box in it: (x0, y0, x1, y1)
    (0.0, 0.0, 10.0, 0.0),
    (10.0, 0.0, 10.0, 8.0),
    (10.0, 8.0, 0.0, 8.0),
    (0.0, 8.0, 0.0, 0.0),
    (6.0, 5.0, 8.0, 5.0),
    (8.0, 5.0, 8.0, 6.0),
    (8.0, 6.0, 6.0, 6.0),
    (6.0, 6.0, 6.0, 5.0),
]
BEARINGS = np.radians(np.arange(-90.0, 90.5, 1.0))


def room_map(spacing_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    pts = []
    for x0, y0, x1, y1 in WALLS:
        n = int(math.hypot(x1 - x0, y1 - y0) / spacing_m) + 1
        t = np.linspace(0.0, 1.0, n)
        pts.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    xy = np.vstack(pts)
    return xy, np.ones(len(xy))


def scan_from(pose: np.ndarray, bearings: np.ndarray = BEARINGS) -> np.ndarray:
    """The end points (K, 2) in the sensor frame of the beams from `pose` to the nearest wall."""
    ends = []
    for b in bearings:
        ux, uy = math.cos(pose[2] + b), math.sin(pose[2] + b)
        best = math.inf
        for x0, y0, x1, y1 in WALLS:
            ex, ey = x1 - x0, y1 - y0
            den = ux * ey - uy * ex
            if abs(den) < 1e-12:
                continue
            wx, wy = x0 - pose[0], y0 - pose[1]
            r = (wx * ey - wy * ex) / den
            s = (wx * uy - wy * ux) / den
            if r > 0 and 0.0 <= s <= 1.0:
                best = min(best, r)
        if best < 20.0:
            ends.append((best * math.cos(b), best * math.sin(b)))
    return np.asarray(ends, dtype=float).reshape(-1, 2)


SETTINGS = MatchSettings(
    cell_m=0.05,
    kernel=1,
    min_p=0.5,
    margin_m=1.0,
    step_xy_m=0.01,
    step_phi_rad=0.01,
    levels=2,
    max_iterations=100,
    score_sigma_m=0.05,
    score_sigma_rad=0.0,
    like_sigma_m=0.2,
    miss_m=0.2,
    line_pair_m=0.2,
    polish_iterations=5,
    climb_stride=2,
    fine_stride=1,
    fine_levels=0,
)


def of(ends: list) -> Callable[[int, int], list]:
    """The scan source `place_scans` reads: scans a to b - 1."""
    return lambda a, b: ends[a:b]


def truth_path(n: int = 60) -> np.ndarray:
    """A curve through the room, 5 cm and about 1 degree a scan."""
    t = np.arange(n)
    return np.column_stack([2.0 + 0.05 * t, 2.0 + 1.2 * np.sin(t / 25.0), 0.3 * np.sin(t / 18.0)])


def errors(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    d = compose(inverse(b), a)
    return float(np.hypot(d[:, 0], d[:, 1]).max()), float(np.degrees(np.abs(d[:, 2])).max())


def test_each_scan_is_matched_to_its_true_pose():
    xy, p = room_map()
    truth = truth_path()
    rng = np.random.default_rng(0)
    recorded = truth + rng.normal(0.0, [0.02, 0.02, math.radians(1.0)], truth.shape)
    assert errors(recorded, truth)[0] > 0.03  # the test means something: the start is off
    ends = [(scan_from(q), math.radians(1.0)) for q in truth]
    placed = place_scans(xy, p, recorded, of(ends), SETTINGS)
    assert placed.counts() == {
        "scans": 60,
        "matched": 60,
        "between_matched": 0,
        "no_returns": 0,
        "retracked_segments": 0,
    }
    trans, rot = errors(placed.poses, truth)
    assert trans < 0.005 and rot < 0.1


def scattered_room_map(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The room as a generative map holds it: points every 4 cm on average, at random along the walls and
    1.5 cm across them."""
    pts = []
    for x0, y0, x1, y1 in WALLS:
        length = math.hypot(x1 - x0, y1 - y0)
        t = rng.uniform(0.0, 1.0, int(length / 0.04) + 1)
        across = rng.normal(0.0, 0.015, len(t))
        nx, ny = -(y1 - y0) / length, (x1 - x0) / length
        pts.append(np.column_stack([x0 + t * (x1 - x0) + across * nx, y0 + t * (y1 - y0) + across * ny]))
    xy = np.vstack(pts)
    return xy, np.ones(len(xy))


def test_the_rasters_lattices_are_spread_over_the_cell():
    for rasters in (1, 2, 3, 4, 8):
        shifts = raster_shifts(rasters, 0.05)
        assert shifts.shape == (rasters, 2)
        assert ((shifts >= 0.0) & (shifts < 0.05)).all()
        # no two share a column or a row of cell edges
        assert len(np.unique(shifts[:, 0])) == rasters and len(np.unique(shifts[:, 1])) == rasters
    np.testing.assert_allclose(raster_shifts(2, 0.05), [[0.0125, 0.0125], [0.0375, 0.0375]])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_two_rasters_move_a_match_less_with_where_the_cell_edges_fall(seed):
    """A raster summarises the map's points by their cell's mean, so a match moves with where the cell
    edges fall. Moving the whole room (map, scans' true and recorded poses) by a fraction of a cell changes
    nothing but that: the placed poses, moved back, spread over eight such moves by 3.9 to 4.7 mm (mean
    over the scans) on one raster and by 2.7 to 3.5 mm as the mean of two."""
    rng = np.random.default_rng(seed)
    xy, p = scattered_room_map(rng)
    truth = truth_path(60)
    recorded = truth + rng.normal(0.0, [0.01, 0.01, math.radians(0.5)], truth.shape)
    ends = [(scan_from(q), math.radians(1.0)) for q in truth]
    settings = replace(SETTINGS, climb_stride=1)
    spread = {}
    for rasters in (1, 2):
        placed = []
        for fraction in np.arange(8) / 8:
            move = np.array([0.05 * fraction, 0.03 * fraction, 0.0])
            at = place_scans(xy + move[:2], p, recorded + move, of(ends), settings, rasters=rasters)
            assert at.counts()["matched"] == len(truth)
            placed.append(at.poses - move)
        placed = np.asarray(placed)
        spread[rasters] = float(np.hypot(placed[..., 0].std(axis=0), placed[..., 1].std(axis=0)).mean())
    assert spread[2] < 0.85 * spread[1], spread
    assert spread[2] < 0.004, spread


def test_a_drifting_odometry_is_followed_from_the_scan_before():
    """The filter's poses between updates are the odometry's: here the heading drifts 0.01 rad a scan.
    From the recorded pose the later scans are too far off to be matched (they are placed between
    neighbours, the only matched one being the first); from the scan before as placed, every one is."""
    xy, p = room_map()
    truth = truth_path()
    steps = compose(inverse(truth[:-1]), truth[1:])
    steps[:, 2] += 0.01
    recorded = [truth[0]]
    for s in steps:
        recorded.append(compose(recorded[-1], s))
    recorded = np.asarray(recorded)
    ends = [(scan_from(q), 0.0) for q in truth]
    anchored = np.zeros(len(truth), dtype=bool)
    anchored[0] = True
    chained = place_scans(xy, p, recorded, of(ends), SETTINGS, anchored=anchored)
    assert chained.counts()["matched"] == len(truth)
    assert errors(chained.poses, truth)[0] < 0.005
    alone = place_scans(xy, p, recorded, of(ends), SETTINGS)
    assert alone.counts()["between_matched"] > 20  # beyond max_turn_rad: not kept


def test_scans_without_returns_are_counted_and_placed_between_neighbours():
    xy, p = room_map()
    truth = truth_path(20)
    recorded = truth + [0.01, -0.01, 0.005]
    ends = [(scan_from(q), 0.0) for q in truth]
    ends[7] = (ends[7][0][:3], 0.0)
    placed = place_scans(xy, p, recorded, of(ends), SETTINGS)
    assert placed.how[7] == NO_RETURNS and placed.counts()["no_returns"] == 1
    assert (placed.how[np.arange(20) != 7] == PLACED).all()
    assert errors(placed.poses[6:9], truth[6:9])[0] < 0.01


def test_between_matched_carries_a_common_correction_exactly():
    truth = truth_path(30)
    offset = np.array([0.3, -0.2, 0.05])
    recorded = compose(inverse(offset), truth)  # recorded = C^-1 (+) truth: the same rigid error everywhere
    matched = np.zeros(30, dtype=bool)
    matched[[3, 12, 25]] = True
    placed = recorded.copy()
    placed[matched] = truth[matched]
    out = between_matched(recorded, placed, matched)
    trans, rot = errors(out, truth)
    assert trans < 1e-9 and rot < 1e-7


def test_between_matched_blends_along_the_path():
    """Half way along the recorded path between two matched scans, half of each end's correction."""
    recorded = np.column_stack([np.linspace(0.0, 1.0, 11), np.zeros(11), np.zeros(11)])
    placed = recorded.copy()
    placed[10, 1] = 0.1  # the far end is found 10 cm to the left
    matched = np.zeros(11, dtype=bool)
    matched[[0, 10]] = True
    out = between_matched(recorded, placed, matched)
    assert out[5, 1] == pytest.approx(0.05)
    assert out[0, 1] == 0.0 and out[10, 1] == pytest.approx(0.1)


def test_nothing_matched_leaves_the_trajectory_as_recorded():
    recorded = truth_path(10)
    out = between_matched(recorded, recorded + 1.0, np.zeros(10, dtype=bool))
    np.testing.assert_array_equal(out, recorded)


def test_placement_counts_every_scan_once():
    xy, p = room_map()
    truth = truth_path(12)
    ends = [(scan_from(q), 0.0) for q in truth]
    far = truth.copy()
    far[5, :2] += 2.0  # two metres off: a jump, not a correction
    ends[5] = (scan_from(truth[5] + [0.0, 0.0, 1.0]), 0.0)  # and taken 57 degrees away: nothing matches
    placed = place_scans(xy, p, far, of(ends), SETTINGS)
    assert placed.how[5] == BETWEEN
    c = placed.counts()
    assert c["matched"] + c["between_matched"] + c["no_returns"] == c["scans"] == 12
    with pytest.raises(ValueError, match="recorded poses"):
        place_scans(xy, p, truth[:5], lambda a, b: ends, SETTINGS)


def drifting_updates(truth: np.ndarray, every: int) -> tuple[np.ndarray, np.ndarray]:
    """The poses a filter records along `truth` whose odometry turns 0.004 rad too far each scan, matched
    (set to the truth) every `every` scans, and which scans those are."""
    steps = compose(inverse(truth[:-1]), truth[1:])
    steps[:, 2] += 0.004
    recorded = [truth[0]]
    for k, s in enumerate(steps, start=1):
        recorded.append(truth[k] if k % every == 0 else compose(recorded[-1], s))
    return np.asarray(recorded), np.arange(len(truth)) % every == 0


def test_workers_place_parts_of_the_run_at_once_with_the_same_result():
    """Cut at anchored scans, where a scan starts from its recorded pose either way: two or three workers
    give the one worker's poses exactly, whatever the order their threads run in."""
    xy, p = room_map()
    truth = truth_path(90)
    recorded, anchored = drifting_updates(truth, 20)  # an update every 20 scans
    ends = [(scan_from(q), 0.0) for q in truth]
    read = []

    def source(a, b):
        read.append((a, b))
        return ends[a:b]

    one = place_scans(xy, p, recorded, source, SETTINGS, anchored=anchored)
    assert read == [(0, 90)]
    for workers, cuts in ((2, [(0, 60), (60, 90)]), (3, [(0, 40), (40, 60), (60, 90)])):
        read.clear()
        many = place_scans(xy, p, recorded, source, SETTINGS, anchored=anchored, workers=workers)
        assert sorted(read) == cuts
        np.testing.assert_array_equal(many.poses, one.poses)
        np.testing.assert_array_equal(many.how, one.how)
    assert errors(one.poses, truth)[0] < 0.005


@pytest.mark.parametrize("rasters", [1, 2])
def test_batches_of_any_size_place_the_scans_alike(monkeypatch, rasters):
    """The compiled placement takes the scans a batch at a time, each starting from the scan before as the
    previous batch placed it, and rasterises the map anew where a batch starts or a scan's window leaves
    the raster: the batch size changes nothing, even where a batch ends between updates."""
    import gslam.placement as placement

    xy, p = room_map()
    truth = truth_path(40)
    recorded, anchored = drifting_updates(truth, 15)
    ends = [(scan_from(q), 0.0) if k != 7 else (np.zeros((0, 2)), 0.0) for k, q in enumerate(truth)]
    whole = place_scans(xy, p, recorded, of(ends), SETTINGS, anchored=anchored, rasters=rasters)
    assert whole.how[7] == NO_RETURNS and np.sum(whole.how == PLACED) == 39
    for size in (1, 4, 7):
        monkeypatch.setattr(placement, "BATCH", size)
        batched = place_scans(xy, p, recorded, of(ends), SETTINGS, anchored=anchored, rasters=rasters)
        np.testing.assert_array_equal(batched.poses, whole.poses)
        np.testing.assert_array_equal(batched.how, whole.how)


def test_the_scalar_motion_is_the_composition():
    from gslam.se2 import between_scalar, compose_scalar

    rng = np.random.default_rng(3)
    for _ in range(20):
        placed, before, after = rng.normal(0.0, 3.0, (3, 3))
        want = compose(placed, compose(inverse(before), after))
        got = np.array(compose_scalar(placed, between_scalar(before, after)))
        assert np.allclose(got[:2], want[:2], atol=1e-12)
        assert abs(np.remainder(got[2] - want[2] + np.pi, 2 * np.pi) - np.pi) < 1e-12


def test_scans_between_neighbours_follow_the_motion_not_the_filters_jump():
    """The recorded poses jump at an update (the filter's correction is in them): a scan left to its
    neighbours just before the update must follow the motion, not take the jump as motion."""
    xy, p = room_map()
    truth = truth_path(30)
    motion = np.vstack([np.zeros(3), compose(inverse(truth[:-1]), truth[1:])])
    recorded = truth.copy()
    recorded[:20] = truth[:20] + [0.0, 0.0, 0.05]  # the heading 0.05 rad off before it
    recorded[20:] = truth[20:]  # the update at scan 20 corrected it
    anchored = np.zeros(30, dtype=bool)
    anchored[[0, 20]] = True
    ends = [(scan_from(q), 0.0) for q in truth]
    ends[19] = (ends[19][0][:3], 0.0)  # no returns: placed between scans 18 and 20
    placed = place_scans(xy, p, recorded, of(ends), SETTINGS, anchored=anchored, motion=motion)
    assert placed.how[19] == NO_RETURNS
    trans, rot = errors(placed.poses[19:20], truth[19:20])
    assert trans < 0.005 and rot < 0.2  # along the recorded poses: 1.4 deg


def _reading_7_lost(truth: np.ndarray) -> tuple[np.ndarray, np.ndarray, list, np.ndarray]:
    """(motion, anchored, scans, recorded poses) of a run along `truth` (14 poses) whose odometry misses the
    reading of scan 7: no motion into it, its motion and scan 8's together into scan 8; only scan 0 anchored."""
    motion = np.vstack([np.zeros(3), compose(inverse(truth[:-1]), truth[1:])])
    lost = motion.copy()
    lost[7] = 0.0
    lost[8] = compose(motion[7], motion[8])
    anchored = np.zeros(14, dtype=bool)
    anchored[0] = True
    ends = [(scan_from(q), 0.0) for q in truth]
    return lost, anchored, ends, dead_reckoned(truth[0], lost)


def test_a_scan_whose_odometry_was_lost_is_placed_between_its_neighbours_in_time():
    """The odometry misses one reading (no motion into scan 7, twice the motion into scan 8), as a log that
    drops a message: from the scan before, scan 7 starts 60 cm behind, too far for its match to be kept,
    and the path between its neighbours would leave it there. The second start, between scans 6 and 8 by
    time, places it."""
    xy, p = room_map()
    truth = truth_path(14)
    truth[:, 0] = 1.0 + 0.6 * np.arange(14)
    lost, anchored, ends, recorded = _reading_7_lost(truth)
    assert errors(recorded[7:8], truth[7:8])[0] > 0.55  # the test means something
    placed = place_scans(xy, p, recorded, of(ends), SETTINGS, anchored=anchored, motion=lost, times=np.arange(14.0))
    assert placed.how[7] == PLACED
    trans, rot = errors(placed.poses, truth)
    assert trans < 0.005 and rot < 0.1


def test_a_turn_hidden_by_a_lost_reading_is_found_from_a_neighbours_position():
    """The robot turns in place by 0.5 rad into scan 7 and drives 0.6 m into scan 8, but the odometry misses
    the reading of scan 7 (all the motion comes with scan 8). The pose interpolated by time between scans
    6 and 8 is 0.3 m and 0.25 rad off, beyond the fine climb's reach: the second start also starts from the
    neighbours' positions and headings, and climbs with the update's matcher (`search`), which places it."""
    xy, p = room_map()
    truth = np.zeros((14, 3))
    truth[:7, 0], truth[:7, 1] = 1.0 + 0.6 * np.arange(7), 4.0
    truth[7] = [truth[6, 0], 4.0, -0.5]
    steps = 0.6 * np.arange(1, 7)
    truth[8:] = np.column_stack([truth[7, 0] + steps * math.cos(-0.5), 4.0 + steps * math.sin(-0.5), np.full(6, -0.5)])
    lost, anchored, ends, recorded = _reading_7_lost(truth)
    between = (truth[6] + truth[8]) / 2
    off_m, off_deg = errors(between[None, :], truth[7:8])
    assert off_m > 0.25 and off_deg > 14.0  # the test means something
    search = replace(SETTINGS, step_xy_m=0.05, step_phi_rad=0.05, levels=5)
    placed = place_scans(
        xy, p, recorded, of(ends), SETTINGS, anchored=anchored, motion=lost, times=np.arange(14.0), search=search
    )
    assert placed.how[7] == PLACED
    trans, rot = errors(placed.poses, truth)
    assert trans < 0.005 and rot < 0.1
