"""A trinary occupancy grid (occupied / free / unknown) from a SLAM result, for navigation maps.

Occupied cells come from the final map's points: a cell is occupied when a point in it has an occupancy
probability of at least `occupied_probability`, and so is the cell of a scan's return that lies within
`support_m` of such a point (the point map holds a few points per 0.25 m; the returns cast along the
final trajectory fill the wall in between, only where the map says there is an obstacle). Free cells are
those the beams cross on the way to their returns (beams with no return say nothing of where the free
space ends and are not cast). Occupied wins over free; everything else is unknown. Ray casting is
vectorised over all the samples of a scan's beams (one numpy pass per scan).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

UNKNOWN, FREE, OCCUPIED = -1, 0, 100
"""Cell states, as in a ROS nav_msgs/OccupancyGrid."""

MAX_CELLS = 100_000_000


@dataclass(frozen=True)
class GridSpec:
    """Cells of `resolution_m`; cell (ix, iy) covers [origin + i r, origin + (i + 1) r) on each axis."""

    origin_xy_m: tuple[float, float]
    resolution_m: float
    width: int  # cells along x
    height: int  # cells along y

    @classmethod
    def around(cls, xy: np.ndarray, resolution_m: float, margin_m: float = 1.0) -> GridSpec:
        """The grid covering points `xy` (K, 2) with `margin_m` around them."""
        if not resolution_m > 0:
            raise ValueError(f"grid resolution must be positive, got {resolution_m} m")
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        if len(xy) == 0:
            raise ValueError("no map points and no poses: nothing to make a grid of")
        lo = np.floor((xy.min(axis=0) - margin_m) / resolution_m) * resolution_m
        hi = xy.max(axis=0) + margin_m
        size = np.ceil((hi - lo) / resolution_m).astype(int) + 1
        if size[0] * size[1] > MAX_CELLS:
            raise ValueError(
                f"a {size[0]} x {size[1]} grid at {resolution_m} m is over {MAX_CELLS} cells; use a coarser resolution"
            )
        return cls((float(lo[0]), float(lo[1])), float(resolution_m), int(size[0]), int(size[1]))

    def flat_index(self, xy: np.ndarray) -> np.ndarray:
        """Flat cell index (iy * width + ix) of each point (K, 2); -1 outside the grid."""
        ij = np.floor((xy - np.asarray(self.origin_xy_m)) / self.resolution_m).astype(np.int64)
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < self.width) & (ij[:, 1] >= 0) & (ij[:, 1] < self.height)
        return np.where(inside, ij[:, 1] * self.width + ij[:, 0], -1)


class ScanCaster:
    """Marks the cells the beams of each scan pass through before their return (`free`), and the cells
    of the returns (`hit`)."""

    def __init__(self, spec: GridSpec, sample_step_m: float | None = None) -> None:
        self.spec = spec
        self.free = np.zeros(spec.width * spec.height, dtype=bool)
        self.hit = np.zeros(spec.width * spec.height, dtype=bool)
        self.step = sample_step_m or spec.resolution_m / 2  # two samples per cell: few cells skipped

    def add_scan(self, laser_pose: np.ndarray, ranges_m: np.ndarray, bearings_rad: np.ndarray) -> None:
        """One scan from `laser_pose` (x, y, heading); `ranges_m` with a return only (finite, > 0)."""
        ok = np.isfinite(ranges_m) & (ranges_m > 0)
        r, b = ranges_m[ok], bearings_rad[ok]
        ends = laser_pose[:2] + r[:, None] * np.column_stack([np.cos(laser_pose[2] + b), np.sin(laser_pose[2] + b)])
        idx = self.spec.flat_index(ends)
        self.hit[idx[idx >= 0]] = True
        # Samples from the laser up to half a cell short of the return (the return's own cell is not free).
        counts = np.maximum(np.ceil((r - self.spec.resolution_m / 2) / self.step).astype(np.int64), 0)
        total = int(counts.sum())
        if total == 0:
            return
        beam = np.repeat(np.arange(len(r)), counts)
        first = np.repeat(np.cumsum(counts) - counts, counts)
        d = (np.arange(total) - first) * self.step
        heading = laser_pose[2] + b[beam]
        xy = np.column_stack([laser_pose[0] + d * np.cos(heading), laser_pose[1] + d * np.sin(heading)])
        idx = self.spec.flat_index(xy)
        self.free[idx[idx >= 0]] = True


def occupied_cells(
    spec: GridSpec,
    xy: np.ndarray,
    p: np.ndarray,
    occupied_probability: float,
    hit: np.ndarray | None = None,
    support_m: float = 0.15,
) -> np.ndarray:
    """Boolean (cells,): cells holding a map point with p >= `occupied_probability`, and cells of `hit`
    (returns) within `support_m` of such a point."""
    from scipy.ndimage import binary_dilation

    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    idx = spec.flat_index(xy[np.asarray(p, dtype=float) >= occupied_probability])
    occupied = np.zeros(spec.width * spec.height, dtype=bool)
    occupied[idx[idx >= 0]] = True
    if hit is None or support_m <= 0:
        return occupied
    k = int(np.ceil(support_m / spec.resolution_m))
    dy, dx = np.mgrid[-k : k + 1, -k : k + 1]
    disk = np.hypot(dx, dy) * spec.resolution_m <= support_m
    near = binary_dilation(occupied.reshape(spec.height, spec.width), structure=disk).reshape(-1)
    return occupied | (hit & near)


@dataclass(frozen=True)
class OccupancyGrid:
    spec: GridSpec
    state: np.ndarray  # (height, width) int8: OCCUPIED, FREE or UNKNOWN; row iy, column ix

    @classmethod
    def combine(cls, spec: GridSpec, occupied: np.ndarray, free: np.ndarray) -> OccupancyGrid:
        state = np.full(spec.width * spec.height, UNKNOWN, dtype=np.int8)
        state[free] = FREE
        state[occupied] = OCCUPIED
        return cls(spec, state.reshape(spec.height, spec.width))

    def state_at(self, xy: np.ndarray) -> np.ndarray:
        """The state of the cell under each point (K, 2); UNKNOWN outside the grid."""
        idx = self.spec.flat_index(np.asarray(xy, dtype=float).reshape(-1, 2))
        return np.where(idx >= 0, self.state.reshape(-1)[np.maximum(idx, 0)], UNKNOWN)
