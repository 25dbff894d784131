"""Read an input MCAP (from `gslam ingest`) as a stream of typed events in log-time order."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gslam.scan import ScanGeometry
from mcaplog import channels as ch
from mcaplog.mcapio import McapInput

from .errors import InputError
from .mount import LaserMount


@dataclass
class ScanEvent:
    index: int
    t_s: float  # log time (monotone)
    stamp_s: float  # the sensor's own time stamp (may go backwards in some logs)
    ranges_m: np.ndarray
    intensities: np.ndarray | None


@dataclass
class ControlEvent:
    t_s: float
    speed_mps: float
    steering_rad: float


@dataclass
class OdomEvent:
    t_s: float
    pose: np.ndarray  # x, y, theta


@dataclass
class GpsEvent:
    t_s: float
    xy: np.ndarray


Event = ScanEvent | ControlEvent | OdomEvent | GpsEvent
INPUT_TOPICS = [ch.LASER, ch.ODOM_ACKERMANN, ch.ODOM_POSE, ch.GPS]


class InputLog:
    """An input MCAP: its metadata, sensor geometry, motion model, and its event stream."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.mcap = McapInput(self.path)
        try:
            self.meta: dict[str, Any] = self.mcap.metadata()
            summary = self.mcap.summary()
        except Exception as e:
            raise InputError(f"{self.path}: not a readable MCAP file ({type(e).__name__}: {e})") from None
        if "sensor" not in self.meta or "vehicle" not in self.meta:
            raise InputError(f"{self.path}: no 'sensor'/'vehicle' metadata; is this an MCAP from `gslam ingest`?")
        s = self.meta["sensor"]
        self.geometry = ScanGeometry(
            int(s["beam_count"]), float(s["start_angle_rad"]), float(s["angle_increment_rad"]), float(s["max_range_m"])
        )
        self.motion_model = self.meta["vehicle"].get("motion_model", "ackermann")
        self.self_return_range_m = float(s.get("self_return_range_m", 0.0))
        try:
            # Only odometry logs carry a mount (ROS bags); for the rest base and laser are one frame.
            self.mount = LaserMount.from_sensor(s) if self.motion_model == "odometry" else None
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{self.path}: the 'sensor' metadata has a malformed mount ({e})") from None
        counts = {}
        if summary is not None and summary.statistics is not None:
            for cid, channel in summary.channels.items():
                counts[channel.topic] = summary.statistics.channel_message_counts.get(cid, 0)
        self.counts = counts
        if counts.get(ch.LASER, 0) == 0:
            raise InputError(f"{self.path}: no {ch.LASER} messages; SLAM needs laser scans")
        self.scan_count = counts[ch.LASER]
        self.start_s = summary.statistics.message_start_time / 1e9
        self.end_s = summary.statistics.message_end_time / 1e9

    def events(self) -> Iterator[Event]:
        """All input events in log-time order. Malformed messages raise InputError naming their index."""
        k = 0
        for n, msg in enumerate(self.mcap.messages(INPUT_TOPICS)):
            try:
                if msg.topic == ch.LASER:
                    v = msg.value
                    ranges = np.asarray(v.ranges, dtype=float)
                    if len(ranges) != self.geometry.beam_count:
                        raise ValueError(f"{len(ranges)} ranges, expected {self.geometry.beam_count}")
                    inten = np.asarray(v.intensities, dtype=float) if len(v.intensities) else None
                    yield ScanEvent(k, msg.t_s, ch.t_of(v.timestamp), ranges, inten)
                    k += 1
                elif msg.topic == ch.ODOM_ACKERMANN:
                    yield ControlEvent(msg.t_s, float(msg.value["speed_mps"]), float(msg.value["steering_rad"]))
                elif msg.topic == ch.ODOM_POSE:
                    v = msg.value
                    yield OdomEvent(msg.t_s, np.array([v["x_m"], v["y_m"], v["theta_rad"]], dtype=float))
                else:
                    yield GpsEvent(msg.t_s, np.array([msg.value.pose.position.x, msg.value.pose.position.y]))
            except (KeyError, TypeError, ValueError) as e:
                raise InputError(f"{self.path}: message {n} on {msg.topic} is malformed ({e})") from None

    def read_all(self, topic: str) -> list:
        return list(self.mcap.messages([topic]))

    def gps_array(self) -> np.ndarray | None:
        msgs = self.read_all(ch.GPS)
        if not msgs:
            return None
        return np.array([[m.t_s, m.value.pose.position.x, m.value.pose.position.y] for m in msgs])

    def head_controls_and_gps(self, seconds: float) -> tuple[np.ndarray, np.ndarray]:
        """Ackermann controls and GPS fixes of the first `seconds` of the log (for initialisation)."""
        controls, gps = [], []
        for msg in self.mcap.messages([ch.ODOM_ACKERMANN, ch.GPS]):
            if msg.t_s > self.start_s + seconds:
                break
            if msg.topic == ch.GPS:
                gps.append([msg.t_s, msg.value.pose.position.x, msg.value.pose.position.y])
            else:
                controls.append([msg.t_s, msg.value["speed_mps"], msg.value["steering_rad"]])
        return np.array(controls).reshape(-1, 3), np.array(gps).reshape(-1, 3)
