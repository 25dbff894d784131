"""Channel names, the project's own JSON schemas, and builders for the Foxglove protobuf messages.

The full reference, with field meanings and units, is docs/CHANNELS.md.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.LaserScan_pb2 import LaserScan
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from google.protobuf.timestamp_pb2 import Timestamp

from mcaplog import wire
from mcaplog.wire import seconds_nanos

# ---- input channels ---------------------------------------------------------------------------
LASER = "/laser/scan"
ODOM_ACKERMANN = "/vehicle/odometry"  # Sydney logs: rear-left wheel speed and steering angle
ODOM_POSE = "/odom/pose"  # CARMEN logs: integrated odometry pose (and velocities where known)
ODOM = "/odom"  # the same odometry poses as foxglove.PoseInFrame (frame odom), for viewers
GPS = "/gps/position"
LANDMARKS_TRUTH = "/ground_truth/landmarks"  # surveyed poles (Car Park) or simulated obstacles
RELATIONS_TRUTH = "/ground_truth/relations"  # Kuemmerle et al. relations (Freiburg logs)
TRAJECTORY_TRUTH = "/ground_truth/pose"  # true pose where a simulator knows it

# ---- output channels --------------------------------------------------------------------------
SLAM_POSE = "/slam/pose"
SLAM_PARTICLES = "/slam/particles"
SLAM_TRAJECTORY = "/slam/trajectory"
SLAM_PATH = "/slam/path"  # foxglove.PosesInFrame at each map update: the best particle's path so far
SLAM_MAP = "/slam/map"
SLAM_MAP_FINAL = "/slam/map_final"
SLAM_STATS = "/slam/stats"
SLAM_LANDMARKS = "/slam/landmarks"  # FastSLAM: landmark means and covariances (final, best particle)
SLAM_GRAPH = "/slam/graph"  # the pose graph (final): nodes, sequential edges, loop closures kept and rejected
SLAM_GRAPH_SCANS = "/slam/graph_scans"  # each graph node's returns in the map frame (final): what --continue reads
SLAM_SESSIONS = "/slam/sessions"  # the earlier mapping runs a continued result goes on from (final)
SLAM_EARLIER_MAPS = "/slam/earlier_maps"  # maps of earlier runs a later one could not find itself in (final)
SLAM_EARLIER_GRAPHS = "/slam/earlier_graphs"  # the pose graph under each earlier map (final)
SLAM_EARLIER_GRAPH_SCANS = "/slam/earlier_graph_scans"  # each earlier graph's node returns (final)
SLAM_GRID = "/slam/grid"  # grid methods: occupancy grid (final, best particle)
MAP_OCCUPANCY = "/map/occupancy"  # `gslam process --occupancy`: trinary navigation grid (final)

TF = "/tf"  # foxglove.FrameTransforms at each step: map -> odom -> base_link -> laser
SLAM_SCAN = "/slam/scan"  # the step's scan in the laser frame (placed by /tf)

MAP_FRAME = "map"
ODOM_FRAME = "odom"
BASE_FRAME = "base_link"
LASER_FRAME = "laser"

ACKERMANN_SCHEMA: dict[str, Any] = {
    "title": "gslam.AckermannOdometry",
    "description": "Rear-left wheel speed and front steering angle of a car-like vehicle.",
    "type": "object",
    "properties": {
        "t_s": {"type": "number", "description": "sample time on the dataset clock [s]"},
        "speed_mps": {"type": "number", "description": "rear-left wheel speed [m/s]"},
        "steering_rad": {"type": "number", "description": "front steering angle [rad], left positive"},
    },
    "required": ["t_s", "speed_mps", "steering_rad"],
}

ODOM_POSE_SCHEMA: dict[str, Any] = {
    "title": "gslam.OdometryPose",
    "description": "Integrated odometry pose, odometry frame (CARMEN ODOM or FLASER odom; ROS bags: base at scan).",
    "type": "object",
    "properties": {
        "t_s": {"type": "number", "description": "time stamp from the log [s] (may go backwards)"},
        "x_m": {"type": "number"},
        "y_m": {"type": "number"},
        "theta_rad": {"type": "number"},
        "tv_mps": {"type": ["number", "null"], "description": "translational velocity, if logged"},
        "rv_radps": {"type": ["number", "null"], "description": "rotational velocity, if logged"},
        "source": {"type": "string", "description": "ODOM or FLASER (CARMEN), interpolated (ROS bags)"},
    },
    "required": ["t_s", "x_m", "y_m", "theta_rad"],
}

LANDMARKS_SCHEMA: dict[str, Any] = {
    "title": "gslam.Landmarks",
    "description": "Surveyed (or simulated) landmark positions in the GPS frame [m].",
    "type": "object",
    "properties": {
        "x_m": {"type": "array", "items": {"type": "number"}},
        "y_m": {"type": "array", "items": {"type": "number"}},
        "radius_m": {"type": "array", "items": {"type": "number"}},
        "kind": {"type": "string"},
    },
    "required": ["x_m", "y_m"],
}

RELATIONS_SCHEMA: dict[str, Any] = {
    "title": "gslam.Relations",
    "description": "Ground-truth relations (Kuemmerle et al. 2009): pose(t2) in the frame of pose(t1).",
    "type": "object",
    "properties": {
        "t1_s": {"type": "array", "items": {"type": "number"}},
        "t2_s": {"type": "array", "items": {"type": "number"}},
        "dx_m": {"type": "array", "items": {"type": "number"}},
        "dy_m": {"type": "array", "items": {"type": "number"}},
        "dyaw_rad": {"type": "array", "items": {"type": "number"}},
    },
    "required": ["t1_s", "t2_s", "dx_m", "dy_m", "dyaw_rad"],
}

SLAM_LANDMARKS_SCHEMA: dict[str, Any] = {
    "title": "gslam.LandmarkMap",
    "description": "Landmark EKFs of the best particle: means [m] and 2x2 covariances [m^2], row-major.",
    "type": "object",
    "properties": {
        "x_m": {"type": "array", "items": {"type": "number"}},
        "y_m": {"type": "array", "items": {"type": "number"}},
        "cov": {"type": "array", "items": {"type": "array", "items": {"type": "number"}}},
    },
}

SLAM_GRAPH_SCHEMA: dict[str, Any] = {
    "title": "gslam.PoseGraph",
    "description": "The back end's pose graph at the end of the run: the optimised node poses (x [m], y [m], "
    "yaw [rad], in the map frame), the step of each node, its edges as node index pairs, and the loop "
    "closures the optimisation kept and rejected with their match scores (0 to 1).",
    "type": "object",
    "properties": {
        "x_m": {"type": "array", "items": {"type": "number"}},
        "y_m": {"type": "array", "items": {"type": "number"}},
        "yaw_rad": {"type": "array", "items": {"type": "number"}},
        "step": {"type": "array", "items": {"type": "integer"}},
        "session": {"type": "array", "items": {"type": "integer"}},
        "sequential": {"type": "array", "items": {"type": "array", "items": {"type": "integer"}}},
        "closures": {"type": "array", "items": {"type": "array", "items": {"type": "integer"}}},
        "closure_scores": {"type": "array", "items": {"type": "number"}},
        "rejected": {"type": "array", "items": {"type": "array", "items": {"type": "integer"}}},
        "rejected_scores": {"type": "array", "items": {"type": "number"}},
    },
}

SLAM_SESSIONS_SCHEMA: dict[str, Any] = {
    "title": "gslam.Sessions",
    "description": "The earlier mapping runs of a continued map (`gslam process --continue`), oldest first: "
    "each run's index, input, the map it belongs to (0: the result's map, in whose frame it lies; k >= 1: "
    "the k-th message of /slam/earlier_maps, in that map's frame), and its final trajectory (log times [s], "
    "the base's x [m], y [m], yaw [rad], moved with the final pose graph).",
    "type": "object",
    "properties": {
        "sessions": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "session": {"type": "integer"},
                    "input": {"type": "string"},
                    "map": {"type": "integer"},
                    "connected": {"type": "boolean"},
                    "t_s": {"type": "array", "items": {"type": "number"}},
                    "x_m": {"type": "array", "items": {"type": "number"}},
                    "y_m": {"type": "array", "items": {"type": "number"}},
                    "yaw_rad": {"type": "array", "items": {"type": "number"}},
                },
            },
        }
    },
}

STATS_SCHEMA: dict[str, Any] = {
    "title": "gslam.StepStats",
    "description": "Per-step statistics of the filter.",
    "type": "object",
    "properties": {
        "scan_index": {"type": "integer"},
        "t_s": {"type": "number"},
        "effective_sample_size": {"type": "number"},
        "resampled": {"type": "boolean"},
        "updated": {"type": "boolean", "description": "the map and weights were updated at this scan"},
        "map_points": {"type": "integer", "description": "points in the best particle's map"},
        "map_points_total": {"type": "integer", "description": "points over all particles"},
        "step_ms": {"type": "number", "description": "filter step wall time [ms]"},
        "best_particle": {"type": "integer"},
        "matched": {"type": "integer", "description": "particles whose scan match was kept"},
    },
}


def map_frame(k: int) -> str:
    """The frame of a result's map k: `map` for its own (0), `map_K` for the K-th earlier map it keeps apart
    (`/slam/earlier_maps`)."""
    return MAP_FRAME if k == 0 else f"{MAP_FRAME}_{k}"


def map_index(frame_id: str) -> int:
    """Inverse of `map_frame`; -1 for a frame that is not a map's."""
    if frame_id == MAP_FRAME:
        return 0
    head, _, k = frame_id.rpartition("_")
    return int(k) if head == MAP_FRAME and k.isdigit() and int(k) > 0 else -1


