"""The back end while the run goes (`gslam.livebackend`): the graph built from the front end's poses as
they come, its correction published only where the front end misses its closures, and the outputs' view
of it (`pipelines.run.live_graph`); on the simulated ring corridor of tests/test_backend.py."""

from __future__ import annotations

import numpy as np
import pytest

from gslam.livebackend import LiveBackEnd
from gslam.se2 import compose, inverse
from pipelines.run.live_graph import CorrectedView
from tests.test_backend import drifting, position_errors, ring_path, ring_world, scans_along


@pytest.fixture(scope="module")
def long_ring():
    """Two laps of the ring corridor: the second lap's closures are many."""
    rng = np.random.default_rng(11)
    world = ring_world(rng)
    truth = ring_path(laps=1.8)
    return truth, scans_along(world, truth, rng)


def feed(live: LiveBackEnd, offered: np.ndarray, history: np.ndarray, scans: list[np.ndarray]) -> list:
    """Offer every step, as the runner does (`history`: the front end's poses as it believes them now);
    the correction in force at each step."""
    in_force = []
    for t, pose in enumerate(offered):
        live.offer(t, pose, lambda t=t: scans[t], lambda steps: history[np.asarray(steps)])
        in_force.append(live.correction)
    return in_force


def relation_error(a: np.ndarray, b: np.ndarray, true_a: np.ndarray, true_b: np.ndarray) -> float:
    """How far (m) pose b is from where it should be relative to pose a."""
    err = compose(inverse(compose(inverse(true_a), true_b)), compose(inverse(a), b))
    return float(np.hypot(err[0], err[1]))


def lap_index(truth: np.ndarray) -> int:
    return int(np.argmin(position_errors(truth[200:], truth[:1]))) + 200


def test_a_front_end_that_misses_the_loop_is_corrected_from_the_closure_on(long_ring):
    """A front end whose heading drifts 0.0005 rad a step is metres off when it comes round again. Nothing
    is published on the first lap (no closure yet); from the second lap on the correction moves the current
    pose to within decimetres of the truth, where the front end alone is metres off."""
    truth, scans = long_ring
    front = drifting(truth, 0.0005)
    live = LiveBackEnd(background=False)
    in_force = feed(live, front, front, scans)
    lap = lap_index(truth)
    assert all(c is None for c in in_force[: lap - 5])
    corrected = [t for t, c in enumerate(in_force) if c is not None]
    assert corrected and corrected[0] < lap + 110, corrected[:3]  # five closures confirmed: ~45 m
    # what the user sees at step t: the robot (its pose moved) in the map of the first lap (its path moved)
    tail = np.arange(len(truth) - 40, len(truth))
    history = lambda s: front[np.asarray(s)]  # noqa: E731
    errors_before, errors_after = [], []
    for t in tail:
        corr = in_force[t]
        here, there = (
            corr.current(front[t], history),
            corr.trajectory(front[t - lap : t - lap + 1], [t - lap], history)[0],
        )
        errors_after.append(relation_error(there, here, truth[t - lap], truth[t]))
        errors_before.append(relation_error(front[t - lap], front[t], truth[t - lap], truth[t]))
    # between two optimisations the newest poses follow the front end, and drift with it again
    assert min(errors_before) > 1.0, min(errors_before)
    assert np.median(errors_after) < 0.3 and max(errors_after) < 0.5 * min(errors_before), errors_after
    record = live.stop()
    assert record["corrections_published"] > 0 and record["closures_kept"] >= 5, record
    assert record["error"] is None and record["nodes"] == live.offered


def test_a_front_end_that_holds_the_loop_is_left_alone(long_ring):
    """The same loop with a front end that is right to a centimetre: the closures agree with it, and the
    live graph publishes nothing (its gate)."""
    truth, scans = long_ring
    rng = np.random.default_rng(5)
    front = truth + rng.normal(0.0, [0.01, 0.01, 0.001], truth.shape)
    live = LiveBackEnd(background=False)
    in_force = feed(live, front, front, scans)
    assert all(c is None for c in in_force)
    record = live.stop()
    assert record["closures_kept"] >= 5 and record["corrections_published"] == 0, record


def test_a_history_rewritten_right_is_judged_not_the_poses_offered(long_ring):
    """A particle filter rewrites its best history when it resamples: poses offered at the time drift, but
    the history as it stands is right. The graph takes the history (`refresh_front`) and the gate judges it,
    so nothing is published."""
    truth, scans = long_ring
    front = drifting(truth, 0.0005)
    live = LiveBackEnd(background=False)
    in_force = feed(live, front, truth, scans)
    assert all(c is None for c in in_force[-40:])


