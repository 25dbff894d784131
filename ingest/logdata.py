"""`LogData`: one log in memory, in SI units, between a reader and the MCAP writer."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gslam.scan import ScanGeometry

__all__ = ["LogData", "ScanGeometry"]


@dataclass
class LogData:
    """A log's streams. Times are seconds on the dataset's clock, in file order."""

    dataset: str
    source_format: str
    source: str
    motion_model: str  # "ackermann" (speed + steering) or "odometry" (integrated odometry poses)
    vehicle_preset: str | None = None
    geometry: ScanGeometry | None = None
    self_return_range_m: float = 0.0  # returns this close are the vehicle itself (Sydney car: 1.0 m)
    scan_t_s: np.ndarray | None = None
    scan_ranges_m: np.ndarray | None = None  # (K, B), +inf where there is no return
    scan_intensities: np.ndarray | None = None  # (K, B) or None
    ackermann: np.ndarray | None = None  # (K, 3): t_s, speed_mps, steering_rad
    odom_pose: np.ndarray | None = None  # (K, 6): t_s, x_m, y_m, theta_rad, tv_mps, rv_radps (NaN unknown)
    odom_source: list[str] | None = None  # per odom_pose row: "ODOM" or "FLASER"
    gps: np.ndarray | None = None  # (K, 3): t_s, x_east_m, y_north_m
    landmarks: np.ndarray | None = None  # (P, 2) surveyed pole centres [m]
    relations: np.ndarray | None = None  # (R, 5): t1_s, t2_s, dx_m, dy_m, dyaw_rad
    truth_pose: np.ndarray | None = None  # (K, 4): t_s, x, y, theta (simulated logs)
    warnings: list[str] = field(default_factory=list)
    extra_metadata: dict[str, dict] = field(default_factory=dict)

    def counts(self) -> dict[str, int]:
        def n(a):
            return 0 if a is None else len(a)

        return {
            "scans": n(self.scan_t_s),
            "ackermann": n(self.ackermann),
            "odom_pose": n(self.odom_pose),
            "gps": n(self.gps),
            "landmarks": n(self.landmarks),
            "relations": n(self.relations),
        }
