"""`LogData`: one log held in memory, in SI units, and its records in writing order (a `LogStream`).

The Sydney and CARMEN readers parse their (small) logs into a `LogData`; ROS bags stream instead
(`ingest.rosbag`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gslam.scan import ScanGeometry
from gslam.vehicle import vehicle_preset

from .base import (
    AckermannRecord,
    GpsRecord,
    LandmarksRecord,
    OdomRecord,
    Record,
    RelationsRecord,
    ScanRecord,
    TruthPoseRecord,
)
from .textlog import monotone_log_times_ns

__all__ = ["LogData", "ScanGeometry"]

# Order among equal times: odometry before GPS before the scan, so a scan sees the controls up to it.
_PRIORITY = {"ackermann": 0, "odom": 0, "gps": 1, "scan": 2}


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

    # -- LogStream ---------------------------------------------------------------------------------
    @property
    def expected_records(self) -> int:
        return sum(self.counts().values()) + (0 if self.truth_pose is None else len(self.truth_pose))

    def metadata(self) -> dict[str, dict[str, Any]]:
        meta: dict[str, dict[str, Any]] = {
            "dataset": {
                "name": self.dataset,
                "source_format": self.source_format,
                "source": self.source,
                "counts": self.counts(),
            }
        }
        if self.motion_model == "ackermann":
            preset = vehicle_preset(self.vehicle_preset or "carpark")
            meta["vehicle"] = {"motion_model": "ackermann", "preset": preset.name, **preset.as_dict()}
        else:
            meta["vehicle"] = {"motion_model": "odometry", "preset": "odometry"}
        if self.geometry is not None:
            meta["sensor"] = {
                "frame": "laser",
                **self.geometry.as_dict(),
                "self_return_range_m": self.self_return_range_m,
            }
        meta.update(self.extra_metadata)
        return meta

    def records(self) -> Iterator[tuple[int, Record]]:
        t_ns, kinds, idx = self._event_order()
        first_ns = int(t_ns[0]) if len(t_ns) else 0
        if self.landmarks is not None:
            yield first_ns, LandmarksRecord(self.landmarks)
        if self.relations is not None:
            yield first_ns, RelationsRecord(self.relations)
        for ns, kind, i in zip(t_ns.tolist(), kinds, idx.tolist(), strict=True):
            yield ns, self._record(kind, i)
        if self.truth_pose is not None:
            # Written after the stream: MCAP indexes keep log-time order for readers.
            tns, _ = monotone_log_times_ns(self.truth_pose[:, 0])
            for ns, row in zip(tns.tolist(), self.truth_pose.tolist(), strict=True):
                yield ns, TruthPoseRecord(*row)

    def _record(self, kind: str, i: int) -> Record:
        if kind == "scan":
            inten = None if self.scan_intensities is None else self.scan_intensities[i]
            g = self.geometry
            return ScanRecord(float(self.scan_t_s[i]), self.scan_ranges_m[i], g.start_angle_rad, g.end_angle_rad, inten)
        if kind == "ackermann":
            return AckermannRecord(*self.ackermann[i].tolist())
        if kind == "odom":
            source = self.odom_source[i] if self.odom_source else "ODOM"
            return OdomRecord(*self.odom_pose[i].tolist(), source=source)
        return GpsRecord(*self.gps[i].tolist())

    def _event_order(self) -> tuple[np.ndarray, list[str], np.ndarray]:
        """(log_time_ns, kind per event, index into that kind's arrays), in the order to write."""
        if self.odom_pose is not None and self.odom_source is not None:
            # CARMEN: file order; each FLASER's odometry pose comes just before its scan.
            kinds: list[str] = []
            idx: list[int] = []
            times: list[float] = []
            k = 0
            for i, src in enumerate(self.odom_source):
                kinds.append("odom")
                idx.append(i)
                times.append(self.odom_pose[i, 0])
                if src == "FLASER":
                    kinds.append("scan")
                    idx.append(k)
                    times.append(self.scan_t_s[k])
                    k += 1
            t_ns, _ = monotone_log_times_ns(np.asarray(times))
            return t_ns, kinds, np.asarray(idx)
        streams = []
        if self.ackermann is not None:
            streams.append(("ackermann", self.ackermann[:, 0]))
        if self.gps is not None:
            streams.append(("gps", self.gps[:, 0]))
        if self.scan_t_s is not None:
            streams.append(("scan", self.scan_t_s))
        all_t, all_prio, all_kind, all_idx = [], [], [], []
        for kind, t in streams:
            t_ns, _ = monotone_log_times_ns(t)
            all_t.append(t_ns)
            all_prio.append(np.full(len(t), _PRIORITY[kind]))
            all_kind.extend([kind] * len(t))
            all_idx.append(np.arange(len(t)))
        t_ns = np.concatenate(all_t)
        prio = np.concatenate(all_prio)
        idx = np.concatenate(all_idx)
        order = np.lexsort((idx, prio, t_ns))
        # Re-apply monotonicity so that ties between streams keep the order chosen above.
        ordered_ns = t_ns[order]
        i = np.arange(len(ordered_ns), dtype=np.int64)
        ordered_ns = np.maximum.accumulate(ordered_ns - i) + i
        return ordered_ns, [all_kind[j] for j in order], idx[order]
