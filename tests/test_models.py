"""Motion and measurement models, resampling, the map update on a tiny map, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gslam.ancestry import AncestryTree
from gslam.config import FilterConfig
from gslam.filter import GSlamFilter
from gslam.initialisation import fit_initial_heading
from gslam.mapupdate.wholemap import point_likelihood_ratio, prune_and_thin, update_probabilities
from gslam.motion import ackermann_step, apply_odometry, integrate_ackermann, odometry_delta
from gslam.pointmap import FlatMaps, PointMap
from gslam.resampling import effective_sample_size, normalise_log_weights, residual_systematic_resampling
from gslam.scan import Scan, ScanGeometry, inverse_measure, measure
from gslam.se2 import compose
from gslam.vehicle import VEHICLE_PRESETS, vehicle_preset
from pipelines.evaluation.metrics import align_se2, gps_mean_error, gps_rmse_aligned, relations_error, relative_pose

CARPARK = VEHICLE_PRESETS["carpark"]


def test_ackermann_straight_and_hand_computed_turn():
    out = ackermann_step(np.array([[0.0, 0.0, 0.0]]), 2.0, 0.0, 0.5, CARPARK)
    np.testing.assert_allclose(out, [[1.0, 0.0, 0.0]])
    # Hand computation, paper eq. kinem: L 2.83, H 0.76, a 3.78, b 0.5, ve 2, alpha 0.1, dt 0.1, phi 0.3.
    ve, al, dt, phi = 2.0, 0.1, 0.1, 0.3
    vc = ve / (1 - math.tan(al) * 0.76 / 2.83)
    x = dt * (vc * math.cos(phi) - vc / 2.83 * math.tan(al) * (3.78 * math.sin(phi) + 0.5 * math.cos(phi)))
    y = dt * (vc * math.sin(phi) + vc / 2.83 * math.tan(al) * (3.78 * math.cos(phi) - 0.5 * math.sin(phi)))
    th = phi + dt * vc / 2.83 * math.tan(al)
    out = ackermann_step(np.array([[0.0, 0.0, phi]]), ve, al, dt, CARPARK)
    np.testing.assert_allclose(out[0], [x, y, th], rtol=1e-12)


def test_paper_preset_and_unknown_preset():
    p = vehicle_preset("paper")
    assert (p.wheelbase_m, p.encoder_offset_m, p.laser_x_m, p.laser_y_m) == (2.75, 0.74, 3.25, 0.5)
    with pytest.raises(ValueError, match="unknown vehicle preset"):
        vehicle_preset("tank")


def test_integrate_uses_every_sample_with_zero_order_hold():
    controls = np.array([[0.0, 1.0, 0.0], [1.0, 2.0, 0.0], [2.0, 0.0, 0.0]])
    out = integrate_ackermann(np.zeros((1, 3)), controls, 2.5, 0.5, CARPARK)
    np.testing.assert_allclose(out[0], [0.5 * 1.0 + 1.0 * 2.0, 0.0, 0.0])


def test_noise_per_interval_is_seeded_and_spreads_particles():
    controls = np.array([[0.0, 2.0, 0.05]])
    a = integrate_ackermann(np.zeros((50, 3)), controls, 1.0, 0.0, CARPARK, np.random.default_rng(1), 0.1, 0.05, 0.02)
    b = integrate_ackermann(np.zeros((50, 3)), controls, 1.0, 0.0, CARPARK, np.random.default_rng(1), 0.1, 0.05, 0.02)
    np.testing.assert_array_equal(a, b)
    assert a[:, 0].std() > 0.03


def test_odometry_model_round_trip():
    prev, cur = np.array([1.0, 2.0, 0.3]), np.array([2.0, 2.5, 0.9])
    delta = odometry_delta(prev, cur)
    out = apply_odometry(prev[None, :], delta, None, (0, 0, 0, 0))
    np.testing.assert_allclose(out[0], cur, atol=1e-12)


def test_odometry_noise_turning_on_the_spot_stays_proportional_to_the_turn():
    # A turn of 0.3 rad with 1 mm of backwards slip: the heading noise is stt x 0.3 rad (+ srt x 1 mm), not
    # a noise on an arbitrary "first rotation" of about pi, as the rot1-trans-rot2 model would give.
    prev, cur = np.array([0.0, 0.0, 0.0]), np.array([-0.001, 0.0, 0.3])
    delta = odometry_delta(prev, cur)
    out = apply_odometry(np.zeros((4000, 3)), delta, np.random.default_rng(0), (0.1, 0.2, 0.1, 0.2))
    assert out[:, 2].std() == pytest.approx(0.2 * 0.3 + 0.2 * 0.001, rel=0.1)
    assert np.abs(out[:, 2] - 0.3).max() < 0.3  # never flipped round
    assert out[:, 0].std() == pytest.approx(0.1 * 0.3 + 0.1 * 0.001, rel=0.1)


def test_compiled_odometry_model_gives_the_array_formulas_bit_for_bit():
    """apply_odometry's compiled loop against the model written as numpy array expressions: the same
    numbers, so seeded runs on odometry logs are what they were before it was compiled."""

    def reference(poses, delta, rng, sigma):
        dx, dy, dth = delta
        srr, srt, str_, stt = sigma
        if rng is None:
            mx, my, mth = (np.full(len(poses), v) for v in delta)
        else:
            e = rng.standard_normal((len(poses), 3))
            mx = dx + e[:, 0] * (srr * abs(dx) + str_ * abs(dth) + 0.3 * srr * abs(dy))
            my = dy + e[:, 1] * (srr * abs(dy) + str_ * abs(dth) + 0.3 * srr * abs(dx))
            mth = dth + e[:, 2] * (stt * abs(dth) + srt * float(np.hypot(dx, dy)))
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        th = (poses[:, 2] + mth + np.pi) % (2 * np.pi) - np.pi
        return np.column_stack([poses[:, 0] + c * mx - s * my, poses[:, 1] + s * mx + c * my, th])

    rng = np.random.default_rng(3)
    for k in range(300):
        poses = np.column_stack([rng.normal(0, 30, (25, 2)), rng.uniform(-4, 4, 25)])
        delta = tuple(float(v) for v in rng.normal(0, [0.3, 0.05, 0.2]) * (k % 5 != 0))
        sigma = (0.1, 0.05, 0.1, 0.2)
        for seed in (None, k):
            got = apply_odometry(poses, delta, None if seed is None else np.random.default_rng(seed), sigma)
            want = reference(poses, delta, None if seed is None else np.random.default_rng(seed), sigma)
            np.testing.assert_array_equal(got, want)


def test_measurement_model_and_inverse():
    pose = np.array([1.0, 1.0, math.pi / 2])
    r, b = measure(pose, np.array([0.0, 1.0]))  # a point to the robot's left
    assert r == pytest.approx(1.0) and b == pytest.approx(math.pi / 2)
    xy = inverse_measure(pose, np.array(3.0), np.array(-0.4))
    r2, b2 = measure(pose, xy)
    assert (r2, b2) == pytest.approx((3.0, -0.4))


def test_initial_heading_recovers_rotation():
    rng = np.random.default_rng(0)
    t = np.arange(0, 6, 0.025)
    controls = np.column_stack([t, np.full_like(t, 2.0), 0.05 + 0.01 * rng.standard_normal(len(t))])
    from gslam.initialisation import dead_reckoning

    true_heading = -2.2
    gps_t = np.arange(0.0, 6.0, 0.2)
    dr = dead_reckoning(controls, np.array([3.0, 4.0, true_heading]), 0.0, gps_t[1:], CARPARK)
    gps = np.vstack([[0.0, 3.0, 4.0], np.column_stack([gps_t[1:], dr[:, :2]])])
    est = fit_initial_heading(controls, gps, CARPARK, 5.0)
    assert est[:2] == pytest.approx([3.0, 4.0])
    assert est[2] == pytest.approx(true_heading, abs=1e-6)


weights_strategy = st.lists(st.floats(0.0, 1.0, allow_nan=False), min_size=1, max_size=60).filter(
    lambda w: sum(w) > 1e-6
)


@settings(max_examples=200, deadline=None)
@given(weights_strategy, st.integers(0, 2**32 - 1))
def test_rsr_properties(w, seed):
    w = np.asarray(w) / np.sum(w)
    idx = residual_systematic_resampling(w, np.random.default_rng(seed))
    n = len(w)
    assert len(idx) == n
    assert np.all(np.diff(idx) >= 0)  # replications come in order
    counts = np.bincount(idx, minlength=n)
    # RSR's counts stay within one of N w_i, and zero-weight particles are never picked.
    assert np.all(np.abs(counts - n * w) < 1 + 1e-9)
    assert np.all(counts[w == 0] == 0)


def test_rsr_is_unbiased_on_average():
    w = np.array([0.1, 0.2, 0.3, 0.4])
    rng = np.random.default_rng(3)
    mean = np.mean([np.bincount(residual_systematic_resampling(w, rng), minlength=4) for _ in range(4000)], axis=0)
    np.testing.assert_allclose(mean, 4 * w, atol=0.03)


def test_ess_and_log_weight_normalisation():
    assert effective_sample_size(np.full(8, 1 / 8)) == pytest.approx(8)
    assert effective_sample_size(np.array([1.0, 0, 0])) == pytest.approx(1)
    w = normalise_log_weights(np.array([-1000.0, -1000.0 + math.log(3), -np.inf]))
    np.testing.assert_allclose(w, [0.25, 0.75, 0.0])


def test_eq7_update_on_a_tiny_map_by_hand():
    cfg = FilterConfig(map_update="global")
    p = np.array([0.5, 0.3, 0.2])
    q = np.array([3.0, 1.0, 0.3])
    owner = np.zeros(3, dtype=np.int64)
    out = update_probabilities(p, q, owner, np.ones(3, bool), 1, cfg)
    denom = 3 * 0.5 + 0.3 + 0.3 * 0.2
    np.testing.assert_allclose(out, [1.5 / denom, 0.3 / denom, 0.06 / denom])
    # "observed": the unobserved point keeps its p, the observed mass (0.8) is redistributed.
    cfg = FilterConfig(map_update="observed")
    out = update_probabilities(p, q, owner, np.array([True, False, True]), 1, cfg)
    assert out[1] == 0.3
    np.testing.assert_allclose(out[[0, 2]], np.array([1.5, 0.06]) * 0.7 / 1.56)
    # binary: logit p += log q.
    cfg = FilterConfig(map_update="binary")
    out = update_probabilities(np.array([0.5]), np.array([3.0]), np.zeros(1, dtype=np.int64), np.ones(1, bool), 1, cfg)
    assert out[0] == pytest.approx(0.75)


def test_point_likelihood_regions():
    cfg = FilterConfig(hit_ratio=3.0, free_ratio=0.3, hit_sigma_m=0.2)
    r = np.array([5.0, 2.0, 9.0, 5.0])
    z = np.array([5.0, 5.0, 5.0, 5.0])
    observed = np.array([True, True, True, False])
    q = point_likelihood_ratio(r, z, observed, cfg)
    assert q[0] == pytest.approx(3.0)  # at the return
    assert q[1] == pytest.approx(0.3)  # observed free space
    assert q[2] == pytest.approx(1.0)  # occluded, behind the return
    assert q[3] == 1.0  # unobserved


def test_prune_and_thin():
    cfg = FilterConfig(prune_relative=True, prune_threshold=0.5, max_points_per_cell=1, cell_size_m=1.0)
    xy = np.array([[0.1, 0.1], [0.2, 0.2], [5.0, 5.0], [9.0, 9.0]])
    p = np.array([0.4, 0.3, 0.25, 0.05])
    out = prune_and_thin(FlatMaps(xy, p, np.zeros(4, dtype=np.int64)), 1, cfg)
    # mean p 0.25: the 0.05 point goes; of the two in one cell the more probable stays.
    np.testing.assert_allclose(out.xy, [[0.1, 0.1], [5.0, 5.0]])


def test_point_maps_are_immutable_and_shared_after_resampling():
    m = PointMap(np.zeros((2, 2)), np.ones(2))
    with pytest.raises(ValueError):
        m.p[0] = 3.0
    cfg = FilterConfig(particles=4, resample_threshold=1.0)
    flt = GSlamFilter(cfg, np.zeros(3))
    assert all(mp is flt.maps[0] for mp in flt.maps)


def test_ancestry_tree_shares_histories():
    tree = AncestryTree()
    tree.record(0.0, np.array([[0, 0, 0], [1, 0, 0]], dtype=float))
    tree.continue_from(np.array([1, 1]))
    tree.record(1.0, np.array([[1, 1, 0], [1, 2, 0]], dtype=float))
    t, traj = tree.trajectory(0)
    np.testing.assert_allclose(traj, [[1, 0, 0], [1, 1, 0]])
    assert tree.distinct_ancestors(0) == 1


def test_ancestry_tree_matches_walking_every_parent_link():
    """Random resamplings (several between records, some the identity): every trajectory read, by
    particle or by a level's node, in any order, is the one a walk over every level's parent gives."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        tree, poses, parents, current, n = AncestryTree(), [], [], None, 6
        for k in range(150):
            level = rng.standard_normal((n, 3))
            tree.record(float(k), level)
            poses.append(level)
            parents.append(np.arange(n) if current is None else current)
            current = np.arange(n)
            for _ in range(int(rng.integers(0, 3))):
                chosen = rng.integers(0, n, n) if rng.random() < 0.8 else np.arange(n)
                tree.continue_from(chosen)
                current = current[chosen]
            if rng.random() < 0.3:

                def walk(node: int, poses=poses, parents=parents) -> np.ndarray:
                    out = []
                    for t in range(len(poses) - 1, -1, -1):
                        out.append(poses[t][node])
                        node = int(parents[t][node])
                    return np.array(out[::-1])

                node, particle = int(rng.integers(0, n)), int(rng.integers(0, n))
                np.testing.assert_array_equal(tree.node_trajectory(node)[1], walk(node))
                np.testing.assert_array_equal(tree.trajectory(particle)[1], walk(int(current[particle])))
                levels = np.sort(rng.choice(len(poses), size=min(5, len(poses)), replace=False))
                np.testing.assert_array_equal(tree.node_trajectory(node, levels)[1], walk(node)[levels])