def session_trajectory(k: int) -> str:
    """The channel of earlier mapping run k's final trajectory in a continued result (foxglove.PosesInFrame)."""
    return f"/slam/sessions/{k}/trajectory"


def _json_float(v: float) -> str:
    """A number as `json.dumps` writes it (repr; NaN and the infinities as JavaScript names them)."""
    v = float(v)
    if v != v:
        return "NaN"
    if v in (math.inf, -math.inf):
        return "Infinity" if v > 0 else "-Infinity"
    return float.__repr__(v)


def _json_int(v: int) -> str:
    return ("true" if v else "false") if isinstance(v, bool) else int.__repr__(int(v))


def step_stats_json(
    scan_index: int,
    t_s: float,
    effective_sample_size: float,
    resampled: bool,
    updated: bool,
    map_points: int,
    map_points_total: int,
    step_ms: float,
    best_particle: int,
    matched: int,
) -> bytes:
    """A /slam/stats message (`STATS_SCHEMA`): the bytes `json.dumps(..., separators=(",", ":"))` writes for
    the object of these fields in this order, from one format string (a step writes one; the encoder's
    generic walk cost several microseconds of every scan)."""
    return (
        f'{{"scan_index":{_json_int(scan_index)},"t_s":{_json_float(t_s)},'
        f'"effective_sample_size":{_json_float(effective_sample_size)},"resampled":{_json_int(resampled)},'
        f'"updated":{_json_int(updated)},"map_points":{_json_int(map_points)},'
        f'"map_points_total":{_json_int(map_points_total)},"step_ms":{_json_float(step_ms)},'
        f'"best_particle":{_json_int(best_particle)},"matched":{_json_int(matched)}}}'
    ).encode()


