"""Reader for ROS 1 bags and ROS 2 bags (sqlite3 `.db3` and MCAP storage) through `rosbags` (pure Python).

What it takes from a bag (docs/CHANNELS.md, "ROS bags"):

- scans: one `sensor_msgs/msg/LaserScan` topic (`--scan-topic` when there are several);
- odometry: one `nav_msgs/msg/Odometry` topic (`--odom-topic` when there are several), or, when the bag
  has none, the transform odom -> base frame in /tf;
- the laser's mount on the robot: the chain base frame -> laser frame in /tf_static (or, failing that,
  in the first seconds of /tf, where ROS 1 static publishers put it).

Each scan is written with the odometry pose interpolated at its stamp (`ingest.align`) just before it.
Messages are read one at a time in bag order, so memory stays flat in the bag's length.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .align import NS, OdomSample, ScanOdometryAligner
from .base import OdomRecord, ReadOptions, Record, ScanRecord
from .textlog import IngestError
from .tf import FrameTree, PlanarMount, frame_name, planar_mount, yaw_of_quaternion

LASER_TYPE = "sensor_msgs/msg/LaserScan"
ODOM_TYPE = "nav_msgs/msg/Odometry"
TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
BAG_SUFFIXES = (".bag", ".db3", ".mcap")
MOUNT_SEARCH_S = 5.0
"""Seconds of /tf read at the start of the bag for transforms missing from /tf_static."""
MAX_BEAMS = 100_000
MAX_ODOM_GAP_S = 1.0
"""Scans between two odometry samples further apart than this are dropped (the motion is unknown)."""
ANGLE_TOLERANCE_RAD = 1e-6
"""Tolerance on a scan's angles when checking them against its beam count and the first scan's."""
PRINTED_ABS_RAD = 5e-7
"""Rounding of an angle printed with 6 decimal places (pi/180 written 0.017453)."""
PRINTED_REL = 5e-6
"""Relative rounding of an angle printed with 6 significant digits (-1.56643); float32's (6e-8) is within."""


class RosbagReader:
    """ROS 1 `.bag`, ROS 2 bag directory (metadata.yaml), or a ROS 2 storage file (`.db3`, `.mcap`)."""

    formats = ("rosbag",)

    def detect(self, source: Path) -> str | None:
        if source.is_file():
            return "rosbag" if source.suffix.lower() in BAG_SUFFIXES else None
        return "rosbag" if (source / "metadata.yaml").exists() else None

    def open(self, source: Path, fmt: str, options: ReadOptions) -> BagStream:
        return BagStream(source, options)


@dataclass(frozen=True)
class TopicChoice:
    topic: str
    msgtype: str
    count: int


@dataclass(frozen=True)
class ScanGeometryRos:
    """The first scan's geometry: the log's in the metadata (later scans keep their own beams) and the
    range limit of the map."""

    beam_count: int
    angle_min_rad: float
    angle_increment_rad: float
    range_min_m: float
    range_max_m: float
    frame: str


def _printed(x: float) -> float:
    """How far an angle may be from the true one when a converter printed it: rounded to 6 decimal places
    or to 6 significant digits (both common), then stored as float32."""
    return max(PRINTED_ABS_RAD, PRINTED_REL * abs(x))