def test_metrics_on_constructed_trajectories():
    t = np.linspace(0, 10, 101)
    path = np.column_stack([np.cos(t), np.sin(t), t])
    gps = np.column_stack([t, path[:, 0], path[:, 1]])
    assert gps_mean_error(t, path, gps) == pytest.approx(0.0)
    shifted = path + [0.3, 0.4, 0]
    assert gps_mean_error(t, shifted, gps) == pytest.approx(0.5)
    c, s = math.cos(0.5), math.sin(0.5)
    rotated = np.column_stack([c * path[:, 0] - s * path[:, 1] + 2, s * path[:, 0] + c * path[:, 1] - 1, t])
    assert gps_rmse_aligned(t, rotated, gps) == pytest.approx(0.0, abs=1e-9)
    ang, _ = align_se2(rotated[:, :2], path[:, :2])
    assert ang == pytest.approx(-0.5)
    # Relations of a perfect trajectory give zero error.
    rel_t1, rel_t2 = t[:-5], t[5:]
    ref = relative_pose(path[:-5], path[5:])
    relations = np.column_stack([rel_t1, rel_t2, ref])
    err = relations_error(t, path, relations)
    assert err["relations_trans_m"] == pytest.approx(0.0, abs=1e-12) and err["relations_used"] == 96