def test_the_worker_thread_runs_beside_and_stops(long_ring):
    """In the background the same nodes are taken (those queued at the stop are dropped and counted), the
    record is whole and the thread is gone after `stop`."""
    truth, scans = long_ring
    front = drifting(truth, 0.0005)
    live = LiveBackEnd()
    feed(live, front, front, scans)
    record = live.stop()
    assert record["error"] is None
    assert record["nodes"] + record["nodes_dropped_at_end"] == live.offered
    assert live._thread is not None and not live._thread.is_alive()
    assert LiveBackEnd()._thread is None  # none started before the first node


def test_a_failing_worker_leaves_the_run_uncorrected_and_says_why(long_ring, monkeypatch):
    truth, scans = long_ring
    live = LiveBackEnd(background=False)

    def broken(*args, **kwargs):
        raise RuntimeError("solver gone")

    monkeypatch.setattr(live.graph, "add_node", broken)
    with pytest.raises(RuntimeError):  # in the caller's thread it is raised where it happens
        feed(live, truth[:3], truth, scans)
    background = LiveBackEnd()
    monkeypatch.setattr(background.graph, "add_node", broken)
    feed(background, truth[:50], truth, scans)  # never raises in the run's thread
    background._thread.join(30)  # the worker ends at its first failure (`stop` would drop what it has not taken)
    record = background.stop()
    assert "solver gone" in record["error"] and background.correction is None


class _StubFilter:
    """A filter whose map and history are given: what the view reads."""

    def __init__(self, xy: np.ndarray, history: np.ndarray) -> None:
        self.xy, self.history, self.steps = xy, history, len(history)

    def map_points(self, particle: int) -> tuple[np.ndarray, np.ndarray]:
        return self.xy, np.ones(len(self.xy))

    @property
    def tree(self):
        outer = self

        class Tree:
            def __len__(self) -> int:
                return len(outer.history)

            def trajectory(self, particle, levels=None):
                at = np.arange(len(outer.history)) if levels is None else np.asarray(levels)
                return at.astype(float), outer.history[at]

            node_trajectory = trajectory

        return Tree()


def test_the_outputs_view_moves_the_map_and_path_with_the_graph(long_ring):
    """Once a correction is published the view moves each map point with its nearest node and the path
    with its nodes; before it, and after the run (`correction` None), it passes them through."""
    truth, scans = long_ring
    front = drifting(truth, 0.0005)
    live = LiveBackEnd(background=False)
    feed(live, front, front, scans)
    live.stop()
    corr = live.correction
    assert corr is not None
    xy = front[corr.steps[-3:], :2].copy()  # points where the last nodes' scans were taken
    view = CorrectedView(_StubFilter(xy, front), live)
    moved, _ = view.map_points(0)
    np.testing.assert_allclose(moved, corr.estimate[-3:, :2], atol=1e-9)  # each moved with its node
    assert position_errors(moved, xy).min() > 0.05  # and moved at all
    _, path = view.tree.node_trajectory(0, corr.steps)
    np.testing.assert_allclose(path, corr.estimate, atol=1e-9)  # the path at the nodes is the graph's
    live.correction = None
    assert view.map_points(0)[0] is xy


class _FixedCorrection:
    """A correction that moves everything by one world transform: what the plumbing must carry."""

    def __init__(self, move: np.ndarray) -> None:
        self.move = move

    def latest(self, history) -> np.ndarray:
        return self.move

    def trajectory(self, poses, at_steps, history) -> np.ndarray:
        return compose(self.move, poses)

    def points(self, xy, history) -> np.ndarray:
        return compose(self.move, np.column_stack([xy, np.zeros(len(xy))]))[:, :2]


