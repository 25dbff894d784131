"""Odometry alone: the pose the vehicle's own odometry (or controls) gives, without noise and without a
map. The yardstick every SLAM method must beat on a log ("worse than odometry alone" is a failure)."""

from __future__ import annotations

import numpy as np

from gslam.ancestry import AncestryTree
from gslam.filter import Predictor, StepResult
from gslam.scan import Scan


class DeadReckoning:
    """One particle moved by the noise-free motion model at every scan (`gslam.filter.SlamFilter`)."""

    def __init__(self, initial_pose: np.ndarray) -> None:
        self.poses = np.asarray(initial_pose, dtype=float).reshape(1, 3).copy()
        self.weights = np.ones(1)
        self.tree = AncestryTree()

    def step(self, scan: Scan, predict: Predictor | None = None, intensities: np.ndarray | None = None) -> StepResult:
        if predict is not None:
            self.poses = predict(self.poses, None)
        self.tree.record(scan.t_s, self.poses)
        return StepResult(
            scan.t_s, self.poses.copy(), self.weights.copy(), 1.0, False, False, 0, self.poses[0].copy(), 0, 0, 0
        )

    def best_particle(self) -> int:
        return 0

    def best_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        return self.tree.trajectory(0)

    def map_points(self, particle: int) -> tuple[np.ndarray, np.ndarray]:
        return np.empty((0, 2)), np.empty(0)