def _drive_with_turns_in_place() -> np.ndarray:
    """Base poses every 0.1 s: 1 m ahead, then a quarter turn in place, four times over."""
    poses = [np.zeros(3)]
    for _ in range(4):
        for _ in range(10):
            x, y, th = poses[-1]
            poses.append(np.array([x + 0.1 * math.cos(th), y + 0.1 * math.sin(th), th]))
        for _ in range(16):
            poses.append(poses[-1] + [0.0, 0.0, math.pi / 32])
    return np.array(poses)


def test_the_relations_frame_is_found_from_turns_in_place():
    """Relations of a sensor 5 cm ahead of the base, scored against the base's trajectory: every relation
    that turns round is off by up to twice that, and the turns in place say where the frame lies."""
    from pipelines.evaluation.evaluate import frame_note
    from pipelines.evaluation.metrics import relations_frame_offset

    base = _drive_with_turns_in_place()
    t = np.arange(len(base)) * 0.1
    sensor = compose(base, np.array([0.05, 0.0, 0.0]))
    pairs = [(i, j) for i in range(len(base)) for j in (i + 5, i + 30) if j < len(base)]
    i1, i2 = np.array(pairs).T
    relations = np.column_stack([t[i1], t[i2], relative_pose(sensor[i1], sensor[i2])])
    offset, turns = relations_frame_offset(t, base, relations)
    assert turns >= 10 and np.allclose(offset, [0.05, 0.0], atol=1e-9)
    assert relations_error(t, base, relations)["relations_trans_m"] > 0.01
    note = frame_note(t, base, relations)
    assert "0.050 m ahead" in note and note.endswith("scored in that frame: 0.000 m")
    # The sensor's own trajectory: the frames agree, nothing to say.
    same, _ = relations_frame_offset(t, sensor, relations)
    assert np.allclose(same, 0.0, atol=1e-9) and frame_note(t, sensor, relations) is None


