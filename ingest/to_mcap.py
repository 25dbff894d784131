"""Write a `LogStream` (any reader's records) as an input MCAP with the channels of docs/CHANNELS.md."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gslam import __version__
from mcaplog import channels as ch
from mcaplog.mcapio import AtomicMcapWriter

from .base import (
    AckermannRecord,
    GpsRecord,
    LandmarksRecord,
    LogStream,
    OdomRecord,
    Record,
    RelationsRecord,
    ScanRecord,
    TruthPoseRecord,
)
from .textlog import IngestError


def _none_if_nan(v: float) -> float | None:
    return None if math.isnan(v) else v


def _write(writer: AtomicMcapWriter, ns: int, rec: Record) -> tuple[str, ...]:
    """Write one record; returns the topics written."""
    if isinstance(rec, ScanRecord):
        msg = ch.laser_scan(rec.t_s, rec.ranges_m, rec.start_angle_rad, rec.end_angle_rad, rec.intensities)
        writer.write_proto(ch.LASER, msg, ns)
        return (ch.LASER,)
    if isinstance(rec, OdomRecord):
        obj = {
            "t_s": rec.t_s,
            "x_m": rec.x_m,
            "y_m": rec.y_m,
            "theta_rad": rec.theta_rad,
            "tv_mps": _none_if_nan(rec.tv_mps),
            "rv_radps": _none_if_nan(rec.rv_radps),
            "source": rec.source,
        }
        writer.write_json(ch.ODOM_POSE, "gslam.OdometryPose", ch.ODOM_POSE_SCHEMA, obj, ns)
        # The same pose for Foxglove and Rerun (the filter reads the JSON, which has the velocities too).
        writer.write_proto(ch.ODOM, ch.pose_in_frame(rec.t_s, rec.x_m, rec.y_m, rec.theta_rad, ch.ODOM_FRAME), ns)
        return ch.ODOM_POSE, ch.ODOM
    if isinstance(rec, AckermannRecord):
        obj = {"t_s": rec.t_s, "speed_mps": rec.speed_mps, "steering_rad": rec.steering_rad}
        writer.write_json(ch.ODOM_ACKERMANN, "gslam.AckermannOdometry", ch.ACKERMANN_SCHEMA, obj, ns)
        return (ch.ODOM_ACKERMANN,)
    if isinstance(rec, GpsRecord):
        writer.write_proto(ch.GPS, ch.pose_in_frame(rec.t_s, rec.x_m, rec.y_m, 0.0, "gps"), ns)
        return (ch.GPS,)
    if isinstance(rec, TruthPoseRecord):
        msg = ch.pose_in_frame(rec.t_s, rec.x_m, rec.y_m, rec.theta_rad, "gps")
        writer.write_proto(ch.TRAJECTORY_TRUTH, msg, ns)
        return (ch.TRAJECTORY_TRUTH,)
    if isinstance(rec, LandmarksRecord):
        obj = {"x_m": rec.xy_m[:, 0].tolist(), "y_m": rec.xy_m[:, 1].tolist(), "kind": "pole"}
        writer.write_json(ch.LANDMARKS_TRUTH, "gslam.Landmarks", ch.LANDMARKS_SCHEMA, obj, ns)
        return (ch.LANDMARKS_TRUTH,)
    if isinstance(rec, RelationsRecord):
        r = rec.rows
        obj = {
            "t1_s": r[:, 0].tolist(),
            "t2_s": r[:, 1].tolist(),
            "dx_m": r[:, 2].tolist(),
            "dy_m": r[:, 3].tolist(),
            "dyaw_rad": r[:, 4].tolist(),
        }
        writer.write_json(ch.RELATIONS_TRUTH, "gslam.Relations", ch.RELATIONS_SCHEMA, obj, ns)
        return (ch.RELATIONS_TRUTH,)
    raise TypeError(f"unknown record {type(rec).__name__}")


def write_log_mcap(
    log: LogStream,
    out: Path,
    progress: Callable[[int, int], None] | None = None,
    source: Path | None = None,
    dataset_extra: dict[str, Any] | None = None,
) -> dict[str, int]:
    """Stream `log` into `out` atomically (nothing is left at `out` on an error or interruption);
    returns the message count per topic. A log with no record at all is refused (IngestError naming
    `source`): an MCAP of nothing is no log. `dataset_extra`: more fields for the `dataset` metadata (what
    `gslam process` records of a log it ingests on the way)."""
    counts: dict[str, int] = {}
    writer = AtomicMcapWriter(out)
    try:
        n = 0
        for n, (ns, rec) in enumerate(log.records(), start=1):
            for topic in _write(writer, ns, rec):
                counts[topic] = counts.get(topic, 0) + 1
            if progress is not None and n % 2000 == 0:
                progress(n, max(log.expected_records or 0, n))
        if progress is not None:
            progress(n, n)
        if not counts:  # an MCAP with no message is no log: say so rather than write one
            raise IngestError(f"{source or log.dataset}: holds no scan, odometry or GPS record; nothing to ingest")
        meta = log.metadata()
        meta["dataset"].update(dataset_extra or {})
        meta["dataset"]["written"] = counts
        meta["ingest"] = {
            "gslam_version": __version__,
            "created_unix_s": round(time.time(), 3),
            "warnings": log.warnings,
        }
        for name, data in meta.items():
            writer.add_metadata(name, data)
        writer.finish()
    except BaseException:
        writer.abort()
        raise
    return counts
