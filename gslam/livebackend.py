"""The back end while the run goes: the pose graph of `gslam.backend` built in a background thread from the
front end's motion as it comes, and its correction ready for the outputs as soon as a closure is accepted.

The filter does not wait for it: `LiveBackEnd.offer` takes a node (every `node_travel_m` or
`node_turn_rad` of the best particle's motion) and queues it; a worker thread adds it to the graph, which
searches for closures and optimises (`PoseGraphBackEnd.add_node`).

A particle filter's best particle changes from one scan to the next, and with it the history of the poses
before: the poses it had at the time are not one trajectory. So each node is tied to the one before by
the best particle's own motion since it (its history says how it moved), and every `refresh_nodes` nodes
the graph takes the current best particle's history at all its nodes as the front end's poses
(`PoseGraphBackEnd.refresh_front`); the gate (`PoseGraphBackEnd.judge_front_end`) judges that history.
Each time the graph is optimised and the front end misses enough of its closures, the worker publishes
a `GraphCorrection`: the nodes' optimised poses. The outputs move a pose of the current best particle
by its own pose at the graph's last node (map -> odom), and its path and map by its own poses at every
node. The front end runs on in its own frame, as Cartographer's local SLAM does
under its global one.

The correction applies from the step at which the worker has published it; that step depends on how
fast the machine ran the worker, so the live outputs' corrections may come a few steps earlier or later
from one run to the next. The run's final trajectory and map do not depend on it: the run's end builds
the graph again over the placed trajectory (`GSlamFilter.close_loops`).
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from gslam.backend import BackEndSettings, PoseGraphBackEnd, correct_between, move_with_nodes
from gslam.motion import wrap_angle_scalar
from gslam.se2 import compose, inverse

History = Callable[[np.ndarray], np.ndarray]
"""The current best particle's poses (M, 3) at the steps (M,) given: its history as it stands now."""


@dataclass(frozen=True)
class GraphCorrection:
    """The graph's nodes: their steps and optimised poses. What moves the best particle's poses and map
    onto the graph, given that particle's own poses at the nodes (`History`)."""

    steps: np.ndarray  # (M,)
    estimate: np.ndarray  # (M, 3)
    closures: int
    """Closures kept in the graph when it was published."""

    def latest(self, history: History) -> np.ndarray:
        """The correction (3,) of the poses since the last node: the world transform that takes the best
        particle's pose at that node to the node's optimised pose (map -> odom's change)."""
        return compose(self.estimate[-1], inverse(history(self.steps[-1:])[0]))

    def current(self, poses: np.ndarray, history: History) -> np.ndarray:
        """Poses (..., 3) of the steps since the last node, moved with it."""
        return compose(self.latest(history), np.asarray(poses, dtype=float))

    def trajectory(self, poses: np.ndarray, at_steps: np.ndarray, history: History) -> np.ndarray:
        """The particle's poses (T, 3) at the steps `at_steps`, each moved with the nodes either side of it
        (blended, as the run's end does: `gslam.backend.correct_between`); past the last node, with it."""
        return correct_between(np.asarray(poses, dtype=float), self.steps, history(self.steps), self.estimate, at_steps)

    def points(self, xy: np.ndarray, history: History) -> np.ndarray:
        """The particle's map points (K, 2) moved with the node nearest each, by the particle's positions at
        the nodes (the run's end uses the nodes' scan returns instead: finer, and worth its cost once)."""
        from scipy.spatial import cKDTree

        xy = np.asarray(xy, dtype=float)
        if len(xy) == 0:
            return xy.copy()
        front = history(self.steps)
        _, node = cKDTree(front[:, :2]).query(xy)
        return move_with_nodes(xy, node, front, self.estimate)


LIVE_SETTINGS = replace(
    BackEndSettings(),
    search_every=8,
    confirm_nodes=16,
    optimise_chi2=math.inf,
    optimise_closures=2**62,
    inconsistent_chi2=100.0,
)
"""The live graph's: a quarter of the searches of the run's end's (a closure confirmed by the next
search's), for it shares the machine with the filter; optimised by `LiveBackEnd` itself, only where it
corrects the front end; and it does so only where the front end misses its closures by half a metre or
more (chi2 100 at a closure's 5 cm). Before the run's end places every scan, the best particle's poses
are a few decimetres less precise than the placed ones; a graph over them is no finer than the particle
filter where the filter is right to a few decimetres (docs/CHOICES.md)."""