def beam_increment(n: int, a0: float, a1: float, inc: float) -> float | None:
    """The increment of a LaserScan's n beams, or None when its angles contradict its ranges.

    ROS puts beam k at angle_min + k angle_increment, and angle_max at the last beam; drivers disagree by
    up to one increment on whether angle_max is inclusive (some write angle_min + n angle_increment), and
    converters round the increment (Freiburg logs: pi/180 written 0.017453). A rounding of the increment
    adds up over the beams, so the tolerance grows with their count: for m steps from angle_min to
    angle_max, |a0 + m inc - a1| <= m r(inc) + r(a0) + r(a1), r the rounding of a printed angle
    (`_printed`). It is capped at half an increment, where it would stop telling m from m +- 1, so a
    message whose ranges are two or more beams off the count its angles make, or whose increment is 1 %
    off over 180 beams (1.8 increments at angle_max on the last beam), is still refused.

    The increment returned: when angle_max falls on the beams' grid (m = n - 1 or n steps, or n - 2, within
    the rounding), (a1 - a0) / m. It is the accurate one: angle_min and angle_max are each rounded once,
    while the increment's rounding is multiplied by the beam index (0.017453 for pi/180 puts beam 179 of
    a Freiburg scan 5e-5 rad off; (a1 - a0) / 180 is within the rounding of angle_max), and for an exact
    message it is the message's increment to float precision. When angle_max is off the grid (a driver
    stating the edge of the last beam's sector, say) the message's increment is all there is.
    """

    def slack(m: int) -> float:
        rounding = m * _printed(inc) + _printed(a0) + _printed(a1)
        return min(rounding, abs(inc) / 2) + ANGLE_TOLERANCE_RAD

    # angle_max within one increment of the last beam, plus the rounding (or the former allowance,
    # 0.001 increment + ANGLE_TOLERANCE_RAD, when larger: no message accepted before is refused now).
    if abs(a0 + (n - 1) * inc - a1) > abs(inc) + max(abs(inc) * 0.001 + ANGLE_TOLERANCE_RAD, slack(n)):
        return None
    for m in (n - 1, n, n - 2):
        if m >= 1 and abs(a0 + m * inc - a1) <= slack(m):
            return (a1 - a0) / m
    return inc


def _stamp_ns(header, bag_ns: int) -> int:
    """The header's stamp, or the bag's receive time when the stamp is zero (unset)."""
    ns = int(header.stamp.sec) * NS + int(header.stamp.nanosec)
    return ns if ns > 0 else int(bag_ns)


def _listing(topics: dict[str, TopicChoice]) -> str:
    return ", ".join(f"{t.topic} ({t.msgtype}, {t.count} messages)" for t in topics.values()) or "none"


