"""An update's scan placed again from the pose tracked to it (`gslam.placement.Retrack`): a simulated
corridor with known truth.

Along a corridor every pose on its axis fits the walls; only the alcoves tell them apart. A particle
filter can take a jump along it at an update that one scan's returns favour (Freiburg building 079, a
0.8 m jump at 2109.7 s, and back at the next update): the placement then starts that update's scan, and
the scans after it, from the jumped pose, and nothing pulls them back. Placed again from the scan before
moved by the odometry, the segment fits the map better and is kept; where the odometry is what went
wrong, the filter's chain fits better and stays.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from gslam.placement import PLACED, Retrack, place_scans
from gslam.scanmatch import MatchSettings
from gslam.se2 import compose, inverse
from pipelines.demo.world import World, ray_cast

LENGTH_M = 16.0
WALLS = [[0.0, 0.0, LENGTH_M, 0.0], [0.0, 2.0, LENGTH_M, 2.0], [0.0, 0.0, 0.0, 2.0], [LENGTH_M, 0.0, LENGTH_M, 2.0]]
for x0, x1 in ((5.5, 6.0), (6.9, 7.8), (9.1, 9.5), (10.6, 11.6), (12.4, 12.8), (14.0, 15.0)):  # alcoves, the features
    WALLS += [[x0, 2.0, x0, 2.5], [x0, 2.5, x1, 2.5], [x1, 2.5, x1, 2.0]]
for x0, x1 in ((4.8, 5.2), (6.3, 7.0), (8.2, 8.9), (10.0, 10.4), (11.3, 12.0), (13.1, 13.5), (14.5, 15.3)):
    WALLS += [[x0, 0.0, x0, -0.5], [x0, -0.5, x1, -0.5], [x1, -0.5, x1, 0.0]]
WALLS = np.array(WALLS)
WORLD = World(np.zeros((0, 3)), WALLS)
BEARINGS = np.radians(np.arange(-90.0, 90.5, 0.5))
EVERY = 10
"""An update every this many scans."""
JUMP = np.array([0.45, 0.0, 0.0])
"""The filter's jump along the corridor at one update (m, m, rad in the robot's frame)."""
SETTINGS = MatchSettings(
    cell_m=0.05, kernel=1, min_p=0.5, margin_m=1.0, step_xy_m=0.01, step_phi_rad=0.01, levels=2, max_iterations=100,
    score_sigma_m=0.05, score_sigma_rad=0.0, like_sigma_m=0.2, miss_m=0.2, line_pair_m=0.2, polish_iterations=5,
    climb_stride=1, fine_stride=1, fine_levels=0,
)  # fmt: skip


def corridor_map(spacing_m: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    pts = []
    for x0, y0, x1, y1 in WALLS:
        t = np.linspace(0.0, 1.0, int(math.hypot(x1 - x0, y1 - y0) / spacing_m) + 1)
        pts.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    xy = np.vstack(pts)
    return xy, np.ones(len(xy))


def truth_path(n: int = 80) -> np.ndarray:
    """Down the corridor's middle from x = 5 m, 0.1 m a scan, weaving a little."""
    t = np.arange(n)
    return np.column_stack([5.0 + 0.1 * t, 1.0 + 0.15 * np.sin(t / 9.0), 0.1 * np.sin(t / 13.0)])


def scans(truth: np.ndarray) -> list[tuple[np.ndarray, float]]:
    out = []
    for q in truth:
        r = ray_cast(WORLD, q[:2], q[2] + BEARINGS, 20.0)
        ok = np.isfinite(r)
        out.append((np.column_stack([r[ok] * np.cos(BEARINGS[ok]), r[ok] * np.sin(BEARINGS[ok])]), math.radians(0.5)))
    return out


def filter_record(truth: np.ndarray, jump_at: int | None, odometry_slip_at: int | None):
    """(recorded, anchored, motion): the poses a filter records, matched (the truth) at every EVERY-th
    scan and moved by the odometry between; the update at `jump_at` jumped by JUMP, its segment recorded
    from there; the odometry's step into scan `odometry_slip_at` off by JUMP (the recorded poses right)."""
    motion = np.zeros_like(truth)
    motion[1:] = compose(inverse(truth[:-1]), truth[1:])
    anchored = np.arange(len(truth)) % EVERY == 0
    recorded = truth.copy()
    for k in range(1, len(truth)):
        if k == jump_at:
            recorded[k] = compose(truth[k], JUMP)
        elif not anchored[k]:
            recorded[k] = compose(recorded[k - 1], motion[k])
    if odometry_slip_at is not None:
        motion[odometry_slip_at] = compose(motion[odometry_slip_at], JUMP)
    return recorded, anchored, motion


def place(truth, recorded, anchored, motion, retrack, workers=1):
    ends = scans(truth)
    return place_scans(*corridor_map(), recorded, lambda a, b: ends[a:b], SETTINGS, anchored=anchored,
                       workers=workers, motion=motion, retrack=retrack)  # fmt: skip


def worst_m(poses: np.ndarray, truth: np.ndarray) -> float:
    d = compose(inverse(truth), poses)
    return float(np.hypot(d[:, 0], d[:, 1]).max())


def test_a_jump_at_an_update_is_undone_by_the_segment_tracked_to_it():
    truth = truth_path()
    recorded, anchored, motion = filter_record(truth, jump_at=40, odometry_slip_at=None)
    segment = slice(40, 50)
    first = place(truth, recorded, anchored, motion, None)
    assert worst_m(first.poses[segment], truth[segment]) > 0.3  # the jump kept: the test can fail
    again = place(truth, recorded, anchored, motion, Retrack())
    assert (again.how == PLACED).all()
    assert worst_m(again.poses, truth) < 0.01
    assert again.counts()["retracked_segments"] == 1 and first.counts()["retracked_segments"] == 0
    np.testing.assert_array_equal(again.poses[:40], first.poses[:40])  # only the jumped segment moved


def test_where_the_odometry_slipped_the_filters_update_stays():
    truth = truth_path()
    recorded, anchored, motion = filter_record(truth, jump_at=None, odometry_slip_at=40)
    first = place(truth, recorded, anchored, motion, None)
    again = place(truth, recorded, anchored, motion, Retrack())
    assert worst_m(first.poses, truth) < 0.01
    np.testing.assert_array_equal(again.poses, first.poses)
    assert again.counts()["retracked_segments"] == 0


def test_a_gate_wider_than_the_jump_leaves_it():
    truth = truth_path()
    recorded, anchored, motion = filter_record(truth, jump_at=40, odometry_slip_at=None)
    wide = place(truth, recorded, anchored, motion, Retrack(gate_m=0.5, gate_rad=1.0))
    first = place(truth, recorded, anchored, motion, None)
    np.testing.assert_array_equal(wide.poses, first.poses)


@pytest.mark.parametrize("jump_at", [40, 50])
def test_workers_retrack_alike(jump_at):
    """Cut at an anchored scan, a worker's run begins with a segment whose scan before is another's: it is
    placed again once the runs are done, from the first pass's pose there, as one worker places it within
    its run."""
    truth = truth_path()
    recorded, anchored, motion = filter_record(truth, jump_at=jump_at, odometry_slip_at=None)
    one = place(truth, recorded, anchored, motion, Retrack())
    for workers in (2, 3):
        many = place(truth, recorded, anchored, motion, Retrack(), workers=workers)
        np.testing.assert_array_equal(many.poses, one.poses)
        np.testing.assert_array_equal(many.how, one.how)
        assert many.retracked == one.retracked == 1
    assert worst_m(one.poses, truth) < 0.01