class LiveBackEnd:
    """A `PoseGraphBackEnd` fed while the run goes, in a worker thread (`background`; else in the caller's,
    for tests that need the same answer every time)."""

    refresh_nodes = 20
    """Nodes between two looks at the graph: its front-end poses refreshed from the best particle's
    history, the gate judged, and the graph optimised if it corrects the front end."""
    optimise_gap_nodes = 20
    """Nodes at least between two optimisations (each takes tens of milliseconds on a graph of a
    thousand nodes); until the next one, the nodes since follow the front end."""
    optimise_gap_share = 25
    """... and at least the graph's nodes / this: an optimisation's cost grows with the graph, so spaced
    so, their total cost on a long run (a 4.8 km log makes some 10 000 nodes) grows with the nodes (about
    25 graphs' worth), not with their square."""

    def __init__(self, settings: BackEndSettings = LIVE_SETTINGS, background: bool = True) -> None:
        self.settings = settings
        self.graph = PoseGraphBackEnd(self.settings)
        self.correction: GraphCorrection | None = None
        """The latest correction published; None while the graph has none for the front end."""
        self.first_corrected_step: int | None = None
        """The first step whose outputs the correction moved (`note_applied`)."""
        self.published = 0  # corrections published
        self.offered = 0  # nodes offered
        self.most_waiting = 0  # the longest the queue grew
        self._steps: list[int] = []  # the steps of the nodes offered
        self._last_pose: np.ndarray | None = None  # the best particle's pose at the last node
        self._refreshed_at = 0  # the nodes offered at the last `refresh_front` the offers asked for
        self._optimised_at = (0, 0)  # (the graph's size, its closures kept) at its last optimisation
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._stopping = False
        self._error: Exception | None = None
        self._worker_s = 0.0
        self._background = background
        self._thread: threading.Thread | None = None
        """The worker, started by the first node (a runner built but never run starts none)."""

    def due(self, pose: np.ndarray) -> bool:
        """Whether the front end's `pose` makes a node: the first, then one each `node_travel_m` of
        travel or `node_turn_rad` of turn from the last node (as `PoseGraphBackEnd.node_steps`)."""
        last = self._last_pose
        if last is None:
            return True
        s = self.settings
        return (
            math.hypot(pose[0] - last[0], pose[1] - last[1]) >= s.node_travel_m
            or abs(wrap_angle_scalar(pose[2] - last[2])) >= s.node_turn_rad
        )

    def offer(self, step: int, pose: np.ndarray, points_xy: Callable[[], np.ndarray], history: History) -> bool:
        """Offer the best particle's `pose` at `step`; when it makes a node (`due`), queue it with its
        returns (`points_xy()`, sensor frame) and the particle's history (`history`): at the node before,
        for its motion since; every `refresh_nodes` nodes at every node, the front end's poses for
        `refresh_front` and the gate (asked for only then: the whole history at every node would cost
        the square of the nodes). Returns whether it made a node. Never waits."""
        if self._error is not None:
            return False  # the worker failed: the run goes on without the live graph (`stop` says why)
        pose = np.asarray(pose, dtype=float)
        if not self.due(pose):
            return False
        self._steps.append(int(step))
        self._last_pose = pose.copy()
        self.offered += 1
        refresh = self.offered - self._refreshed_at >= self.refresh_nodes
        if refresh:
            self._refreshed_at = self.offered
        belief = history(np.asarray(self._steps if refresh else self._steps[-2:]))
        item = (int(step), pose.copy(), np.asarray(points_xy(), dtype=float), belief, refresh)
        if not self._background:
            self._add(*item)
        else:
            if self._thread is None and not self._stopping:
                self._thread = threading.Thread(target=self._work, name="gslam-back-end", daemon=True)
                self._thread.start()
            self._queue.put(item)
            self.most_waiting = max(self.most_waiting, self._queue.qsize())
        return True

    def note_applied(self, step: int) -> None:
        """Record that the outputs of `step` were moved by the correction (the first such step is kept)."""
        if self.first_corrected_step is None:
            self.first_corrected_step = int(step)

    def _work(self) -> None:
        while True:
            item = self._queue.get()
            if item is None or self._stopping:
                return
            try:
                self._add(*item)
            except Exception as e:  # the run goes on uncorrected; `stop` records it
                self._error = e
                self.correction = None
                return

    def _add(self, step: int, pose: np.ndarray, points: np.ndarray, belief: np.ndarray, refresh: bool) -> None:
        """Add the node (tied to the one before by the history's motion, `belief[-2]` to `pose`); with
        `refresh`, `belief` holds the history at every node: refresh the front end and judge the gate."""
        t0 = time.perf_counter()
        g = self.graph
        relative = compose(inverse(belief[-2]), pose) if len(belief) > 1 else None
        g.add_node(step, pose, points, relative)
        if refresh:
            g.refresh_front(belief)
            self._judge(belief)
        self._worker_s += time.perf_counter() - t0

    def _judge(self, belief: np.ndarray) -> None:
        """Whether the graph corrects the front end (the gate, on the best particle's history `belief`):
        if not, the graph's estimate is the front end's poses and nothing is published; if so, the graph
        is optimised when closures came since it last was, and its correction published."""
        g = self.graph
        _, applies = g.judge_front_end(belief)
        if not applies:
            g.estimate = np.array(belief, dtype=float)
            self.correction = None
            return
        kept = sum(c.kept for c in g.closures)
        size, kept_then = self._optimised_at
        if size > 0:
            # the nodes since the last optimisation follow the front end from the last node it moved (their
            # estimate, chained by the motion as it was offered, would drift from the history as rewritten)
            move = compose(g.estimate[size - 1], inverse(belief[size - 1]))
            g.estimate = np.vstack([g.estimate[:size], compose(move, belief[size:])])
        gap = max(self.optimise_gap_nodes, len(g) // self.optimise_gap_share)
        if kept > kept_then and (size == 0 or len(g) - size >= gap):
            g.optimise()
            self._optimised_at = (len(g), sum(c.kept for c in g.closures))
        self.correction = GraphCorrection(np.asarray(g.steps), np.asarray(g.estimate, dtype=float), kept)
        self.published += 1

    def stop(self) -> dict:
        """Stop the worker (the nodes still queued are dropped: the run's end builds the graph again) and
        return what the live graph did, with the error that stopped it early, if one did. The graph is let
        go (its nodes' scans and submap fields); the last correction is kept."""
        self._stopping = True
        waiting = self._queue.qsize()
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join()
        g = self.graph
        self.graph = PoseGraphBackEnd(self.settings)  # its scans and submaps freed for the run's end
        return {
            "nodes": len(g),
            "nodes_dropped_at_end": waiting,
            "most_waiting": self.most_waiting,
            "closures_kept": sum(c.kept for c in g.closures),
            "optimisations": len(g.optimisations),
            "corrections_published": self.published,
            "first_corrected_step": self.first_corrected_step,
            "worker_s": round(self._worker_s, 3),
            "error": None if self._error is None else repr(self._error),
        }