def test_filter_is_deterministic_for_a_seed():
    geom = ScanGeometry(181, -math.pi / 2, math.pi / 180, 30.0)
    rng = np.random.default_rng(5)
    scans = [Scan(float(i), 5.0 + 0.05 * rng.standard_normal(181), geom) for i in range(5)]

    def run(seed):
        flt = GSlamFilter(FilterConfig(particles=5, seed=seed, proposal="motion"), np.zeros(3))

        def predict(poses, g):
            return poses.copy() if g is None else poses + g.standard_normal(poses.shape) * 0.05

        for sc in scans:
            flt.step(sc, predict)
        return flt.best_trajectory()[1], flt.maps[flt.best_particle()].xy

    a, b, c = run(1), run(1), run(2)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])


def test_skipped_scans_are_filled_with_noise_free_motion():
    geom = ScanGeometry(181, -math.pi / 2, math.pi / 180, 30.0)
    scans = [Scan(float(i), np.full(181, 5.0), geom) for i in range(6)]

    def predict(poses, g):  # 0.3 m ahead per scan, with 5 cm of noise when sampled
        out = poses + [0.3, 0.0, 0.0]
        return out if g is None else out + g.standard_normal(poses.shape) * [0.05, 0.05, 0.0]

    trajectories = {}
    for fill in ("odometry", "sampled"):
        cfg = FilterConfig(particles=4, seed=0, proposal="motion", fill_skipped=fill, min_travel_m=1.0)
        flt = GSlamFilter(cfg, np.zeros(3))
        updated = [flt.step(sc, predict).updated for sc in scans]
        assert updated == [True, False, False, False, True, False]  # after 1.2 m of travel
        trajectories[fill] = flt.tree.trajectory(0)[1]
    odo = trajectories["odometry"]
    np.testing.assert_allclose(np.diff(odo[:4, 0]), 0.3)  # skipped scans: exactly the odometry
    np.testing.assert_allclose(odo[1:4, 1], odo[0, 1])  # no sideways noise either
    assert np.abs(np.diff(trajectories["sampled"][:4, 0]) - 0.3).max() > 0.01