def test_the_live_correction_reaches_tf_pose_and_path_but_not_the_final_result(tmp_path, monkeypatch):
    """A run whose live graph publishes a correction from step 15 on: from then, /tf's map -> odom, the
    /slam/pose (the base's, the laser mounted off it), the particles and the /slam/path are moved by it; the
    steps before, the odometry and the final trajectory are as in a run without it; the record says when."""
    import math

    from bagtools import bag_from_log
    from test_user_commands import _carmen_log, gslam

    import pipelines.run.runner as runner_module
    from ingest import ingest, read_log
    from mcaplog.mcapio import McapInput

    move = np.array([0.4, -0.3, 0.05])

    class Publishing(LiveBackEnd):
        def __init__(self) -> None:
            super().__init__(background=False)

        def offer(self, step, pose, points_xy, history) -> bool:
            if step == 15:
                self.correction = _FixedCorrection(move)
            return super().offer(step, pose, points_xy, history)

    bag = bag_from_log(read_log(_carmen_log(tmp_path / "corridor.clf", 40)), tmp_path / "r.bag", "ros1", 40, "topic",
                       (0.25, -0.125, 0.5))  # fmt: skip
    ingest(bag, tmp_path / "r.mcap")
    plain, moved = tmp_path / "plain.mcap", tmp_path / "moved.mcap"
    assert gslam("process", tmp_path / "r.mcap", "-o", plain, "--no-rrd", "-N", "2").exit_code == 0
    monkeypatch.setattr(runner_module, "LiveBackEnd", Publishing)
    assert gslam("process", tmp_path / "r.mcap", "-o", moved, "--no-rrd", "-N", "2").exit_code == 0

    def read(path):
        topics = {"/tf": [], "/slam/pose": [], "/slam/path": [], "/slam/trajectory": [], "/slam/particles": []}
        for m in McapInput(path).messages(list(topics)):
            topics[m.topic].append(m.value)
        return topics

    def planar(tf) -> np.ndarray:
        q = tf.rotation
        return np.array([tf.translation.x, tf.translation.y, 2 * math.atan2(q.z, q.w)])

    def links(tf) -> dict:
        return {(x.parent_frame_id, x.child_frame_id): planar(x) for x in tf.transforms}

    def pose_of(p) -> np.ndarray:
        q = p.orientation
        return np.array([p.position.x, p.position.y, 2 * math.atan2(q.z, q.w)])

    a, b = read(plain), read(moved)
    for k, (tf_a, tf_b) in enumerate(zip(a["/tf"], b["/tf"], strict=True)):
        la, lb = links(tf_a), links(tf_b)
        np.testing.assert_allclose(la[("odom", "base_link")], lb[("odom", "base_link")], atol=1e-9)
        expected = compose(move, la[("map", "odom")]) if k >= 15 else la[("map", "odom")]
        d = lb[("map", "odom")] - expected
        assert math.hypot(d[0], d[1]) < 1e-6 and abs(math.sin(d[2])) < 1e-6, (k, lb[("map", "odom")], expected)
        pa, pb = pose_of(a["/slam/pose"][k].pose), pose_of(b["/slam/pose"][k].pose)
        np.testing.assert_allclose(pb[:2], (compose(move, pa) if k >= 15 else pa)[:2], atol=1e-6)
        pa0, pb0 = a["/slam/particles"][k].poses[0], b["/slam/particles"][k].poses[0]
        np.testing.assert_allclose(pose_of(pb0)[:2], (compose(move, pose_of(pa0)) if k >= 15 else pose_of(pa0))[:2],
                                   atol=1e-6)  # fmt: skip
    last_a = np.array([pose_of(p) for p in a["/slam/path"][-1].poses])
    last_b = np.array([pose_of(p) for p in b["/slam/path"][-1].poses])
    np.testing.assert_allclose(last_b[:, :2], compose(move, last_a)[:, :2], atol=1e-6)
    final_a = np.array([pose_of(p) for p in a["/slam/trajectory"][0].poses])
    final_b = np.array([pose_of(p) for p in b["/slam/trajectory"][0].poses])
    np.testing.assert_allclose(final_b, final_a, atol=1e-12)
    live = McapInput(moved).metadata()["result"]["loop_closure"]["live"]
    assert live["first_corrected_step"] == 15 and live["error"] is None, live


def test_a_run_that_cannot_start_leaves_no_worker_thread(tmp_path, monkeypatch):
    """The live graph's thread starts with the runner; a run whose outputs cannot be started stops it."""
    import threading

    from test_user_commands import _carmen_log, gslam

    import pipelines.outputs.mcap_result as mcap_result
    from ingest import ingest

    ingest(_carmen_log(tmp_path / "corridor.clf", 10), tmp_path / "in.mcap")

    def refuse(self, run):
        raise OSError("disk full")

    monkeypatch.setattr(mcap_result.McapResultWriter, "start", refuse)
    before = set(threading.enumerate())
    result = gslam("process", tmp_path / "in.mcap", "-o", tmp_path / "out.mcap", "--no-rrd", "-N", "2")
    assert result.exit_code != 0
    assert not [t for t in set(threading.enumerate()) - before if t.name == "gslam-back-end"]
