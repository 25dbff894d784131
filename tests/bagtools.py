"""Build real ROS bags for the tests with rosbags' writers: ROS 1 (.bag), ROS 2 sqlite3 and ROS 2 MCAP.

`BagBuilder` writes LaserScan, Odometry and TFMessage messages (typed by the rosbags type store of the
bag's ROS version); `bag_from_log` turns the first scans of a CARMEN log into a robot bag with a laser
mounted at `mount` on the base (odometry topic or /tf only).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gslam.se2 import compose, inverse
from ingest.logdata import LogData

KINDS = ("ros1", "sqlite3", "mcap")
NS = 1_000_000_000

# ROS 1 Noetic's store in rosbags lacks tf2_msgs; this is its definition (tf2_msgs/TFMessage).
_TF_MSG_ROS1 = "geometry_msgs/TransformStamped[] transforms\n"


def _typestore(kind: str):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    if kind == "ros1":
        ts = get_typestore(Stores.ROS1_NOETIC)
        ts.register(get_types_from_msg(_TF_MSG_ROS1, "tf2_msgs/msg/TFMessage"))
        return ts
    return get_typestore(Stores.ROS2_HUMBLE)


def _quaternion(yaw: float, roll: float = 0.0) -> tuple[float, float, float, float]:
    """(x, y, z, w) of Rz(yaw) Rx(roll)."""
    cy, sy, cr, sr = math.cos(yaw / 2), math.sin(yaw / 2), math.cos(roll / 2), math.sin(roll / 2)
    return (cy * sr, sy * sr, sy * cr, cy * cr)


class BagBuilder:
    """A bag being written; messages must be written in non-decreasing bag time."""

    def __init__(self, path: Path, kind: str) -> None:
        from rosbags.rosbag1 import Writer as Writer1
        from rosbags.rosbag2 import StoragePlugin
        from rosbags.rosbag2 import Writer as Writer2

        self.kind = kind
        self.ts = _typestore(kind)
        self.T = self.ts.types
        if kind == "ros1":
            self.writer = Writer1(Path(path))
        else:
            plugin = StoragePlugin.SQLITE3 if kind == "sqlite3" else StoragePlugin.MCAP
            self.writer = Writer2(Path(path), version=9, storage_plugin=plugin)
        self.connections: dict[tuple[str, str], object] = {}
        self.seq = 0

    def __enter__(self) -> BagBuilder:
        self.writer.open()
        return self

    def __exit__(self, *exc) -> None:
        self.writer.close()

    # -- messages ----------------------------------------------------------------------------------
    def header(self, t_ns: int, frame: str):
        stamp = self.T["builtin_interfaces/msg/Time"](sec=t_ns // NS, nanosec=t_ns % NS)
        if self.kind == "ros1":
            self.seq += 1
            return self.T["std_msgs/msg/Header"](seq=self.seq, stamp=stamp, frame_id=frame)
        return self.T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def write(self, topic: str, msgtype: str, msg, bag_ns: int) -> None:
        key = (topic, msgtype)
        if key not in self.connections:
            self.connections[key] = self.writer.add_connection(topic, msgtype, typestore=self.ts)
        raw = self.ts.serialize_ros1(msg, msgtype) if self.kind == "ros1" else self.ts.serialize_cdr(msg, msgtype)
        self.writer.write(self.connections[key], int(bag_ns), raw)

    def laser_scan(
        self,
        t_ns: int,
        ranges: np.ndarray,
        angle_min: float,
        angle_increment: float,
        *,
        angle_max: float | None = None,
        range_min: float = 0.0,
        range_max: float = 30.0,
        frame: str = "laser",
        topic: str = "/scan",
        intensities: np.ndarray | None = None,
        bag_ns: int | None = None,
    ) -> None:
        n = len(ranges)
        msg = self.T["sensor_msgs/msg/LaserScan"](
            header=self.header(t_ns, frame),
            angle_min=angle_min,
            angle_max=angle_min + (n - 1) * angle_increment if angle_max is None else angle_max,
            angle_increment=angle_increment,
            time_increment=0.0,
            scan_time=0.0,
            range_min=range_min,
            range_max=range_max,
            ranges=np.asarray(ranges, dtype=np.float32),
            intensities=np.asarray([] if intensities is None else intensities, dtype=np.float32),
        )
        self.write(topic, "sensor_msgs/msg/LaserScan", msg, t_ns if bag_ns is None else bag_ns)

    def _pose(self, x: float, y: float, yaw: float):
        T = self.T
        qx, qy, qz, qw = _quaternion(yaw)
        return T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
        )

    def odometry(
        self,
        t_ns: int,
        x: float,
        y: float,
        yaw: float,
        *,
        topic: str = "/odom",
        frame: str = "odom",
        child: str = "base_link",
        bag_ns: int | None = None,
    ) -> None:
        T = self.T
        zero3 = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        msg = T["nav_msgs/msg/Odometry"](
            header=self.header(t_ns, frame),
            child_frame_id=child,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=self._pose(x, y, yaw), covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=zero3, angular=zero3), covariance=np.zeros(36)
            ),
        )
        self.write(topic, "nav_msgs/msg/Odometry", msg, t_ns if bag_ns is None else bag_ns)

    def tf(
        self,
        t_ns: int,
        transforms: list[tuple],
        *,
        static: bool = False,
        bag_ns: int | None = None,
    ) -> None:
        """transforms: (parent, child, x, y, yaw[, z, roll]) each."""
        T = self.T
        items = []
        for parent, child, x, y, yaw, *rest in transforms:
            z = rest[0] if rest else 0.0
            roll = rest[1] if len(rest) > 1 else 0.0
            qx, qy, qz, qw = _quaternion(yaw, roll)
            items.append(
                T["geometry_msgs/msg/TransformStamped"](
                    header=self.header(t_ns, parent),
                    child_frame_id=child,
                    transform=T["geometry_msgs/msg/Transform"](
                        translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                        rotation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
                    ),
                )
            )
        msg = T["tf2_msgs/msg/TFMessage"](transforms=items)
        self.write("/tf_static" if static else "/tf", "tf2_msgs/msg/TFMessage", msg, t_ns if bag_ns is None else bag_ns)


def bag_from_log(
    log: LogData,
    path: Path,
    kind: str,
    scans: int,
    odometry: str = "topic",
    mount: tuple[float, float, float] = (0.0, 0.0, 0.0),
    mount_z_m: float = 0.25,
) -> Path:
    """The first `scans` scans of a CARMEN log as a robot's bag.

    The log's odometry pose at each scan is taken as the laser's pose L_k; the robot's base is then at
    B_k = L_k (+) mount^-1, which the bag records as odometry (`odometry="topic"`: nav_msgs/Odometry on
    /odom, at each scan and half-way between scans) or as the transform odom -> base_link on /tf
    (`odometry="tf"`, beside a fixed map -> odom that must be ignored). /tf_static holds base_link ->
    laser = mount (lifted by `mount_z_m`). Scans arrive 20 ms after their stamp, odometry 1 ms after.
    """
    g = log.geometry
    t_ns = np.round(log.scan_t_s[:scans] * 1e9).astype(np.int64)
    laser = log.odom_pose[np.array([i for i, s in enumerate(log.odom_source) if s == "FLASER"][:scans]), 1:4]
    base = compose(laser, inverse(np.asarray(mount, dtype=float)))
    events: list[tuple[int, int, str, object]] = []  # (bag ns, order, kind, payload)
    for k in range(scans):
        events.append((int(t_ns[k]) + 1_000_000, 0, "odom", (int(t_ns[k]), base[k])))
        if k + 1 < scans:
            mid = (int(t_ns[k]) + int(t_ns[k + 1])) // 2
            f = (mid - t_ns[k]) / (t_ns[k + 1] - t_ns[k])
            dyaw = math.remainder(base[k + 1, 2] - base[k, 2], 2 * math.pi)
            pose = np.array([*(base[k, :2] + f * (base[k + 1, :2] - base[k, :2])), base[k, 2] + f * dyaw])
            events.append((mid + 1_000_000, 0, "odom", (mid, pose)))
        events.append((int(t_ns[k]) + 20_000_000, 1, "scan", k))
    events.sort(key=lambda e: (e[0], e[1]))
    ranges = np.where(np.isfinite(log.scan_ranges_m[:scans]), log.scan_ranges_m[:scans], 81.91)
    with BagBuilder(path, kind) as bag:
        t0 = int(t_ns[0]) - 10_000_000
        bag.tf(t0, [("base_link", "laser", mount[0], mount[1], mount[2], mount_z_m)], static=True, bag_ns=t0)
        if odometry == "tf":
            bag.tf(t0, [("map", "odom", 0.0, 0.0, 0.0)], bag_ns=t0)
        for bag_ns, _, what, payload in events:
            if what == "scan":
                k = payload
                bag.laser_scan(
                    int(t_ns[k]),
                    ranges[k],
                    g.start_angle_rad,
                    g.angle_increment_rad,
                    range_max=g.max_range_m,
                    bag_ns=bag_ns,
                )
            else:
                stamp, pose = payload
                if odometry == "topic":
                    bag.odometry(stamp, *pose, bag_ns=bag_ns)
                else:
                    bag.tf(stamp, [("odom", "base_link", *pose)], bag_ns=bag_ns)
    return path


def bag_from_robot(sim, path: Path, kind: str, odometry: str = "topic", t0_s: float = 1000.0) -> Path:
    """A `pipelines.demo.world.RobotLog` as a robot's bag: its odometry (topic or /tf), its scans, and its mount on
    /tf_static. Odometry comes at each scan's stamp and half-way between scans."""
    t_ns = np.round((t0_s + sim.t_s) * 1e9).astype(np.int64)
    odo = sim.odometry
    ranges = np.where(np.isfinite(sim.ranges), sim.ranges, sim.max_range_m + 1.0)
    with BagBuilder(path, kind) as bag:
        m = sim.mount
        bag.tf(int(t_ns[0]) - 1000, [("base_link", "laser", m[0], m[1], m[2], 0.2)], static=True)
        for k in range(len(t_ns)):
            stamps = [(int(t_ns[k]), odo[k])]
            if k + 1 < len(t_ns):
                dyaw = math.remainder(odo[k + 1, 2] - odo[k, 2], 2 * math.pi)
                mid = np.array([*(odo[k, :2] + odo[k + 1, :2]) / 2, odo[k, 2] + dyaw / 2])
                stamps.append(((int(t_ns[k]) + int(t_ns[k + 1])) // 2, mid))
            for i, (stamp, pose) in enumerate(stamps):
                if odometry == "topic":
                    bag.odometry(stamp, *pose)
                else:
                    bag.tf(stamp, [("odom", "base_link", *pose)])
                if i == 0:
                    bag.laser_scan(
                        int(t_ns[k]), ranges[k], sim.start_angle_rad, sim.angle_increment_rad, range_max=sim.max_range_m
                    )
    return path


def bag_of_scans(
    path: Path,
    scans: list[tuple[int, float, float, float]],
    kind: str = "ros1",
    *,
    upside_down: bool = False,
    t0_ns: int = 1_700_000_000 * NS,
) -> Path:
    """A small robot bag whose LaserScan messages carry the given angles as written, unchecked:
    `scans` holds (ranges count, angle_min, angle_increment, angle_max) per message, each message's
    ranges 4 m everywhere. Scans come at 5 Hz between odometry at 10 Hz (0.5 m/s ahead); /tf_static
    holds base_link -> laser (rolled over when `upside_down`)."""
    with BagBuilder(path, kind) as bag:
        roll = math.pi if upside_down else 0.0
        bag.tf(t0_ns - 10**8, [("base_link", "laser", 0.1, 0.0, 0.0, 0.2, roll)], static=True)
        events: list[tuple[int, int, int | None]] = []  # (bag ns, order, scan index or None for odometry)
        events += [(t0_ns + k * 10**8, 0, None) for k in range(2 * len(scans) + 2)]
        events += [(t0_ns + k * 2 * 10**8 + 5 * 10**7, 1, k) for k in range(len(scans))]
        for t, _, k in sorted(events, key=lambda e: (e[0], e[1])):
            if k is None:
                bag.odometry(t, (t - t0_ns) / NS * 0.5, 0.0, 0.0)
            else:
                n, angle_min, angle_increment, angle_max = scans[k]
                bag.laser_scan(t, np.full(n, 4.0), angle_min, angle_increment, angle_max=angle_max)
    return path
