"""The result channels' encoders: the fast particle encoder decodes to the message the protobuf classes
build, pose for pose."""

from __future__ import annotations

import numpy as np

from mcaplog import channels as ch


def test_poses_in_frame_bytes_decode_to_the_same_message():
    rng = np.random.default_rng(0)
    for n in (0, 1, 30):
        poses = rng.normal(size=(n, 3)) * [50.0, 50.0, 3.0]
        built = ch.poses_in_frame(976052857.337530, poses, ch.MAP_FRAME)
        fast = ch.PosesInFrame.FromString(ch.poses_in_frame_bytes(976052857.337530, poses, ch.MAP_FRAME))
        assert fast == built
        np.testing.assert_allclose(ch.poses_of(fast)[:, :2], poses[:, :2], rtol=0, atol=0)
        np.testing.assert_allclose(np.cos(ch.poses_of(fast)[:, 2] - poses[:, 2]), 1.0, atol=1e-12)