def timestamp(t_s: float) -> Timestamp:
    ts = Timestamp()
    ts.seconds, ts.nanos = seconds_nanos(t_s)
    return ts


def t_of(ts: Timestamp) -> float:
    return ts.seconds + ts.nanos * 1e-9


def _set_pose(pose: Pose, x: float, y: float, theta: float) -> None:
    pose.position.x = float(x)
    pose.position.y = float(y)
    pose.position.z = 0.0
    pose.orientation.w = math.cos(theta / 2)
    pose.orientation.z = math.sin(theta / 2)


def yaw_of(pose: Pose) -> float:
    q = pose.orientation
    return math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))


def laser_scan(
    t_s: float,
    ranges_m: np.ndarray,
    start_angle_rad: float,
    end_angle_rad: float,
    intensities: np.ndarray | None = None,
    frame_id: str = "laser",
) -> LaserScan:
    """A foxglove.LaserScan; ranges with no return are +inf."""
    msg = LaserScan(frame_id=frame_id, start_angle=start_angle_rad, end_angle=end_angle_rad)
    msg.timestamp.CopyFrom(timestamp(t_s))
    msg.pose.orientation.w = 1.0
    msg.ranges.extend(ranges_m.tolist())
    if intensities is not None:
        msg.intensities.extend(intensities.tolist())
    return msg