def _open_reader(path: Path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from .bag_limits import install

    install()  # chunks and messages decompressed within a bound (ingest.bag_limits)

    # ROS 2 bags recorded before Iron carry no message definitions: use the standard ones.
    try:  # the constructor too: it refuses some files that are not bags (a .clf.gz given --format rosbag)
        reader = AnyReader([path], default_typestore=get_typestore(Stores.LATEST))
        reader.open()
    except Exception as e:  # rosbags raises several types for files that are not (whole) bags
        raise IngestError(f"{path}: not a readable ROS bag ({_why(e)})") from None
    return reader


def _why(e: BaseException) -> str:
    text = str(e).strip().rstrip(".") or type(e).__name__
    return " ".join(text.split())


class BagStream:
    """A `LogStream` over one bag. Opening checks the topics, the first scan and the transforms."""

    source_format = "rosbag"

    def __init__(self, path: Path, options: ReadOptions) -> None:
        self.path = Path(path)
        self.options = options
        self.dataset = options.dataset or (self.path.stem if self.path.is_file() else self.path.name)
        self.warnings: list[str] = []
        reader = _open_reader(self.path)
        try:
            self.storage = self._storage(reader)
            topics = {
                name: TopicChoice(name, info.msgtype or "?", int(info.msgcount))
                for name, info in sorted(reader.topics.items())
            }
            self.scan = self._pick(topics, LASER_TYPE, options.scan_topic, "--scan-topic", "laser scans")
            if self.scan.count == 0:
                raise IngestError(f"{self.path}: {self.scan.topic} holds no messages")
            self.geometry = self._first_scan(reader)
            static = FrameTree()
            if TF_STATIC_TOPIC in topics:
                for msg in self._read(reader, TF_STATIC_TOPIC):
                    static.add_message(msg)
            self.odom: TopicChoice | None = None
            self.odom_frame = ""
            odoms = {k: t for k, t in topics.items() if t.msgtype == ODOM_TYPE}
            if options.odom_topic is not None or odoms:
                self.odom = self._pick(topics, ODOM_TYPE, options.odom_topic, "--odom-topic", "odometry")
                self.base_frame = self._odometry_base(reader)
                early = None
            else:
                if TF_TOPIC not in topics:
                    raise IngestError(
                        f"{self.path}: no odometry: no {ODOM_TYPE} topic and no {TF_TOPIC} (topics: {_listing(topics)})"
                    )
                early = self._early_tf(reader, static)
                self.base_frame, self.odom_frame = self._tf_base(early)
            self.mount = self._mount(reader, static, early, TF_TOPIC in topics)
        finally:
            reader.close()
        g = self.geometry
        self.start_angle_rad = g.angle_min_rad
        if self.mount.upside_down:
            # Seen from above, an upside-down laser sweeps the other way: written reversed, beam k is at
            # -(angle of beam n-1-k), so the first bearing is minus the last angle, the step unchanged.
            self.start_angle_rad = -(g.angle_min_rad + (g.beam_count - 1) * g.angle_increment_rad)
        self.expected_records = 2 * self.scan.count
        self.geometry_counts: dict[tuple[int, float, float], int] = {}
        """Scans by beam geometry (beam count, angle_min, angle_increment), as they are read."""
        self.range_max_counts: dict[float, int] = {}
        self.invalid_readings = 0
        """Readings that are NaN or below their message's range_min (no observation)."""
        self.blind_readings = 0
        """No-return readings of messages whose range_max is shorter than the first scan's."""

    # -- opening -----------------------------------------------------------------------------------
    def _storage(self, reader) -> str:
        if not reader.is2:
            return "rosbag1"
        p = self.path
        files = [p] if p.is_file() else list(p.iterdir())
        return "rosbag2-mcap" if any(f.suffix == ".mcap" for f in files) else "rosbag2-sqlite3"

    def _pick(self, topics: dict[str, TopicChoice], msgtype: str, given: str | None, option: str, what: str):
        candidates = {k: t for k, t in topics.items() if t.msgtype == msgtype}
        if given is not None:
            if given not in topics:
                raise IngestError(
                    f"{self.path}: {option} {given}: no such topic; {msgtype} topics: {_listing(candidates)}"
                )
            if topics[given].msgtype != msgtype:
                raise IngestError(
                    f"{self.path}: {option} {given} is {topics[given].msgtype}, not {msgtype}; "
                    f"{msgtype} topics: {_listing(candidates)}"
                )
            return topics[given]
        if not candidates:
            raise IngestError(f"{self.path}: no {msgtype} topic ({what}); topics: {_listing(topics)}")
        if len(candidates) > 1:
            raise IngestError(
                f"{self.path}: {len(candidates)} {msgtype} topics, choose one with {option}: {_listing(candidates)}"
            )
        return next(iter(candidates.values()))

    def _connections(self, reader, *topic_names: str) -> list:
        return [c for c in reader.connections if c.topic in topic_names]

    def _read(self, reader, topic: str, stop_ns: int | None = None) -> Iterator[Any]:
        """Decoded messages of one topic (bad data: one line naming the topic and message index)."""
        n = 0
        try:
            for conn, _, raw in reader.messages(connections=self._connections(reader, topic), stop=stop_ns):
                yield reader.deserialize(raw, conn.msgtype)
                n += 1
        except IngestError:
            raise
        except Exception as e:
            raise IngestError(f"{self.path}: {topic} message {n}: unreadable ({_why(e)})") from None

    def _first(self, reader, topic: str) -> Any:
        messages = self._read(reader, topic)
        try:
            return next(messages)
        except StopIteration:
            raise IngestError(f"{self.path}: {topic} holds no messages") from None
        finally:
            messages.close()

    def _first_scan(self, reader) -> ScanGeometryRos:
        msg = self._first(reader, self.scan.topic)
        n = len(msg.ranges)
        inc = self._check_scan(msg, 0)
        geom = ScanGeometryRos(
            n,
            float(msg.angle_min),
            inc,
            float(msg.range_min),
            float(msg.range_max),
            frame_name(msg.header.frame_id),
        )
        if not (math.isfinite(geom.range_max_m) and geom.range_max_m > max(geom.range_min_m, 0.0)):
            raise IngestError(
                f"{self.path}: {self.scan.topic} message 0: range_max {geom.range_max_m} m is not above "
                f"range_min {geom.range_min_m} m"
            )
        return geom

    def _check_scan(self, msg, index: int) -> float:
        """Refuses a message whose angles contradict its ranges; returns the increment its beams are at
        (`beam_increment`)."""
        where = f"{self.path}: {self.scan.topic} message {index}"
        n = len(msg.ranges)
        inc, a0, a1 = float(msg.angle_increment), float(msg.angle_min), float(msg.angle_max)
        if n < 2:
            raise IngestError(f"{where}: {n} ranges; a scan needs at least 2 beams")
        if not (math.isfinite(inc) and inc != 0 and math.isfinite(a0) and math.isfinite(a1)):
            raise IngestError(f"{where}: angle_increment {inc} rad with angle_min {a0}, angle_max {a1} is not usable")
        used = beam_increment(n, a0, a1, inc)
        if used is None:
            implied = (a1 - a0) / inc + 1
            raise IngestError(
                f"{where}: angle_increment {inc:.6g} rad disagrees with the ranges: angle_min {a0:.6g} to "
                f"angle_max {a1:.6g} rad makes {implied:.1f} beams, the message has {n} ranges"
            )
        if n > MAX_BEAMS:
            raise IngestError(f"{where}: {n} ranges; more than {MAX_BEAMS} beams is not a planar laser scan")
        return used

    def _odometry_base(self, reader) -> str:
        if self.odom.count == 0:
            raise IngestError(f"{self.path}: {self.odom.topic} holds no messages")
        msg = self._first(reader, self.odom.topic)
        child = frame_name(msg.child_frame_id)
        base = frame_name(self.options.base_frame) if self.options.base_frame else child
        if child and base != child:
            raise IngestError(
                f"{self.path}: --base-frame {base}: the odometry on {self.odom.topic} is of frame {child}; "
                f"give --base-frame {child} or leave it out"
            )
        if not base:
            raise IngestError(f"{self.path}: the odometry on {self.odom.topic} names no child frame; give --base-frame")
        return base

    def _early_tf(self, reader, static: FrameTree) -> FrameTree:
        """/tf_static plus the transforms of the first MOUNT_SEARCH_S seconds of /tf."""
        tree = FrameTree()
        stop = reader.start_time + int(MOUNT_SEARCH_S * NS)
        for msg in self._read(reader, TF_TOPIC, stop_ns=stop):
            tree.add_message(msg)
        tree.edges.update(static.edges)
        return tree

    def _tf_base(self, tree: FrameTree) -> tuple[str, str]:
        """(base frame, odometry frame) for odometry from /tf."""
        if self.options.base_frame:
            base = frame_name(self.options.base_frame)
            if base not in tree.edges:
                raise IngestError(
                    f"{self.path}: missing transform: nothing in {TF_TOPIC} has child frame {base} "
                    f"(transforms: {tree.describe()})"
                )
            return base, tree.edges[base][0]
        path = tree.path_up(self.geometry.frame)
        for child, parent in zip(path, path[1:], strict=False):
            if parent == "odom" or parent.endswith(("/odom", "_odom")):
                return child, parent
        raise IngestError(
            f"{self.path}: missing transform: no odom frame above the laser frame {self.geometry.frame} in "
            f"{TF_TOPIC} (path: {' <- '.join(path)}); give --base-frame"
        )

    def _mount(self, reader, static: FrameTree, early: FrameTree | None, has_tf: bool) -> PlanarMount:
        laser = self.geometry.frame
        t = static.chain(self.base_frame, laser)
        if t is None and has_tf:
            if early is None:
                early = self._early_tf(reader, static)
            # The odometry transform (odom -> base) is not part of the mount: leave it out of the chain.
            t = early.chain(self.base_frame, laser)
        if t is None:
            raise IngestError(
                f"{self.path}: missing transform {self.base_frame} -> {laser} (laser mount) in "
                f"{TF_STATIC_TOPIC} (it has: {static.describe()})"
            )
        return planar_mount(t, f"{self.path}: transform {self.base_frame} -> {laser}")

    # -- LogStream ---------------------------------------------------------------------------------
    def metadata(self) -> dict[str, dict[str, Any]]:
        g = self.geometry
        odometry = self.odom.topic if self.odom else f"{TF_TOPIC} ({self.odom_frame} -> {self.base_frame})"
        return {
            "dataset": {
                "name": self.dataset,
                "source_format": self.source_format,
                "source": str(self.path),
                "counts": {"scans": self.scan.count},
            },
            "bag": {
                "storage": self.storage,
                "scan_topic": self.scan.topic,
                "odometry": odometry,
                "base_frame": self.base_frame,
                "laser_frame": g.frame,
            },
            "vehicle": {"motion_model": "odometry", "preset": "odometry"},
            "sensor": {
                "frame": g.frame,
                "beam_count": g.beam_count,
                "start_angle_rad": self.start_angle_rad,
                "end_angle_rad": self.start_angle_rad + (g.beam_count - 1) * g.angle_increment_rad,
                "angle_increment_rad": g.angle_increment_rad,
                "max_range_m": g.range_max_m,
                "self_return_range_m": max(g.range_min_m, 0.0),
                "mount": {
                    "base_frame": self.base_frame,
                    "x_m": self.mount.x_m,
                    "y_m": self.mount.y_m,
                    "yaw_rad": self.mount.yaw_rad,
                    "upside_down": self.mount.upside_down,
                },
            },
        }

    def records(self) -> Iterator[tuple[int, Record]]:
        aligner = ScanOdometryAligner(MAX_ODOM_GAP_S)
        topics = [self.scan.topic, self.odom.topic if self.odom else TF_TOPIC]
        last_ns = -1
        span: tuple[int, int] | None = None  # first and last scan stamps [ns]
        reader = _open_reader(self.path)
        try:
            for topic, index, bag_ns, msg in self._stream(reader, topics):
                if topic == self.scan.topic:
                    inc = self._check_scan(msg, index)
                    t_ns = _stamp_ns(msg.header, bag_ns)
                    span = (t_ns, t_ns) if span is None else (min(span[0], t_ns), max(span[1], t_ns))
                    aligner.add_scan(t_ns, self._scan_record(msg, inc, t_ns))
                elif self.odom is not None:
                    p, tw = msg.pose.pose, msg.twist.twist
                    q = p.orientation
                    yaw = yaw_of_quaternion(q.x, q.y, q.z, q.w)
                    t_ns = _stamp_ns(msg.header, bag_ns)
                    aligner.add_odometry(OdomSample(t_ns, p.position.x, p.position.y, yaw, tw.linear.x, tw.angular.z))
                else:
                    for ts in msg.transforms:
                        if frame_name(ts.child_frame_id) == self.base_frame and (
                            frame_name(ts.header.frame_id) == self.odom_frame
                        ):
                            tr, q = ts.transform.translation, ts.transform.rotation
                            t_ns = _stamp_ns(ts.header, bag_ns)
                            aligner.add_odometry(OdomSample(t_ns, tr.x, tr.y, yaw_of_quaternion(q.x, q.y, q.z, q.w)))
                for scan, odom in aligner.ready():
                    last_ns = yield from self._pair(scan, odom, last_ns)
            for scan, odom in aligner.finish():
                last_ns = yield from self._pair(scan, odom, last_ns)
        finally:
            reader.close()
        self._report(aligner, span)

    def _stream(self, reader, topics: list[str]) -> Iterator[tuple[str, int, int, Any]]:
        counters = dict.fromkeys(topics, 0)
        topic = topics[0]
        try:
            for conn, bag_ns, raw in reader.messages(connections=self._connections(reader, *topics)):
                topic = conn.topic
                msg = reader.deserialize(raw, conn.msgtype)
                yield topic, counters[topic], bag_ns, msg
                counters[topic] += 1
        except IngestError:
            raise
        except Exception as e:
            raise IngestError(
                f"{self.path}: {topic} message {counters[topic]}: unreadable, damaged or truncated bag ({_why(e)})"
            ) from None

    def _scan_record(self, msg, inc: float, t_ns: int) -> ScanRecord:
        """The scan with its own beams (each message's angle_min, increment `inc` (`beam_increment`) and
        count: some lasers interleave several geometries) and its own range limits."""
        g = self.geometry
        ranges = np.asarray(msg.ranges, dtype=float)
        n, a0 = len(ranges), float(msg.angle_min)
        rmin, rmax = float(msg.range_min), float(msg.range_max)
        key = (n, round(a0, 9), round(inc, 12))
        self.geometry_counts[key] = self.geometry_counts.get(key, 0) + 1
        if not (math.isfinite(rmax) and rmax > max(rmin, 0.0)):
            rmax = g.range_max_m  # a message without usable limits: the first scan's
        self.range_max_counts[rmax] = self.range_max_counts.get(rmax, 0) + 1
        out = np.where(ranges >= rmax, np.inf, ranges)  # +inf and beyond range_max: no return
        if rmax < g.range_max_m:
            # No return within a shorter range_max than the log's: the beam saw free space only to rmax, and
            # the log's range is the first scan's: say nothing of that beam rather than claim more.
            blind = ranges >= rmax
            self.blind_readings += int(np.count_nonzero(blind))
            out = np.where(blind, 0.0, out)
        # NaN (no valid reading) and below range_min (too close, -inf): no observation, and the beam
        # tells nothing of free space either: range 0 (below self_return_range_m, so not a return).
        bad = np.isnan(ranges) | (ranges < rmin)
        self.invalid_readings += int(np.count_nonzero(bad))
        out = np.where(bad, 0.0, out)
        inten = np.asarray(msg.intensities, dtype=float) if len(msg.intensities) == len(ranges) else None
        start = a0
        if self.mount.upside_down:
            out = out[::-1]
            inten = None if inten is None else inten[::-1]
            start = -(a0 + (n - 1) * inc)  # seen from above the sweep runs the other way (see __init__)
        return ScanRecord(t_ns / NS, out, start, start + (n - 1) * inc, inten)

    def _pair(self, scan: ScanRecord, odom: OdomSample, last_ns: int) -> Iterator[tuple[int, Record]]:
        ns = max(odom.t_ns, last_ns + 1)
        t_s = odom.t_ns / NS
        yield ns, OdomRecord(t_s, odom.x_m, odom.y_m, odom.theta_rad, odom.tv_mps, odom.rv_radps, "interpolated")
        yield ns + 1, scan
        return ns + 1

    def _report(self, aligner: ScanOdometryAligner, span: tuple[int, int] | None) -> None:
        c = aligner.counts
        odometry = self.odom.topic if self.odom else f"{TF_TOPIC} {self.odom_frame} -> {self.base_frame}"
        if c.paired == 0:
            if aligner.first_odom_ns is None:
                raise IngestError(f"{self.path}: no odometry samples in {odometry}")
            odom_span = f"{aligner.first_odom_ns / NS:.3f} s to {aligner.odom_t[-1] / NS:.3f} s"
            scan_span = f"{span[0] / NS:.3f} s to {span[1] / NS:.3f} s" if span else "none"
            if c.in_gaps:
                raise IngestError(
                    f"{self.path}: no scan has odometry within {MAX_ODOM_GAP_S:g} s on both sides "
                    f"(odometry {odometry}: {odom_span}; scans {self.scan.topic}: {scan_span})"
                )
            raise IngestError(
                f"{self.path}: the odometry never overlaps the scans in time (odometry {odometry}: {odom_span}; "
                f"scans {self.scan.topic}: {scan_span})"
            )
        for n, why in (
            (c.before_odometry, "come before the first odometry sample"),
            (c.after_odometry, "come after the last odometry sample"),
            (c.in_gaps, f"fall in gaps of more than {MAX_ODOM_GAP_S:g} s between odometry samples"),
        ):
            if n:
                self.warnings.append(f"{self.path}: {n} scans {why}; left out")
        if len(self.geometry_counts) > 1:
            kinds = ", ".join(
                f"{n} beams from {math.degrees(a0):.2f} deg by {math.degrees(inc):.3f} deg: {count}"
                for (n, a0, inc), count in sorted(self.geometry_counts.items(), key=lambda kv: -kv[1])
            )
            self.warnings.append(
                f"{self.path}: {self.scan.topic} interleaves {len(self.geometry_counts)} scan geometries "
                f"({kinds} scans); each scan keeps its own beams"
            )
        if len(self.range_max_counts) > 1:
            kinds = ", ".join(f"{r:g} m: {count}" for r, count in sorted(self.range_max_counts.items()))
            self.warnings.append(
                f"{self.path}: range_max differs between messages ({kinds} scans); the map's range is the first "
                f"scan's {self.geometry.range_max_m:g} m, and {self.blind_readings} no-return readings of "
                "shorter-ranged scans are left without an observation"
            )
        if self.invalid_readings:
            self.warnings.append(
                f"{self.path}: {self.invalid_readings} readings are NaN or below their message's range_min; "
                "left without an observation"
            )
        if c.odometry_backwards:
            self.warnings.append(
                f"{self.path}: {c.odometry_backwards} odometry samples did not advance in time; ignored"
            )
