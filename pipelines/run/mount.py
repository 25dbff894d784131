"""The laser's mount on the robot's base, from the input's sensor metadata, and the conversions between
the base's pose and the laser's pose (pose composition).

The filter works on laser poses (its scans are in the laser frame). Where the input records a mount (ROS
bags: base frame -> laser frame from /tf_static), the runner moves the particles with the odometry in
the base frame and the outputs report the base's pose; elsewhere (Sydney, CARMEN) base and laser are
the same frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from gslam.ancestry import AncestryTree
from gslam.filter import SlamFilter
from gslam.se2 import compose, inverse


@dataclass(frozen=True)
class LaserMount:
    """The laser's pose in the base frame: x ahead, y left [m], yaw counter-clockwise [rad]."""

    x_m: float
    y_m: float
    yaw_rad: float
    base_frame: str = "base"

    @classmethod
    def from_sensor(cls, sensor: dict[str, Any]) -> LaserMount | None:
        """The mount in `sensor` metadata; None when there is none or it is the identity."""
        m = sensor.get("mount")
        if not m:
            return None
        mount = cls(float(m["x_m"]), float(m["y_m"]), float(m["yaw_rad"]), str(m.get("base_frame", "base")))
        return None if mount.x_m == mount.y_m == mount.yaw_rad == 0.0 else mount

    @property
    def pose(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m, self.yaw_rad])

    def laser_of(self, base_poses: np.ndarray) -> np.ndarray:
        """Laser poses (..., 3) of base poses (..., 3)."""
        return compose(base_poses, self.pose)

    def base_of(self, laser_poses: np.ndarray) -> np.ndarray:
        """Base poses (..., 3) of laser poses (..., 3)."""
        return compose(laser_poses, inverse(self.pose))


def laser_poses(mount: LaserMount | None, base_poses: np.ndarray) -> np.ndarray:
    """Laser poses (..., 3) of base poses: the same where the input records no mount."""
    return np.asarray(base_poses, dtype=float) if mount is None else mount.laser_of(base_poses)


def base_poses(mount: LaserMount | None, laser_poses: np.ndarray) -> np.ndarray:
    """Base poses (..., 3) of laser poses: the same where the input records no mount."""
    return np.asarray(laser_poses, dtype=float) if mount is None else mount.base_of(laser_poses)


class BaseFrameTree:
    """A filter's ancestry tree whose trajectories are the base's poses."""

    def __init__(self, tree: AncestryTree, mount: LaserMount) -> None:
        self._tree = tree
        self._mount = mount

    def __len__(self) -> int:
        return len(self._tree)

    def trajectory(self, particle: int, levels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        t, traj = self._tree.trajectory(particle, levels)
        return t, self._mount.base_of(traj)

    def node_trajectory(self, node: int, levels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        t, traj = self._tree.node_trajectory(node, levels)
        return t, self._mount.base_of(traj)


class BaseFrameView:
    """A SLAM filter seen from the robot's base: `best_trajectory()` and `tree.trajectory()` give base
    poses; everything else (maps, landmarks, grids, which are in the world frame) passes through."""

    def __init__(self, flt: SlamFilter, mount: LaserMount) -> None:
        self._flt = flt
        self._mount = mount

    @property
    def tree(self) -> BaseFrameTree:
        return BaseFrameTree(self._flt.tree, self._mount)

    def best_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        t, traj = self._flt.best_trajectory()
        return t, self._mount.base_of(traj)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._flt, name)
