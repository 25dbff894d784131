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
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp

_DOUBLE = struct.Struct("<d")


def seconds_nanos(t_s: float) -> tuple[int, int]:
    """A time in seconds as a Timestamp's whole seconds and nanoseconds (rounded, below one second); the
    one rounding rule of both encoders (`mcaplog.channels.timestamp` builds the message from it)."""
    sec = math.floor(t_s)
    return int(sec), min(int(round((t_s - sec) * 1e9)), 999_999_999)


def _numbers(message: type, names: str) -> list[int]:
    fields = message.DESCRIPTOR.fields_by_name
    return [fields[name].number for name in names.split()]


assert _numbers(Timestamp, "seconds nanos") == [1, 2]
assert _numbers(Vector3, "x y z") == [1, 2, 3] and _numbers(Quaternion, "x y z w") == [1, 2, 3, 4]
assert _numbers(Pose, "position orientation") == [1, 2]
assert _numbers(PoseInFrame, "timestamp frame_id pose") == [1, 2, 3]
assert _numbers(PosesInFrame, "timestamp frame_id poses") == [1, 2, 3]
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


_last_stamp: tuple[float, bytes] = (math.nan, b"")


def _stamp(t_s: float) -> bytes:
    """The Timestamp of `t_s` as field 1 of its message (every message here has it there). A step writes
    several messages at one time: the last one is kept."""
    global _last_stamp
    last_t, field = _last_stamp
    if t_s != last_t:
        field = _submessage(1, timestamp(t_s))
        _last_stamp = (t_s, field)
    return field


_STRINGS: dict[tuple[int, str], bytes] = {}


def _name(field: int, text: str) -> bytes:
    """`_string` of a frame name, kept: a run names a handful of frames, thousands of times."""
    out = _STRINGS.get((field, text))
    if out is None:
        out = _STRINGS[(field, text)] = _string(field, text)
    return out


def _planar(x: float, y: float, qz: float, qw: float) -> tuple[bytes, bytes]:
    """The payloads of a foxglove.Vector3 (x, y, 0) and a Quaternion (0, 0, qz, qw): a pose in the plane
    (as `mcaplog.channels._set_pose`) or a transform's translation and rotation."""
    return _double(1, x) + _double(2, y), _double(3, qz) + _double(4, qw)


_PLANAR = struct.Struct("<3sd1sd3sd1sd")
"""Two length-delimited fields of 18 bytes: a Vector3 (x, y) and a Quaternion (z, w), each with its four
doubles written, which is every pose and transform whose numbers are all non-zero: their tags and
lengths come as the format's byte strings (`_POSE_TAGS`, `_TRANSFORM_TAGS`)."""
_POSE_TAGS = (b"\x0a\x12\x09", b"\x11", b"\x12\x12\x19", b"\x21")  # Pose: position 1, orientation 2
_TRANSFORM_TAGS = (b"\x22\x12\x09", b"\x11", b"\x2a\x12\x19", b"\x21")  # translation 4, rotation 5


def _pose_fields(x: float, y: float, yaw: float, tags: tuple[bytes, ...]) -> bytes:
    """The position / translation field, then the orientation / rotation field, of a planar pose."""
    half = yaw / 2
    qz, qw = math.sin(half), math.cos(half)
    if x and y and qz and qw:  # no zero (+0.0 is left out, -0.0 written): the fixed layout
        a, b, c, d = tags
        return _PLANAR.pack(a, x, b, y, c, qz, d, qw)
    position, orientation = _planar(x, y, qz, qw)
    field = tags[0][0] >> 3
    return _submessage(field, position) + _submessage(field + 1, orientation)


def head(t_s: float, frame_id: str) -> bytes:
    """The timestamp and frame_id fields (1 and 2) a foxglove.PoseInFrame or PosesInFrame begins with."""
    return _stamp(t_s) + _name(2, frame_id)


def pose_in_frame(t_s: float, x: float, y: float, yaw: float, frame_id: str) -> bytes:
    """`mcaplog.channels.pose_in_frame`, serialised."""
    pose = _pose_fields(x, y, yaw, _POSE_TAGS)
    return head(t_s, frame_id) + bytes((3 << 3 | 2,)) + _varint(len(pose)) + pose


def frame_transforms(t_s: float, links: list[tuple[str, str, float, float, float]]) -> bytes:
    """`mcaplog.channels.frame_transforms`, serialised."""
    stamp = _stamp(t_s)
    out = []
    for parent, child, x, y, yaw in links:
        if x and y and yaw:
            body = _name(2, parent) + _name(3, child) + _pose_fields(x, y, yaw, _TRANSFORM_TAGS)
        else:  # a zero in the pose: a mount straight ahead or on the axis, the same link at every step
            key = (parent, child, _TRIPLE.pack(x, y, yaw))  # the bytes: -0.0 is not +0.0 on the wire
            body = _FIXED_LINKS.get(key)
            if body is None:
                body = _name(2, parent) + _name(3, child) + _pose_fields(x, y, yaw, _TRANSFORM_TAGS)
                if len(_FIXED_LINKS) < 64:
                    _FIXED_LINKS[key] = body
        out.append(_submessage(1, stamp + body))
    return b"".join(out)


_TRIPLE = struct.Struct("<3d")
_FIXED_LINKS: dict[tuple[str, str, bytes], bytes] = {}
"""The bytes after the timestamp of the links with a zero in their pose, by frames and pose."""


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
    out = _stamp(t_s) + _name(2, frame_id) + _IDENTITY_POSE
    out += _double(4, start_angle_rad) + _double(5, end_angle_rad)
    for field, values in ((6, ranges_m), (7, intensities)):
        if values is not None and len(values):
            out += _submessage(field, np.asarray(values, dtype="<f8").tobytes())
    return out
