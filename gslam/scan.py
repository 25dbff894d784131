"""A laser scan and the range-bearing measurement model g (eq. meas1) and its inverse."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from gslam.motion import wrap_angle


@dataclass(frozen=True)
class ScanGeometry:
    """Beam k is at bearing start_angle_rad + k * angle_increment_rad in the sensor frame (x ahead)."""

    beam_count: int
    start_angle_rad: float
    angle_increment_rad: float
    max_range_m: float

    @property
    def bearings_rad(self) -> np.ndarray:
        return self.start_angle_rad + self.angle_increment_rad * np.arange(self.beam_count)

    @property
    def end_angle_rad(self) -> float:
        return self.start_angle_rad + (self.beam_count - 1) * self.angle_increment_rad

    def as_dict(self) -> dict[str, float]:
        return {
            "beam_count": self.beam_count,
            "start_angle_rad": self.start_angle_rad,
            "end_angle_rad": self.end_angle_rad,
            "angle_increment_rad": self.angle_increment_rad,
            "max_range_m": self.max_range_m,
        }


@dataclass(frozen=True)
class Scan:
    """One scan: ranges [m] per beam, +inf (or >= max range) where there was no return."""

    t_s: float
    ranges_m: np.ndarray
    geometry: ScanGeometry
    min_range_m: float = 0.0
    """Returns closer than this are the vehicle itself: no observation, but they still occlude."""

    @property
    def returns(self) -> np.ndarray:
        """Mask of beams with a return (an observation of an obstacle)."""
        r = self.ranges_m
        return np.isfinite(r) & (r < self.geometry.max_range_m) & (r > max(self.min_range_m, 0.0))

    @property
    def occlusion_ranges_m(self) -> np.ndarray:
        """Per beam, how far the beam saw: its range where it hit anything (the vehicle included), else
        the maximum range (free space all the way)."""
        r = self.ranges_m
        return np.where(np.isfinite(r) & (r < self.geometry.max_range_m), r, self.geometry.max_range_m)

    def return_polar(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(beam index, range, bearing) of every return."""
        idx = np.flatnonzero(self.returns)
        return idx, self.ranges_m[idx], self.geometry.bearings_rad[idx]


def measure(poses: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """g(s, theta) (eq. meas1): range and bearing of points `xy` seen from sensor poses `poses`.

    poses and xy broadcast: poses (..., 3), xy (..., 2). Bearing is relative to the heading, wrapped.
    """
    dx = xy[..., 0] - poses[..., 0]
    dy = xy[..., 1] - poses[..., 1]
    return np.hypot(dx, dy), wrap_angle(np.arctan2(dy, dx) - poses[..., 2])


def inverse_measure(poses: np.ndarray, range_m: np.ndarray, bearing_rad: np.ndarray) -> np.ndarray:
    """The inverse of g: the point at range and bearing from the pose, (..., 2)."""
    heading = poses[..., 2] + bearing_rad
    return np.stack([poses[..., 0] + range_m * np.cos(heading), poses[..., 1] + range_m * np.sin(heading)], axis=-1)


def window_boxes(
    poses: np.ndarray, ends_sensor: np.ndarray, margin_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(x0, y0, x1, y1), each (N,): the box of each pose and its returns' end points (`ends_sensor` (K, 2) in
    the sensor's frame, placed at each pose), grown by `margin_m`: the window the compiled kernels work in.
    Compiled, one pass per pose (ten N x K array expressions cost ~0.1 ms an update)."""
    poses = np.ascontiguousarray(poses, dtype=float)
    ends = np.ascontiguousarray(ends_sensor, dtype=float).reshape(-1, 2)
    boxes = _window_boxes(poses, np.cos(poses[:, 2]), np.sin(poses[:, 2]), ends, float(margin_m))
    return boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3]


@njit(cache=True, inline="always")
def end_point_box(px, py, c, s, ends):  # pragma: no cover - compiled
    """(x0, y0, x1, y1): the box of the pose (px, py) and its returns' end points `ends` (K, 2, sensor frame)
    placed at it (c, s: the cosine and sine of its heading), the end point x + c ex - s ey, y + s ex + c ey,
    as the array expressions `window_boxes` replaced, in their order, so the same numbers."""
    x0, y0, x1, y1 = np.inf, np.inf, -np.inf, -np.inf
    for j in range(ends.shape[0]):
        x = px + c * ends[j, 0] - s * ends[j, 1]
        y = py + s * ends[j, 0] + c * ends[j, 1]
        x0, y0, x1, y1 = min(x0, x), min(y0, y), max(x1, x), max(y1, y)
    return min(x0, px), min(y0, py), max(x1, px), max(y1, py)


@njit(cache=True)
def _window_boxes(poses, cos_phi, sin_phi, ends, margin_m):  # pragma: no cover - compiled
    """`window_boxes`: each pose's `end_point_box`, grown by the margin."""
    out = np.empty((poses.shape[0], 4))
    for i in range(poses.shape[0]):
        x0, y0, x1, y1 = end_point_box(poses[i, 0], poses[i, 1], cos_phi[i], sin_phi[i], ends)
        out[i, 0], out[i, 1] = x0 - margin_m, y0 - margin_m
        out[i, 2], out[i, 3] = x1 + margin_m, y1 + margin_m
    return out


def transform_points(pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Sensor-frame points (K, 2) to the world frame for one pose (x, y, phi), or for each point its own
    pose (K, 3)."""
    pose = np.asarray(pose)
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    return np.column_stack([pose[..., 0] + c * pts[:, 0] - s * pts[:, 1], pose[..., 1] + s * pts[:, 0] + c * pts[:, 1]])