def frame_transforms(t_s: float, links: list[tuple[str, str, float, float, float]]):
    """A foxglove.FrameTransforms: each link (parent, child, x, y, yaw) is the child frame's pose in its
    parent's, in the plane."""
    from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms

    msg = FrameTransforms()
    stamp = timestamp(t_s)
    for parent, child, x, y, yaw in links:
        tf = msg.transforms.add(parent_frame_id=parent, child_frame_id=child)
        tf.timestamp.CopyFrom(stamp)
        tf.translation.x, tf.translation.y, tf.translation.z = float(x), float(y), 0.0
        tf.rotation.w, tf.rotation.z = math.cos(yaw / 2), math.sin(yaw / 2)
    return msg


def pose_in_frame(t_s: float, x: float, y: float, theta: float, frame_id: str) -> PoseInFrame:
    msg = PoseInFrame(frame_id=frame_id)
    msg.timestamp.CopyFrom(timestamp(t_s))
    _set_pose(msg.pose, x, y, theta)
    return msg


def _pose_record_layout() -> np.ndarray:
    """The wire bytes of one PosesInFrame.poses element with every field present (proto3 readers take
    explicit zeros as the defaults): tags and lengths filled, the 7 doubles left zero. Field numbers are
    read from the schema's descriptors, so a schema that moved a field fails here, not silently."""
    pose = Pose.DESCRIPTOR
    assert PosesInFrame.DESCRIPTOR.fields_by_name["poses"].number == 3
    assert pose.fields_by_name["position"].number == 1 and pose.fields_by_name["orientation"].number == 2
    vec = pose.fields_by_name["position"].message_type.fields_by_name
    quat = pose.fields_by_name["orientation"].message_type.fields_by_name
    assert [vec[k].number for k in "xyz"] == [1, 2, 3] and [quat[k].number for k in "xyzw"] == [1, 2, 3, 4]
    rec = np.zeros(69, dtype=np.uint8)
    rec[[0, 1, 2, 3]] = [0x1A, 67, 0x0A, 27]  # poses (3, LEN 67) > position (1, LEN 27)
    rec[[4, 13, 22]] = [0x09, 0x11, 0x19]  # x, y, z: fixed64 fields 1, 2, 3
    rec[[31, 32]] = [0x12, 36]  # orientation (2, LEN 36)
    rec[[33, 42, 51, 60]] = [0x09, 0x11, 0x19, 0x21]  # x, y, z, w
    return rec


_POSE_RECORD = _pose_record_layout()
_POSE_DOUBLES = (5, 14, 23, 34, 43, 52, 61)  # offsets of position x, y, z and orientation x, y, z, w
_POSE_FIELDS = np.dtype(
    {
        "names": ["x", "y", "qz", "qw"],
        "formats": ["<f8"] * 4,
        "offsets": [_POSE_DOUBLES[i] for i in (0, 1, 5, 6)],
        "itemsize": len(_POSE_RECORD),
    }
)
"""The doubles of a pose record that vary (position z and orientation x, y stay 0), unaligned in place."""
_POSE_RECORD_BYTES = _POSE_RECORD.tobytes()


