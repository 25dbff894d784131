"""Read an input MCAP (from `gslam ingest`) as a stream of typed events in log-time order."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from gslam.scan import ScanGeometry
from gslam.vehicle import AckermannVehicle, vehicle_preset
from mcaplog import channels as ch
from mcaplog.mcapio import McapInput, Message, read_error
from pipelines.errors import InputError
from pipelines.run.mount import LaserMount


@dataclass
class ScanEvent:
    index: int
    t_s: float  # log time (monotone)
    stamp_s: float  # the sensor's own time stamp (may go backwards in some logs)
    ranges_m: np.ndarray
    intensities: np.ndarray | None
    geometry: ScanGeometry | None = None
    """The scan's own beam geometry: the log's (`InputLog.geometry`, the same object) unless the message
    says otherwise (lasers that interleave scan geometries)."""


@dataclass
class ControlEvent:
    t_s: float
    speed_mps: float
    steering_rad: float


@dataclass
class OdomEvent:
    t_s: float
    pose: np.ndarray  # x, y, theta
    tv_mps: float | None = None
    """The translational velocity logged with the pose, where the log has one."""


@dataclass
class GpsEvent:
    t_s: float
    xy: np.ndarray


Event = ScanEvent | ControlEvent | OdomEvent | GpsEvent
INPUT_TOPICS = [ch.LASER, ch.ODOM_ACKERMANN, ch.ODOM_POSE, ch.GPS]
GEOMETRY_TOLERANCE_RAD = 1e-6
"""A scan whose first and last beam angles lie this close to the log's has the log's geometry."""


class InputLog:
    """An input MCAP: its metadata, sensor geometry, motion model, and its event stream."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.mcap = McapInput(self.path)
        try:
            self.meta: dict[str, Any] = self.mcap.metadata()
            summary = self.mcap.summary()
        except Exception as e:
            raise InputError(f"{self.path}: not a readable MCAP file ({read_error(e)})") from None
        if "result" in self.meta:
            raise InputError(
                f"{self.path}: a result of `gslam process`, not an input; give the MCAP from `gslam ingest`"
            )
        if "vehicle" not in self.meta or "dataset" not in self.meta:
            raise InputError(f"{self.path}: no 'dataset'/'vehicle' metadata; is this an MCAP from `gslam ingest`?")
        if "sensor" not in self.meta:
            dataset = self.meta["dataset"]
            name = dataset.get("name", "this log") if isinstance(dataset, dict) else "this log"
            raise InputError(
                f"{self.path}: {name} has no laser (no 'sensor' metadata, no {ch.LASER} messages); "
                f"SLAM needs laser scans"
            )
        try:
            s = self.meta["sensor"]
            self.geometry = ScanGeometry(
                int(s["beam_count"]),
                *_finite(s["start_angle_rad"], s["angle_increment_rad"], s["max_range_m"]),
            )
            self.motion_model = self.meta["vehicle"].get("motion_model", "ackermann")
            self.self_return_range_m = _finite(s.get("self_return_range_m", 0.0))[0]
            # Only odometry logs carry a mount (ROS bags); for the rest base and laser are one frame.
            self.mount = LaserMount.from_sensor(s) if self.motion_model == "odometry" else None
        except (AttributeError, KeyError, TypeError, ValueError) as e:
            raise InputError(f"{self.path}: 'sensor'/'vehicle' metadata malformed ({type(e).__name__}: {e})") from None
        g = self.geometry
        if not (1 <= g.beam_count <= 100_000 and g.angle_increment_rad > 0 and g.max_range_m > 0):
            raise InputError(f"{self.path}: 'sensor' metadata out of range ({g})")
        if self.motion_model not in ("ackermann", "odometry"):
            raise InputError(f"{self.path}: unknown motion model {self.motion_model!r} in the 'vehicle' metadata")
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

    def scan_geometry(self, scan: Any, beams: int) -> ScanGeometry:
        """The geometry of a /laser/scan message with `beams` ranges: the log's when the message agrees
        with it, else the message's own (its start and end angles, the log's maximum range). ValueError
        for a message whose angles cannot place its beams."""
        g = self.geometry
        start, end = float(scan.start_angle), float(scan.end_angle)
        if beams == g.beam_count and (
            (start == 0.0 and end == 0.0)  # no angles in the message: the metadata's
            or (
                abs(start - g.start_angle_rad) <= GEOMETRY_TOLERANCE_RAD
                and abs(end - g.end_angle_rad) <= GEOMETRY_TOLERANCE_RAD
            )
        ):
            return g
        if beams < 2 or not (math.isfinite(start) and math.isfinite(end) and end > start):
            raise ValueError(
                f"{beams} ranges from {start} to {end} rad: cannot place the beams (the log has {g.beam_count})"
            )
        return ScanGeometry(beams, start, (end - start) / (beams - 1), g.max_range_m)

    def _event(self, msg: Message) -> Event:
        v = msg.value
        if msg.topic == ch.LASER:
            ranges = np.asarray(v.ranges, dtype=float)
            geometry = self.scan_geometry(v, len(ranges))
            if not (ranges >= 0).all():  # NaN compares false: one pass finds NaN and negatives
                raise ValueError("ranges must be non-negative numbers (+inf: no return)")
            inten = np.asarray(v.intensities, dtype=float) if len(v.intensities) == len(ranges) else None
            return ScanEvent(-1, msg.t_s, ch.t_of(v.timestamp), ranges, inten, geometry)
        if msg.topic == ch.ODOM_ACKERMANN:
            return ControlEvent(msg.t_s, *_finite(v["speed_mps"], v["steering_rad"]))
        if msg.topic == ch.ODOM_POSE:
            tv = v.get("tv_mps")
            tv = None if tv is None else _finite(tv)[0]
            return OdomEvent(msg.t_s, np.array(_finite(v["x_m"], v["y_m"], v["theta_rad"])), tv)
        return GpsEvent(msg.t_s, np.array(_finite(v.pose.position.x, v.pose.position.y)))

    def events(self, scans_only: bool = False) -> Iterator[Event]:
        """All input events in log-time order (only the scans: `scans_only`), each scan numbered in the
        log's order. Malformed messages raise InputError naming their index."""
        k = 0
        for ev in converted(self.mcap, [ch.LASER] if scans_only else INPUT_TOPICS, self._event):
            if isinstance(ev, ScanEvent):
                ev.index = k
                k += 1
            yield ev

    def scans_at(
        self, indices: Sequence[int], progress: Callable[[int, int], None] | None = None
    ) -> Iterator[ScanEvent]:
        """The input's scans number `indices` (increasing), read again (a run's scans, once it is over: to
        place them, to cast them into a grid); the scans between them are passed over undecoded.
        `progress(done, total)` counts the scans read. InputError when the input ends before the last of
        them (not the run's input)."""
        if not len(indices):
            return
        wanted = {int(i) for i in indices}
        last = int(indices[-1])
        at = -1  # the index of the scan read last

        def select(n: int) -> bool:
            nonlocal at
            at = n
            return n in wanted

        for ev in converted(self.mcap, [ch.LASER], self._event, select):
            ev.index = at
            if progress is not None:
                progress(at + 1, last + 1)
            yield ev
            if at >= last:
                return
        raise InputError(
            f"{self.path}: the run needs scan {last} but the input has {at + 1} scans; is this the run's input?"
        )

    def read_all(self, topic: str) -> list[Message]:
        return list(converted(self.mcap, [topic], lambda m: m))

    def gps_array(self) -> np.ndarray | None:
        rows = list(converted(self.mcap, [ch.GPS], lambda m: [m.t_s, m.value.pose.position.x, m.value.pose.position.y]))
        return np.array(rows) if rows else None

    def landmarks_array(self) -> np.ndarray | None:
        """The surveyed (or simulated) landmarks (K, 2), where the log has them."""
        msgs = self.read_all(ch.LANDMARKS_TRUTH)
        if not msgs:
            return None
        return np.column_stack([msgs[0].value["x_m"], msgs[0].value["y_m"]])

    def vehicle(self, preset: str | None = None) -> AckermannVehicle | None:
        """An Ackermann log's vehicle: the `preset` named (`--vehicle`), else the one its metadata names (the Car
        Park's by default); None for an odometry log."""
        if self.motion_model != "ackermann":
            return None
        return vehicle_preset(preset or self.meta["vehicle"].get("preset", "carpark"))

    def head_controls_and_gps(self, seconds: float) -> tuple[np.ndarray, np.ndarray]:
        """Ackermann controls and GPS fixes of the first `seconds` of them (for initialisation): from the first
        of either, not the log's first message (a log cut from a longer one keeps that one's once-written
        messages, such as the surveyed landmarks, at its start)."""
        controls, gps = [], []
        first = None
        for ev in converted(self.mcap, [ch.ODOM_ACKERMANN, ch.GPS], self._event):
            first = ev.t_s if first is None else first
            if ev.t_s > first + seconds:
                break
            if isinstance(ev, GpsEvent):
                gps.append([ev.t_s, *ev.xy])
            else:
                controls.append([ev.t_s, ev.speed_mps, ev.steering_rad])
        return np.array(controls).reshape(-1, 3), np.array(gps).reshape(-1, 3)


