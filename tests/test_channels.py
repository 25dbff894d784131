"""The result channels' encoders: the particle encoder decodes to the message the protobuf classes build
pose by pose."""

from __future__ import annotations

import json
import math

import numpy as np

from mcaplog import channels as ch


def _built(t_s: float, poses: np.ndarray, frame_id: str) -> ch.PosesInFrame:
    """The reference: the message built with the protobuf classes, one pose at a time."""
    msg = ch.PosesInFrame(frame_id=frame_id)
    msg.timestamp.CopyFrom(ch.timestamp(t_s))
    for x, y, theta in poses:
        pose = msg.poses.add()
        pose.position.x, pose.position.y = x, y
        pose.orientation.z, pose.orientation.w = math.sin(theta / 2), math.cos(theta / 2)
    return msg


def test_poses_in_frame_bytes_decode_to_the_same_message():
    rng = np.random.default_rng(0)
    for n in (0, 1, 30):
        poses = rng.normal(size=(n, 3)) * [50.0, 50.0, 3.0]
        fast = ch.PosesInFrame.FromString(ch.poses_in_frame_bytes(976052857.337530, poses, ch.MAP_FRAME))
        assert fast == _built(976052857.337530, poses, ch.MAP_FRAME)
        np.testing.assert_allclose(ch.poses_of(fast)[:, :2], poses[:, :2], rtol=0, atol=0)
        np.testing.assert_allclose(np.cos(ch.poses_of(fast)[:, 2] - poses[:, 2]), 1.0, atol=1e-12)


def test_step_stats_are_the_bytes_json_writes() -> None:
    """The /slam/stats template writes what json.dumps writes, for every kind of number a step can give."""
    rng = np.random.default_rng(3)
    floats = [0.0, -0.0, 1.0, 1e300, 5e-324, -2.5, math.nan, math.inf, -math.inf, np.float64(12.75), 976052857.33753]
    for k in range(400):
        values = [
            int(rng.integers(0, 10**6)),
            floats[k % len(floats)] if k < 40 else float(rng.uniform(-1e9, 1e9)),
            floats[(k + 3) % len(floats)] if k < 40 else float(rng.uniform(0, 30)),
            bool(rng.random() < 0.5),
            bool(rng.random() < 0.5),
            int(rng.integers(0, 10**5)),
            int(rng.integers(0, 10**7)),
            float(rng.exponential(3.0)),
            int(rng.integers(0, 30)),
            int(rng.integers(0, 30)),
        ]
        names = list(ch.STATS_SCHEMA["properties"])
        expected = json.dumps(dict(zip(names, values, strict=True)), separators=(",", ":")).encode()
        assert ch.step_stats_json(*values) == expected
