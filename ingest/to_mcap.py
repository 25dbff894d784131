"""Write a `LogData` as an input MCAP (channels of docs/CHANNELS.md), in log-time order."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from gslam import __version__
from gslam.vehicle import vehicle_preset
from mcaplog import channels as ch
from mcaplog.mcapio import AtomicMcapWriter

from .logdata import LogData
from .textlog import monotone_log_times_ns

# Order among equal times: odometry before GPS before the scan, so a scan sees the controls up to it.
_PRIORITY = {"ackermann": 0, "odom": 0, "gps": 1, "scan": 2}


def _event_order(log: LogData) -> tuple[np.ndarray, list[str], np.ndarray]:
    """(log_time_ns, kind per event, index into that kind's arrays), in the order to write."""
    if log.odom_pose is not None and log.odom_source is not None:
        # CARMEN: file order; each FLASER's odometry pose comes just before its scan.
        kinds: list[str] = []
        idx: list[int] = []
        times: list[float] = []
        k = 0
        for i, src in enumerate(log.odom_source):
            kinds.append("odom")
            idx.append(i)
            times.append(log.odom_pose[i, 0])
            if src == "FLASER":
                kinds.append("scan")
                idx.append(k)
                times.append(log.scan_t_s[k])
                k += 1
        t_ns, _ = monotone_log_times_ns(np.asarray(times))
        return t_ns, kinds, np.asarray(idx)
    streams = []
    if log.ackermann is not None:
        streams.append(("ackermann", log.ackermann[:, 0]))
    if log.gps is not None:
        streams.append(("gps", log.gps[:, 0]))
    if log.scan_t_s is not None:
        streams.append(("scan", log.scan_t_s))
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


def metadata_for(log: LogData) -> dict[str, dict]:
    meta: dict[str, dict] = {
        "dataset": {
            "name": log.dataset,
            "source_format": log.source_format,
            "source": log.source,
            "counts": log.counts(),
        },
        "ingest": {
            "gslam_version": __version__,
            "created_unix_s": round(time.time(), 3),
            "warnings": log.warnings,
        },
    }
    if log.motion_model == "ackermann":
        preset = vehicle_preset(log.vehicle_preset or "carpark")
        meta["vehicle"] = {"motion_model": "ackermann", "preset": preset.name, **preset.as_dict()}
    else:
        meta["vehicle"] = {"motion_model": "odometry", "preset": "odometry"}
    if log.geometry is not None:
        meta["sensor"] = {"frame": "laser", **log.geometry.as_dict(), "self_return_range_m": log.self_return_range_m}
    meta.update(log.extra_metadata)
    return meta


def write_log_mcap(log: LogData, out: Path, progress: Callable[[int, int], None] | None = None) -> dict[str, int]:
    """Write `log` to `out` atomically; returns the message count per topic."""
    t_ns, kinds, idx = _event_order(log)
    counts: dict[str, int] = {}
    geom = log.geometry
    writer = AtomicMcapWriter(out)
    try:
        for name, data in metadata_for(log).items():
            writer.add_metadata(name, data)
        first_ns = int(t_ns[0]) if len(t_ns) else 0
        if log.landmarks is not None:
            writer.write_json(
                ch.LANDMARKS_TRUTH,
                "gslam.Landmarks",
                ch.LANDMARKS_SCHEMA,
                {
                    "x_m": log.landmarks[:, 0].tolist(),
                    "y_m": log.landmarks[:, 1].tolist(),
                    "kind": "pole",
                },
                first_ns,
            )
            counts[ch.LANDMARKS_TRUTH] = 1
        if log.relations is not None:
            r = log.relations
            writer.write_json(
                ch.RELATIONS_TRUTH,
                "gslam.Relations",
                ch.RELATIONS_SCHEMA,
                {
                    "t1_s": r[:, 0].tolist(),
                    "t2_s": r[:, 1].tolist(),
                    "dx_m": r[:, 2].tolist(),
                    "dy_m": r[:, 3].tolist(),
                    "dyaw_rad": r[:, 4].tolist(),
                },
                first_ns,
            )
            counts[ch.RELATIONS_TRUTH] = 1
        total = len(kinds)
        for n, (ns, kind, i) in enumerate(zip(t_ns.tolist(), kinds, idx.tolist(), strict=True)):
            if kind == "scan":
                inten = None if log.scan_intensities is None else log.scan_intensities[i]
                msg = ch.laser_scan(
                    float(log.scan_t_s[i]), log.scan_ranges_m[i], geom.start_angle_rad, geom.end_angle_rad, inten
                )
                writer.write_proto(ch.LASER, msg, ns)
                topic = ch.LASER
            elif kind == "ackermann":
                t, v, s = log.ackermann[i].tolist()
                writer.write_json(
                    ch.ODOM_ACKERMANN,
                    "gslam.AckermannOdometry",
                    ch.ACKERMANN_SCHEMA,
                    {"t_s": t, "speed_mps": v, "steering_rad": s},
                    ns,
                )
                topic = ch.ODOM_ACKERMANN
            elif kind == "odom":
                t, x, y, th, tv, rv = log.odom_pose[i].tolist()
                obj = {
                    "t_s": t,
                    "x_m": x,
                    "y_m": y,
                    "theta_rad": th,
                    "tv_mps": None if np.isnan(tv) else tv,
                    "rv_radps": None if np.isnan(rv) else rv,
                    "source": log.odom_source[i] if log.odom_source else "ODOM",
                }
                writer.write_json(ch.ODOM_POSE, "gslam.OdometryPose", ch.ODOM_POSE_SCHEMA, obj, ns)
                topic = ch.ODOM_POSE
            else:  # gps
                t, x, y = log.gps[i].tolist()
                writer.write_proto(ch.GPS, ch.pose_in_frame(t, x, y, 0.0, "gps"), ns)
                topic = ch.GPS
            counts[topic] = counts.get(topic, 0) + 1
            if progress is not None and (n % 2000 == 0 or n == total - 1):
                progress(n + 1, total)
        if log.truth_pose is not None:
            tp = log.truth_pose
            tns, _ = monotone_log_times_ns(tp[:, 0])
            # Written after the stream: MCAP indexes keep log-time order for readers.
            for ns, row in zip(tns.tolist(), tp.tolist(), strict=True):
                writer.write_proto(ch.TRAJECTORY_TRUTH, ch.pose_in_frame(row[0], row[1], row[2], row[3], "gps"), ns)
            counts[ch.TRAJECTORY_TRUTH] = len(tp)
        writer.finish()
    except BaseException:
        writer.abort()
        raise
    return counts
