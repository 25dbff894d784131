"""The result's per-step messages (foxglove.PoseInFrame, FrameTransforms, LaserScan) encoded straight to
protobuf wire bytes, without building message objects.

`gslam process` writes three of these for every scan; building them as protobuf objects field by field
cost more than writing them (tens of microseconds a scan). The bytes are those protobuf's own serialiser
writes for the messages `mcaplog.channels` builds (fields in number order, proto3 defaults left out, every
sub-message the builders set written even when empty): tests/test_wire.py holds them equal. The field
numbers are read from the schemas' descriptors at import, so a schema that moved a field fails here.
"""

from __future__ import annotations

import math
import struct

import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LaserScan_pb2 import LaserScan
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp

from mcaplog.channels import seconds_nanos

_DOUBLE = struct.Struct("<d")


def _numbers(message: type, names: str) -> list[int]:
    fields = message.DESCRIPTOR.fields_by_name
    return [fields[name].number for name in names.split()]


assert _numbers(Timestamp, "seconds nanos") == [1, 2]
assert _numbers(Vector3, "x y z") == [1, 2, 3] and _numbers(Quaternion, "x y z w") == [1, 2, 3, 4]
assert _numbers(Pose, "position orientation") == [1, 2]
assert _numbers(PoseInFrame, "timestamp frame_id pose") == [1, 2, 3]
assert _numbers(FrameTransforms, "transforms") == [1]
assert _numbers(FrameTransform, "timestamp parent_frame_id child_frame_id translation rotation") == [1, 2, 3, 4, 5]
assert _numbers(LaserScan, "timestamp frame_id pose start_angle end_angle ranges intensities") == [1, 2, 3, 4, 5, 6, 7]


def _varint(value: int) -> bytes:
    value &= (1 << 64) - 1  # a negative int64 as its two's complement
    out = bytearray()
    while value >= 0x80:
        out.append(value & 0x7F | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def _submessage(field: int, payload: bytes) -> bytes:
    """A length-delimited field (a sub-message, a string, a packed array): written even when empty."""
    return bytes((field << 3 | 2,)) + _varint(len(payload)) + payload


def _string(field: int, text: str) -> bytes:
    return _submessage(field, text.encode()) if text else b""


def _double(field: int, value: float) -> bytes:
    value = float(value)
    if value == 0.0 and math.copysign(1.0, value) > 0:
        return b""  # +0.0 is the default (a -0.0 is written, as protobuf does)
    return bytes((field << 3 | 1,)) + _DOUBLE.pack(value)


def _int(field: int, value: int) -> bytes:
    return bytes((field << 3,)) + _varint(value) if value else b""


def timestamp(t_s: float) -> bytes:
    """A google.protobuf.Timestamp's payload, rounded as `mcaplog.channels.timestamp`."""
    sec, nanos = seconds_nanos(t_s)
    return _int(1, sec) + _int(2, nanos)


def _planar(x: float, y: float, yaw: float) -> tuple[bytes, bytes]:
    """The payloads of a foxglove.Vector3 (x, y, 0) and a Quaternion (a turn of `yaw` about z): a pose in
    the plane (as `mcaplog.channels._set_pose`) or a transform's translation and rotation."""
    return _double(1, x) + _double(2, y), _double(3, math.sin(yaw / 2)) + _double(4, math.cos(yaw / 2))


def pose_in_frame(t_s: float, x: float, y: float, yaw: float, frame_id: str) -> bytes:
    """`mcaplog.channels.pose_in_frame`, serialised."""
    position, orientation = _planar(x, y, yaw)
    pose = _submessage(1, position) + _submessage(2, orientation)
    return _submessage(1, timestamp(t_s)) + _string(2, frame_id) + _submessage(3, pose)


def frame_transforms(t_s: float, links: list[tuple[str, str, float, float, float]]) -> bytes:
    """`mcaplog.channels.frame_transforms`, serialised."""
    stamp = _submessage(1, timestamp(t_s))
    out = b""
    for parent, child, x, y, yaw in links:
        translation, rotation = _planar(x, y, yaw)
        transform = stamp + _string(2, parent) + _string(3, child)
        out += _submessage(1, transform + _submessage(4, translation) + _submessage(5, rotation))
    return out


_IDENTITY_POSE = _submessage(3, _submessage(2, _double(4, 1.0)))  # orientation w = 1, nothing else set


def laser_scan(
    t_s: float,
    ranges_m: np.ndarray,
    angles_rad: tuple[float, float],
    frame_id: str,
    intensities: np.ndarray | None = None,
) -> bytes:
    """`mcaplog.channels.laser_scan` of beams from angles_rad[0] to angles_rad[1], serialised: the ranges (and
    intensities) as packed arrays of doubles."""
    start_angle_rad, end_angle_rad = angles_rad
    out = _submessage(1, timestamp(t_s)) + _string(2, frame_id) + _IDENTITY_POSE
    out += _double(4, start_angle_rad) + _double(5, end_angle_rad)
    for field, values in ((6, ranges_m), (7, intensities)):
        if values is not None and len(values):
            out += _submessage(field, np.asarray(values, dtype="<f8").tobytes())
    return out
