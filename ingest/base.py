"""The reader plug-in interface: `LogReader` (claims an input, opens it), `ReadOptions`, and what an
opened log hands the MCAP writer, a `LogStream` of typed records with their log times.

Each input format is one module with one `LogReader` (ingest.sydney, ingest.carmen, ingest.rosbag),
listed in `ingest.READERS`; `gslam ingest` asks each in turn whether it claims the input (as kiss-icp
picks a dataset plug-in). A stream yields `(log_time_ns, record)` pairs in the order to write them; the
writer turns each record into one message of docs/CHANNELS.md. Records carry SI units and the sensor's
own time stamp `t_s`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np


@dataclass(frozen=True)
class ScanRecord:
    t_s: float
    ranges_m: np.ndarray  # (B,), +inf where there is no return
    start_angle_rad: float  # bearing of the first beam in the laser frame (x ahead, counter-clockwise)
    end_angle_rad: float  # bearing of the last beam
    intensities: np.ndarray | None = None


@dataclass(frozen=True)
class OdomRecord:
    """Integrated odometry pose (odometry frame) with velocities where known (NaN: unknown)."""

    t_s: float
    x_m: float
    y_m: float
    theta_rad: float
    tv_mps: float = float("nan")
    rv_radps: float = float("nan")
    source: str = "ODOM"


@dataclass(frozen=True)
class AckermannRecord:
    t_s: float
    speed_mps: float
    steering_rad: float


@dataclass(frozen=True)
class GpsRecord:
    t_s: float
    x_m: float
    y_m: float


@dataclass(frozen=True)
class TruthPoseRecord:
    t_s: float
    x_m: float
    y_m: float
    theta_rad: float


@dataclass(frozen=True)
class LandmarksRecord:
    xy_m: np.ndarray  # (P, 2)


@dataclass(frozen=True)
class RelationsRecord:
    rows: np.ndarray  # (R, 5): t1_s, t2_s, dx_m, dy_m, dyaw_rad


Record = ScanRecord | OdomRecord | AckermannRecord | GpsRecord | TruthPoseRecord | LandmarksRecord | RelationsRecord


class LogStream(Protocol):
    """One opened input log, whatever its format."""

    dataset: str
    source_format: str
    warnings: list[str]
    expected_records: int | None  # for progress reports; None when unknown before streaming

    def records(self) -> Iterator[tuple[int, Record]]:
        """(log_time_ns, record) in writing order. Bad input raises `IngestError` naming where."""
        ...

    def metadata(self) -> dict[str, dict[str, Any]]:
        """MCAP metadata records (`dataset`, `vehicle`, `sensor`, ...); called after `records()` is
        exhausted, so it may report what streaming found."""
        ...


@dataclass(frozen=True)
class ReadOptions:
    """What `gslam ingest` passes to a reader (None: the reader decides)."""

    dataset: str | None = None
    """Dataset name stored in the metadata (default: from the path)."""
    skip_bad_lines: bool = False
    """Text logs: drop malformed lines and report how many, instead of failing on the first."""
    scan_topic: str | None = None
    """ROS bags: the sensor_msgs/msg/LaserScan topic (default: the only one)."""
    odom_topic: str | None = None
    """ROS bags: the nav_msgs/msg/Odometry topic (default: the only one, else odom -> base in /tf)."""
    base_frame: str | None = None
    """ROS bags: the robot's base frame (default: the odometry's child frame, or the child of `odom` in /tf)."""

    BAG_OPTIONS = ("scan_topic", "odom_topic", "base_frame")


class LogReader(Protocol):
    """One input format: says whether it claims an input, and opens it as a `LogStream`."""

    formats: tuple[str, ...]
    """The --format names it answers to."""

    def detect(self, source: Path) -> str | None:
        """The format name if this reader claims `source` (a file or directory that exists), else None."""
        ...

    def open(self, source: Path, fmt: str, options: ReadOptions) -> LogStream:
        """Open `source` (raises `IngestError` with one clear line for bad input)."""
        ...
