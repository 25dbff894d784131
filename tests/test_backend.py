"""The back end (`gslam.backend`): a pose graph closed by loop closures, on a simulated world with known
truth; its parts against known answers (`gslam.posegraph`, `gslam.loopclosure`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gslam.backend import BackEndSettings, PoseGraphBackEnd
from gslam.loopclosure import ClosureSettings, Submap, _mean_field, match_scan
from gslam.posegraph import CLOSURE, SEQUENTIAL, Edge, optimise, optimise_robust
from gslam.scan import transform_points
from gslam.se2 import compose, inverse
from pipelines.demo.world import World, ray_cast

BEARINGS = np.radians(np.arange(-180.0, 180.0, 1.0))


def ring_world(rng: np.random.Generator) -> World:
    """A ring corridor 40 x 24 m (3 m wide) with pillars along its walls: a loop of about 110 m."""
    outer = [(-20, -12, 20, -12), (20, -12, 20, 12), (20, 12, -20, 12), (-20, 12, -20, -12)]
    inner = [(-17, -9, 17, -9), (17, -9, 17, 9), (17, 9, -17, 9), (-17, 9, -17, -9)]
    walls = np.array(outer + inner, dtype=float)
    # pillars against the walls, at random places along them: the corridor is not the same everywhere
    pillars = []
    for x0, y0, x1, y1 in walls:
        for t in rng.uniform(0.05, 0.95, 6):
            x, y = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
            nx, ny = -(y1 - y0), x1 - x0
            norm = math.hypot(nx, ny)
            side = 1.0 if abs(x + 0.3 * nx / norm) < abs(x) or abs(y + 0.3 * ny / norm) < abs(y) else -1.0
            pillars.append([x + side * 0.3 * nx / norm, y + side * 0.3 * ny / norm, rng.uniform(0.15, 0.3)])
    return World(np.array(pillars), walls)


def ring_path(laps: float = 1.3, step_m: float = 0.5, corner_m: float = 1.2) -> np.ndarray:
    """Poses every `step_m` along the corridor's middle (a 37 x 21 m rectangle, its corners rounded to
    `corner_m`), counter-clockwise."""
    hx, hy = 18.5 - corner_m, 10.5 - corner_m
    # (start point, heading) of each straight side; each is followed by a quarter turn of radius corner_m
    sides = [((-hx, -10.5), 0.0, 2 * hx), ((18.5, -hy), math.pi / 2, 2 * hy), ((hx, 10.5), math.pi, 2 * hx),
             ((-18.5, hy), -math.pi / 2, 2 * hy)]  # fmt: skip
    arc = math.pi / 2 * corner_m
    perimeter = sum(length + arc for _, _, length in sides)
    out = []
    for d in np.arange(0.0, laps * perimeter, step_m) % perimeter:
        for (x0, y0), h, length in sides:
            if d < length:
                out.append([x0 + d * math.cos(h), y0 + d * math.sin(h), h])
                break
            d -= length
            if d < arc:
                t = d / corner_m  # the turn so far; the centre is corner_m to the left of the side's end
                ex, ey = x0 + length * math.cos(h), y0 + length * math.sin(h)
                cx, cy = ex - corner_m * math.sin(h), ey + corner_m * math.cos(h)
                out.append([cx + corner_m * math.sin(h + t), cy - corner_m * math.cos(h + t), h + t])
                break
            d -= arc
    poses = np.asarray(out)
    poses[:, 2] = np.angle(np.exp(1j * poses[:, 2]))
    return poses


def scans_along(world: World, truth: np.ndarray, rng: np.random.Generator) -> list[np.ndarray]:
    """Each pose's scan as end points in the sensor frame, ranges with 1 cm noise, 20 m reach."""
    out = []
    for pose in truth:
        r = ray_cast(world, pose[:2], pose[2] + BEARINGS, 20.0)
        ok = np.isfinite(r)
        r = r[ok] + rng.normal(0.0, 0.01, ok.sum())
        out.append(np.column_stack([r * np.cos(BEARINGS[ok]), r * np.sin(BEARINGS[ok])]))
    return out


def drifting(truth: np.ndarray, turn_per_step_rad: float) -> np.ndarray:
    """The truth's motion composed again with a heading error each step: a front end whose error grows
    without bound, as odometry (or a filter that kept the wrong hypothesis) does."""
    steps = compose(inverse(truth[:-1]), truth[1:])
    steps[:, 2] += turn_per_step_rad
    out = [truth[0]]
    for s in steps:
        out.append(compose(out[-1], s))
    return np.asarray(out)


