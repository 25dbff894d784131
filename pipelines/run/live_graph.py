"""The outputs' view of the filter while the live back end corrects it (`gslam.livebackend`): the map
snapshots and the path moved onto the pose graph; everything else passes through.

The runner moves each step's poses itself (`SlamRunner`); this view moves what the writers read from the
filter between steps. Once the run is over the live back end is stopped and the view passes everything
through: the final trajectory and map are the run's end's (`GSlamFilter.close_loops`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gslam.filter import SlamFilter
from gslam.livebackend import GraphCorrection, LiveBackEnd


class CorrectedTree:
    """A filter's ancestry tree whose node trajectories (the /slam/path) are moved onto the live graph."""

    def __init__(self, tree: Any, live: LiveBackEnd) -> None:
        self._tree = tree
        self._live = live

    def __len__(self) -> int:
        return len(self._tree)

    def node_trajectory(self, node: int, levels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        t, traj = self._tree.node_trajectory(node, levels)
        corr = self._live.correction
        if corr is None or len(traj) == 0:
            return t, traj
        steps = np.arange(len(self._tree)) if levels is None else np.asarray(levels)  # a level is a step

        def history(at: np.ndarray) -> np.ndarray:
            return self._tree.node_trajectory(node, at)[1]

        return t, corr.trajectory(traj, steps, history)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._tree, name)


class CorrectedView:
    """A SLAM filter seen through the live back end's latest correction (`GraphCorrection`)."""

    def __init__(self, flt: SlamFilter, live: LiveBackEnd) -> None:
        self._flt = flt
        self._live = live
        self._moved: tuple[int, int, GraphCorrection, tuple[np.ndarray, np.ndarray]] | None = None
        """The last map moved: (particle, the filter's step, the correction, the moved map); the writers
        read the same snapshot one after the other."""

    @property
    def tree(self) -> CorrectedTree:
        return CorrectedTree(self._flt.tree, self._live)

    def map_points(self, particle: int) -> tuple[np.ndarray, np.ndarray]:
        xy, p = self._flt.map_points(particle)
        corr = self._live.correction
        if corr is None:
            return xy, p
        step = getattr(self._flt, "steps", None)
        last = self._moved
        if last is not None and last[0] == particle and last[1] == step and last[2] is corr:
            return last[3]

        def history(at: np.ndarray) -> np.ndarray:
            return self._flt.tree.trajectory(particle, at)[1]

        moved = (corr.points(np.asarray(xy, dtype=float), history).astype(np.asarray(xy).dtype), p)
        self._moved = (particle, step, corr, moved)
        return moved

    def __getattr__(self, name: str) -> Any:
        return getattr(self._flt, name)