def test_pole_map_error_on_constructed_maps():
    from pipelines.evaluation.metrics import pole_map_error

    poles = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    rng = np.random.default_rng(0)
    # Points exactly on the poles, with the highest p, amid weaker clutter far from them.
    clutter = rng.uniform(20, 40, size=(200, 2))
    xy = np.vstack([poles, clutter])
    p = np.r_[np.full(3, 0.9), np.full(200, 0.6)]
    err, within = pole_map_error(xy, p, poles)
    assert err == pytest.approx(0.0) and within == 3
    # Shift the pole points by 0.5 m: the error is 0.5 m.
    err, within = pole_map_error(np.vstack([poles + [0.3, 0.4], clutter]), p, poles)
    assert err == pytest.approx(0.5) and within == 3


def test_covariance_ellipses():
    from pipelines.outputs.rerun_result import covariance_ellipses

    (e,) = covariance_ellipses(np.array([[1.0, 2.0]]), np.array([[[0.04, 0.0], [0.0, 0.01]]]), sigmas=3.0)
    d = e - [1.0, 2.0]
    assert np.abs(d[:, 0]).max() == pytest.approx(0.6, rel=1e-2)  # 3 x 0.2, outline sampled at 24 points
    assert np.abs(d[:, 1]).max() == pytest.approx(0.3, rel=1e-2)  # 3 x 0.1


def test_paper_tables_cover_every_method_of_the_paper_and_n():
    from pipelines.bench.carpark import FULL_GRID, PAPER_TABLE3, PAPER_TABLE4
    from pipelines.methods import NAMES

    paper_methods = [m for m in NAMES if m != "odometry"]  # odometry alone is ours, not a row of the paper
    assert set(PAPER_TABLE3) == set(FULL_GRID)
    assert set(PAPER_TABLE4) == {(m, n) for m in paper_methods for n in (2, 8, 30)}
    assert PAPER_TABLE4[("grid-hr", 8)] == (648, 0.41) and PAPER_TABLE4[("fastslam2", 2)] == (31, 0.47)
