"""Particle trajectories as a shared ancestry tree: one level per step, no history copied on resampling."""

from __future__ import annotations

import numpy as np


class AncestryTree:
    """Level t holds the N poses recorded at step t and, for each, the index of its parent at level t-1.

    Resampling only changes which node each particle continues from (`continue_from`), so the cost per
    step is O(N) whatever the trajectory length. Between two resamplings every node's parent is the node
    of the same index, so only the levels recorded after a resampling keep their parent links ("hops");
    a trajectory is read back with one Python step per hop and numpy gathers for the levels between.
    """

    def __init__(self) -> None:
        self._times_s = np.empty(0)
        self._poses = np.empty((0, 0, 3))  # (capacity, N, 3): level t's poses in [t]
        self._len = 0
        self._hop_levels: list[int] = []  # levels whose parents are not the identity, increasing
        self._hop_parents: list[np.ndarray] = []
        self._current: np.ndarray | None = None  # node index at the last level, per particle
        self._identity = True  # whether _current is 0, 1, ..., N-1 (no resampling since the last level)
        self._last_lineage = np.empty(0, dtype=np.intp)  # the last `lineage` computed (levels never change)

    def __len__(self) -> int:
        return self._len

    def record(self, t_s: float, poses: np.ndarray) -> None:
        """Add a level: particle i's new pose, child of the node particle i continues from."""
        poses = np.asarray(poses, dtype=float)
        n = len(poses)
        if self._len == 0:
            self._poses = np.empty((1024, n, 3))
            self._times_s = np.empty(1024)
        elif n != self._poses.shape[1]:
            raise ValueError(f"the tree holds {self._poses.shape[1]} particles per level, not {n}")
        if self._len == len(self._times_s):  # grow by doubling: amortised O(N) per level
            self._poses = np.concatenate([self._poses, np.empty_like(self._poses)])
            self._times_s = np.concatenate([self._times_s, np.empty_like(self._times_s)])
        if not self._identity:
            self._hop_levels.append(self._len)
            self._hop_parents.append(np.asarray(self._current, dtype=np.int32))
        self._times_s[self._len] = float(t_s)
        self._poses[self._len] = poses
        self._len += 1
        if not self._identity or self._current is None:
            self._current = np.arange(n)
            self._identity = True

    def continue_from(self, parent_indices: np.ndarray) -> None:
        """After resampling: new particle i continues the history of old particle parent_indices[i]."""
        assert self._current is not None, "record a level before resampling"
        self._current = self._current[np.asarray(parent_indices)]
        self._identity = bool(np.array_equal(self._current, np.arange(len(self._current))))

    def lineage(self, node: int) -> np.ndarray:
        """The node index, at every level, of the history of the last level's `node` (T,).

        Histories merge going back (resampling keeps few lines of descent), so the walk stops at the first
        hop where it meets the previous lineage computed: the same node at the same level has the same
        ancestors, which are copied."""
        out = np.empty(self._len, dtype=np.intp)
        if not self._len:
            return out
        known = self._last_lineage
        end = self._len
        for level, parents in zip(reversed(self._hop_levels), reversed(self._hop_parents), strict=True):
            out[level:end] = node
            if level < len(known) and known[level] == node:
                out[:level] = known[:level]
                break
            node = int(parents[node])
            end = level
        else:
            out[:end] = node
        self._last_lineage = out
        return out

    def trajectory(self, particle: int, levels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(times (T,), poses (T, 3)) of the history of `particle` as it stands now; with `levels`, only
        at those levels (indices into the steps recorded)."""
        if not self._len:
            return np.empty(0), np.empty((0, 3))
        return self.node_trajectory(int(self._current[particle]), levels)

    def node_trajectory(self, node: int, levels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """As `trajectory`, for the history of node `node` of the last level recorded (the particle that
        was i when the step recorded it is node i, whatever resampling did after)."""
        if not self._len:
            return np.empty(0), np.empty((0, 3))
        nodes = self.lineage(node)
        at = np.arange(self._len) if levels is None else np.asarray(levels, dtype=np.intp)
        return self._times_s[at].copy(), self._poses[at, nodes[at]]

    def distinct_ancestors(self, level: int) -> int:
        """How many distinct nodes at `level` still have descendants among the current particles."""
        nodes = np.unique(self._current)
        for hop, parents in zip(reversed(self._hop_levels), reversed(self._hop_parents), strict=True):
            if hop <= level:
                break
            nodes = np.unique(parents[nodes])
        return len(nodes)
