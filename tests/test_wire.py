"""mcaplog.wire: the per-step messages encoded without message objects are the bytes protobuf writes for
the messages mcaplog.channels builds."""

from __future__ import annotations

import math

import numpy as np
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms

from mcaplog import channels as ch
from mcaplog import wire


def _cases(n: int, seed: int):
    rng = np.random.default_rng(seed)
    fixed = [(0.0, 0.0, 0.0, 0.0), (1e9 + 0.9999999999, -3.5, 2.25, math.pi), (12.0, 1e-300, -0.0, -math.pi / 2)]
    drawn = [
        (float(rng.uniform(0, 2e9)), *map(float, rng.normal(0, 50, 2)), float(rng.uniform(-4, 4))) for _ in range(n)
    ]
    return fixed + drawn


def test_poses_and_transforms_are_the_bytes_protobuf_writes() -> None:
    for t, x, y, yaw in _cases(200, seed=0):
        assert wire.pose_in_frame(t, x, y, yaw, "map") == ch.pose_in_frame(t, x, y, yaw, "map").SerializeToString()
        links = [("map", "odom", x, y, yaw), ("odom", "base_link", -y, x, -yaw), ("base_link", "laser", 0.0, 0.0, 0.0)]
        assert wire.frame_transforms(t, links) == ch.frame_transforms(t, links).SerializeToString()


def test_scans_are_the_bytes_protobuf_writes() -> None:
    rng = np.random.default_rng(1)
    for t, _, _, yaw in _cases(50, seed=2):
        ranges = rng.uniform(0, 80, int(rng.integers(0, 400)))
        ranges[rng.random(len(ranges)) < 0.2] = np.inf  # no return
        inten = rng.uniform(0, 1000, len(ranges)) if rng.random() < 0.5 else None
        got = wire.laser_scan(t, ranges, (-abs(yaw), abs(yaw)), "laser", inten)
        assert got == ch.laser_scan(t, ranges, -abs(yaw), abs(yaw), inten, "laser").SerializeToString()


def test_a_transform_decodes_to_its_links() -> None:
    msg = FrameTransforms()
    msg.ParseFromString(wire.frame_transforms(5.25, [("map", "odom", 1.5, -2.0, 0.3)]))
    (tf,) = msg.transforms
    assert (tf.parent_frame_id, tf.child_frame_id) == ("map", "odom")
    assert (tf.timestamp.seconds, tf.timestamp.nanos) == (5, 250_000_000)
    assert (tf.translation.x, tf.translation.y, tf.translation.z) == (1.5, -2.0, 0.0)
    assert math.isclose(2 * math.atan2(tf.rotation.z, tf.rotation.w), 0.3)


def test_links_that_differ_only_in_a_signed_zero_keep_their_own_bytes() -> None:
    """A link with a zero in its pose is kept once encoded (a mount's, the same at every step): +0.0 is left
    out on the wire and -0.0 written, so the two must not share the kept bytes."""
    for x, yaw in [(0.0, 0.0), (-0.0, 0.0), (0.0, -0.0), (0.0, 0.0), (0.25, -0.0), (0.25, 0.0)]:
        links = [("base_link", "laser", x, 0.0, yaw)]
        assert wire.frame_transforms(7.5, links) == ch.frame_transforms(7.5, links).SerializeToString()