def _finite(*values: Any) -> list[float]:
    out = [float(v) for v in values]
    if not all(map(math.isfinite, out)):
        raise ValueError(f"non-finite value in {out}")
    return out


T = TypeVar("T")


def converted(
    mcap: McapInput, topics: list[str], convert: Callable[[Message], T], select: Callable[[int], bool] | None = None
) -> Iterator[T]:
    """`convert(msg)` for each message of `topics` in log-time order (those `select(n)` approves of, n the
    message's index among them, where given: `McapInput.messages`). A damaged file, or a message that
    `convert` cannot read, raises InputError naming the file, the message's index and its topic."""
    n = 0  # the index of the message being read

    def counted(k: int) -> bool:
        nonlocal n
        n = k
        return select(k)

    it = mcap.messages(topics, None if select is None else counted)
    while True:
        try:
            msg = next(it)
        except StopIteration:
            return
        except Exception as e:  # the mcap, zstd and protobuf libraries raise many types for damaged data
            raise InputError(f"{mcap.path}: damaged MCAP after message {n} ({read_error(e)})") from None
        try:
            out = convert(msg)
        except (AttributeError, IndexError, KeyError, TypeError, ValueError) as e:
            raise InputError(f"{mcap.path}: message {n} on {msg.topic} is malformed ({e})") from None
        yield out
        if select is None:
            n += 1
