"""Particle trajectories as a shared ancestry tree: one level per step, no history copied on resampling."""

from __future__ import annotations

import numpy as np


class AncestryTree:
    """Level t holds the N poses recorded at step t and, for each, the index of its parent at level t-1.

    Resampling only changes which node each particle continues from (`continue_from`), so the cost per
    step is O(N) whatever the trajectory length; a trajectory is read back by walking parent links.
    """

    def __init__(self) -> None:
        self.times_s: list[float] = []
        self.poses: list[np.ndarray] = []
        self.parents: list[np.ndarray] = []
        self._current: np.ndarray | None = None  # node index at the last level, per particle

    def __len__(self) -> int:
        return len(self.poses)

    def record(self, t_s: float, poses: np.ndarray) -> None:
        """Add a level: particle i's new pose, child of the node particle i continues from."""
        n = len(poses)
        parents = np.arange(n) if self._current is None else self._current
        self.times_s.append(float(t_s))
        self.poses.append(np.array(poses, dtype=float, copy=True))
        self.parents.append(np.asarray(parents, dtype=np.int32))
        self._current = np.arange(n)

    def continue_from(self, parent_indices: np.ndarray) -> None:
        """After resampling: new particle i continues the history of old particle parent_indices[i]."""
        assert self._current is not None, "record a level before resampling"
        self._current = self._current[np.asarray(parent_indices)]

    def trajectory(self, particle: int) -> tuple[np.ndarray, np.ndarray]:
        """(times (T,), poses (T, 3)) of the history of `particle` as it stands now."""
        if not self.poses:
            return np.empty(0), np.empty((0, 3))
        node = int(self._current[particle])
        out = np.empty((len(self.poses), 3))
        for t in range(len(self.poses) - 1, -1, -1):  # one step per level, not per point
            out[t] = self.poses[t][node]
            node = int(self.parents[t][node])
        return np.asarray(self.times_s), out

    def distinct_ancestors(self, level: int) -> int:
        """How many distinct nodes at `level` still have descendants among the current particles."""
        nodes = np.unique(self._current)
        for t in range(len(self.poses) - 1, level, -1):
            nodes = np.unique(self.parents[t][nodes])
        return len(nodes)