@pytest.fixture(scope="module")
def ring():
    rng = np.random.default_rng(7)
    world = ring_world(rng)
    truth = ring_path()
    return truth, scans_along(world, truth, rng)


def run_backend(front: np.ndarray, scans: list[np.ndarray], settings: BackEndSettings) -> PoseGraphBackEnd:
    backend = PoseGraphBackEnd(settings)
    for step in backend.node_steps(front):
        backend.add_node(int(step), front[step], scans[step])
    backend.finish()
    return backend


def relation_errors(poses: np.ndarray, truth: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and rotation (deg) error of each pair's relative pose against the truth's."""
    a, b = pairs[:, 0], pairs[:, 1]
    err = compose(inverse(compose(inverse(truth[a]), truth[b])), compose(inverse(poses[a]), poses[b]))
    return np.hypot(err[:, 0], err[:, 1]), np.degrees(np.abs(err[:, 2]))


def position_errors(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1])


def test_a_loop_beyond_the_front_ends_reach_is_closed(ring):
    """A heading error of 0.0005 rad a step leaves the front end about 2 m and 6 degrees off when it comes
    back to the start, far beyond a particle filter's spread; the back end finds the start in its first
    submaps by branch and bound over the whole window. Scored as relations (Kuemmerle et al. 2009): the
    poses a lap apart agree again within centimetres, and the poses 10 scans apart are as good as before
    (a pose graph spreads the correction along the loop: the absolute error is not the measure)."""
    truth, scans = ring
    front = drifting(truth, 0.0005)
    lap = int(np.argmin(position_errors(truth[200:], truth[:1]))) + 200  # back at the start
    revisits = np.array([[k, k + lap] for k in range(len(truth) - lap)])
    local = np.array([[k, k + 10] for k in range(len(truth) - 10)])
    before, _ = relation_errors(front, truth, revisits)
    assert before.max() > 1.5  # beyond any filter's spread
    backend = run_backend(front, scans, BackEndSettings())
    summary = backend.summary()
    assert summary["closures_kept"] >= 5, summary
    corrected = backend.correct_trajectory(front)
    trans, rot = relation_errors(corrected, truth, revisits)
    assert trans.max() < 0.05 and rot.max() < 0.5, (trans.max(), rot.max())
    local_before, _ = relation_errors(front, truth, local)
    local_after, local_rot = relation_errors(corrected, truth, local)
    assert local_after.mean() < local_before.mean() + 0.005
    assert local_after.max() < 0.05 and local_rot.max() < 0.5, (local_after.max(), local_rot.max())


def test_a_wrong_closure_is_outvoted_and_rejected(ring):
    """A closure 2 m and 10 degrees off, injected among the right ones, is dropped by the optimisation
    and the trajectory stays where the right ones put it."""
    truth, scans = ring
    front = drifting(truth, 0.0005)
    backend = run_backend(front, scans, BackEndSettings())
    right = backend.correct_trajectory(front)
    assert any(c.kept for c in backend.closures)
    a, k = 10, len(backend.steps) - 30
    true_rel = compose(inverse(truth[backend.steps[a]]), truth[backend.steps[k]])
    wrong = true_rel + [2.0, 0.0, math.radians(10.0)]
    sig = np.array([0.05, 0.05, 0.01])
    edge = Edge(a, k, wrong, sig, CLOSURE, 0.9)
    backend.edges.append(edge)
    from gslam.backend import ClosureRecord

    backend.closures.append(ClosureRecord(edge, 0, kept=True, confirmed=True))
    backend._unoptimised = 1
    backend.finish()
    assert backend.closures[-1].kept is False
    assert sum(c.kept for c in backend.closures) >= 5
    after = backend.correct_trajectory(front)
    assert position_errors(after, right).max() < 0.05


def test_the_optimiser_gives_the_least_squares_answer():
    """A chain 0-1-2 along x with a closure 0-2 that disagrees: the optimum is the weighted least-squares
    solution of the three measurements, which is linear here (no rotation)."""
    a, b = 0.1, 0.05
    edges = [
        Edge(0, 1, np.array([1.0, 0.0, 0.0]), np.array([a, a, 0.01])),
        Edge(1, 2, np.array([1.0, 0.0, 0.0]), np.array([a, a, 0.01])),
        Edge(0, 2, np.array([2.3, 0.0, 0.0]), np.array([b, b, 0.01]), SEQUENTIAL),
    ]
    start = np.array([[0.0, 0.0, 0.0], [0.7, 0.2, 0.05], [1.5, -0.1, -0.03]])
    poses, _ = optimise(start, edges)
    # minimise (x1 - 1)^2 / a^2 + (x2 - x1 - 1)^2 / a^2 + (x2 - 2.3)^2 / b^2 over x1, x2
    A = np.array([[1, 0], [-1, 1], [0, 1]], dtype=float) / np.array([[a], [a], [b]])
    rhs = np.array([1.0, 1.0, 2.3]) / np.array([a, a, b])
    x = np.linalg.lstsq(A, rhs, rcond=None)[0]
    np.testing.assert_allclose(poses[1:, 0], x, atol=1e-6)
    np.testing.assert_allclose(poses[:, 1:], 0.0, atol=1e-6)


def test_consistent_edges_give_back_the_truth_from_a_bad_start():
    rng = np.random.default_rng(3)
    t = np.linspace(0, 5, 20)
    truth = np.column_stack([np.cos(t) * 5, np.sin(t) * 5, t])
    truth[:, 2] = np.angle(np.exp(1j * truth[:, 2]))
    edges = [Edge(i, i + 1, compose(inverse(truth[i]), truth[i + 1]), np.full(3, 0.05)) for i in range(19)]
    edges.append(Edge(0, 19, compose(inverse(truth[0]), truth[19]), np.full(3, 0.05), CLOSURE))
    start = truth + rng.normal(0.0, [0.3, 0.3, 0.1], truth.shape)
    start[0] = truth[0]
    result = optimise_robust(start, edges)
    assert position_errors(result.poses, truth).max() < 1e-5
    assert result.kept == [19] and result.rejected == []


def test_branch_and_bound_finds_the_best_pose_on_the_grid(ring):
    """The search's answer is the best of every pose on its grid (checked by scoring them all) and the
    refinement lands within a centimetre of the truth."""
    truth, scans = ring
    settings = ClosureSettings(window_m=0.6, window_rad=0.05)
    submap = Submap.build(np.vstack([transform_points(truth[k], scans[k]) for k in range(0, 8)]), settings)
    pose = truth[4]
    pts = scans[4][::3]
    guess = pose + [0.35, -0.2, 0.03]
    match = match_scan(submap, pts, guess, settings)
    assert match is not None
    assert math.hypot(*(match.pose[:2] - pose[:2])) < 0.01
    assert abs(match.pose[2] - pose[2]) < math.radians(0.2)
    # exhaustive: every pose of the window's grid scores at most the branch and bound's unrefined best
    r_max = min(float(np.max(np.hypot(pts[:, 0], pts[:, 1]))), settings.heading_range_m)
    step = math.acos(1.0 - settings.cell_m**2 / (2.0 * r_max**2))
    n = int(math.ceil(settings.window_rad / step))
    w = int(math.ceil(settings.window_m / settings.cell_m))
    best = 0.0
    for h in guess[2] + step * np.arange(-n, n + 1):
        c, s = math.cos(h), math.sin(h)
        rot = np.column_stack([c * pts[:, 0] - s * pts[:, 1], s * pts[:, 0] + c * pts[:, 1]])
        for dx in range(-w, w + 1):
            for dy in range(-w, w + 1):
                xy = rot + guess[:2] + np.array([dx, dy]) * settings.cell_m
                ij = np.floor((xy - submap.origin_xy) / settings.cell_m).astype(int)
                n_x, n_y = submap.pyramid.shape[1:]
                inside = (ij >= 0).all(axis=1) & (ij[:, 0] < n_x) & (ij[:, 1] < n_y)
                best = max(best, float(submap.pyramid[0][ij[inside, 0], ij[inside, 1]].sum() / len(pts)))
    assert match.score >= best - 1e-6  # the field is float32: sums in another order differ by ~1e-7
    assert _mean_field(submap.pyramid[0], *submap.origin_xy, settings.cell_m, pts, match.pose) >= 0.9


def test_a_match_off_the_search_grid_is_refined_to_the_truth(ring):
    """Where the truth lies between the search's grid poses (offsets that are no multiple of its 5 cm
    cells), the refinement, not the grid, gives the match: within 5 mm of the truth at every offset,
    where the nearest grid pose is up to 2.5 cm off per axis."""
    truth, scans = ring
    settings = ClosureSettings(window_m=0.6, window_rad=0.05)
    submap = Submap.build(np.vstack([transform_points(truth[k], scans[k]) for k in range(0, 8)]), settings)
    pose, pts = truth[4], scans[4][::3]
    for offset in ([0.337, -0.213, 0.03], [-0.121, 0.262, -0.02], [0.018, 0.041, 0.01], [0.226, 0.112, 0.0]):
        match = match_scan(submap, pts, pose + offset, settings)
        assert match is not None
        assert math.hypot(*(match.pose[:2] - pose[:2])) < 0.005, offset
        assert abs(match.pose[2] - pose[2]) < math.radians(0.1), offset
