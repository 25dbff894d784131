"""Odometry whose pose contradicts its own velocity: the increments of a robot backing up, reported forward.

Some drivers integrate the wheel speed's magnitude into the pose, so that when the robot backs up the
pose moves forward while the reported translational velocity is negative (Freiburg building 079: 400 of
its 8 951 ODOM lines). A scan matcher cannot undo that: the error is twice the distance reversed, at
every reversal. Where a log reports both, the two are compared at every odometry sample: an increment
whose forward component has the opposite sign of the velocity reported with it (both clearly non-zero)
has its translation turned around. Odometry without velocities, or whose velocities agree with its
increments, passes through unchanged (the very same poses).
"""

from __future__ import annotations

import math

import numpy as np

from gslam.motion import wrap_angle
from gslam.se2 import compose, inverse

MIN_SPEED_MPS = 0.02
"""A velocity below this says nothing of the direction (a robot starting or stopping)."""
MIN_STEP_M = 1e-4
"""An increment shorter than this says nothing of the direction either."""


class ReversalCheck:
    """Feeds odometry samples (pose, reported translational velocity) and gives the poses to use."""

    def __init__(self) -> None:
        self._raw: np.ndarray | None = None
        self._clean: np.ndarray | None = None
        self._tv: float | None = None
        self.turned = 0
        """Increments whose translation was turned around."""
        self._corrected = False  # once one increment is turned, poses are the integrated clean ones

    def update(self, pose: np.ndarray, tv_mps: float | None) -> np.ndarray:
        """The pose to use for the sample `pose` (the raw odometry) with its velocity `tv_mps` (None: not
        logged with it; the last velocity logged is used)."""
        if tv_mps is not None and math.isfinite(tv_mps):
            self._tv = float(tv_mps)
        if self._raw is None or (self._tv is None and not self._corrected):
            self._raw, self._clean = pose, pose  # nothing to compare with (yet)
            return pose
        x0, y0, th0 = self._raw
        x1, y1 = float(pose[0]), float(pose[1])
        self._raw = pose
        forward = math.cos(th0) * (x1 - x0) + math.sin(th0) * (y1 - y0)  # scalars: this runs for every sample
        contradicts = (
            self._tv is not None
            and abs(self._tv) >= MIN_SPEED_MPS
            and abs(forward) >= MIN_STEP_M
            and (forward > 0) != (self._tv > 0)
        )
        if not contradicts and not self._corrected:
            self._clean = pose
            return pose
        step = compose(inverse(np.array([x0, y0, th0], dtype=float)), np.asarray(pose, dtype=float))
        if contradicts:
            step = np.array([-step[0], -step[1], step[2]])
            self.turned += 1
            self._corrected = True
        clean = compose(self._clean, step)
        clean[2] = wrap_angle(clean[2])
        self._clean = clean
        return clean