def poses_in_frame_bytes(t_s: float, poses: np.ndarray, frame_id: str) -> bytes:
    """A serialised foxglove.PosesInFrame of `poses` ((K, 3): x, y, heading), encoded with numpy for all
    poses at once (building the message objects pose by pose cost more than the filter on long logs)."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    buf = bytearray(_POSE_RECORD_BYTES * len(poses))  # the records' tags and zeros, written through `rec`
    rec = np.frombuffer(buf, dtype=_POSE_FIELDS)
    half = poses[:, 2] / 2
    rec["x"], rec["y"], rec["qz"], rec["qw"] = poses[:, 0], poses[:, 1], np.sin(half), np.cos(half)
    # Serialised messages concatenate as a merge: repeated fields append.
    return wire.head(t_s, frame_id) + bytes(buf)


def poses_of(msg: PosesInFrame) -> np.ndarray:
    return np.array([[p.position.x, p.position.y, yaw_of(p)] for p in msg.poses]).reshape(-1, 3)


_CLOUD_FIELDS = (("x", 0), ("y", 4), ("z", 8), ("probability", 12))


def point_cloud(t_s: float, xy: np.ndarray, probability: np.ndarray, frame_id: str = MAP_FRAME) -> PointCloud:
    """A foxglove.PointCloud with float32 x, y, z=0 and probability fields (Rerun needs the z field)."""
    msg = PointCloud(frame_id=frame_id, point_stride=16)
    msg.timestamp.CopyFrom(timestamp(t_s))
    msg.pose.orientation.w = 1.0
    for name, offset in _CLOUD_FIELDS:
        msg.fields.add(name=name, offset=offset, type=PackedElementField.FLOAT32)
    buf = np.zeros((len(xy), 4), dtype=np.float32)
    buf[:, :2] = xy
    buf[:, 3] = probability
    msg.data = buf.tobytes()
    return msg


def occupancy_grid(t_s: float, prob: np.ndarray, origin: np.ndarray, cell_m: float, frame_id: str = MAP_FRAME):
    """A foxglove.Grid of occupancy probability (float32 field "occupancy"); prob is indexed [ix, iy]."""
    from foxglove_schemas_protobuf.Grid_pb2 import Grid

    rows = np.ascontiguousarray(prob.T.astype(np.float32))  # Grid rows run along y, columns along x
    msg = Grid(frame_id=frame_id, column_count=rows.shape[1], row_stride=rows.shape[1] * 4, cell_stride=4)
    msg.timestamp.CopyFrom(timestamp(t_s))
    _set_pose(msg.pose, origin[0], origin[1], 0.0)
    msg.cell_size.x = cell_m
    msg.cell_size.y = cell_m
    msg.fields.add(name="occupancy", offset=0, type=PackedElementField.FLOAT32)
    msg.data = rows.tobytes()
    return msg


def navigation_grid(
    t_s: float, state: np.ndarray, origin: tuple[float, float], cell_m: float, frame_id: str = MAP_FRAME
):
    """A foxglove.Grid with one int8 field "occupancy": 100 occupied, 0 free, -1 unknown (as a ROS
    OccupancyGrid); `state` is indexed [iy, ix] (rows along y)."""
    from foxglove_schemas_protobuf.Grid_pb2 import Grid

    rows = np.ascontiguousarray(state.astype(np.int8))
    msg = Grid(frame_id=frame_id, column_count=rows.shape[1], row_stride=rows.shape[1], cell_stride=1)
    msg.timestamp.CopyFrom(timestamp(t_s))
    _set_pose(msg.pose, origin[0], origin[1], 0.0)
    msg.cell_size.x = cell_m
    msg.cell_size.y = cell_m
    msg.fields.add(name="occupancy", offset=0, type=PackedElementField.INT8)
    msg.data = rows.tobytes()
    return msg


_NODE_FIELDS = (("x", 0, PackedElementField.FLOAT32), ("y", 4, PackedElementField.FLOAT32),
                ("z", 8, PackedElementField.FLOAT32), ("node", 12, PackedElementField.UINT32))  # fmt: skip


def node_returns_cloud(t_s: float, xy: np.ndarray, node: np.ndarray, frame_id: str = MAP_FRAME) -> PointCloud:
    """A foxglove.PointCloud of the pose graph's scans: float32 x, y, z=0 and the uint32 index of the node
    each return belongs to."""
    msg = PointCloud(frame_id=frame_id, point_stride=16)
    msg.timestamp.CopyFrom(timestamp(t_s))
    msg.pose.orientation.w = 1.0
    for name, offset, kind in _NODE_FIELDS:
        msg.fields.add(name=name, offset=offset, type=kind)
    buf = np.zeros(len(xy), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("node", "<u4")])
    buf["x"], buf["y"], buf["node"] = np.asarray(xy)[:, 0], np.asarray(xy)[:, 1], node
    msg.data = buf.tobytes()
    return msg


def node_returns_arrays(msg: PointCloud) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of `node_returns_cloud`: (xy (K, 2) float64, node (K,) int64)."""
    names = [f.name for f in msg.fields]
    if names != [n for n, _, _ in _NODE_FIELDS] or msg.point_stride != 16 or len(msg.data) % 16:
        raise ValueError("the graph's scans are not x, y, z, node points")
    buf = np.frombuffer(msg.data, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("node", "<u4")])
    return np.column_stack([buf["x"], buf["y"]]).astype(float), buf["node"].astype(np.int64)


def cloud_arrays(msg: PointCloud) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of `point_cloud`: (xy (K,2) float64, probability (K,))."""
    buf = np.frombuffer(msg.data, dtype=np.float32).reshape(-1, 4)
    return buf[:, :2].astype(float), buf[:, 3].astype(float)
