"""The laser's mount: planar pose composition, the mount from metadata and /tf, and the runner's motion
composed in the base frame."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gslam.motion import apply_odometry, odometry_delta
from gslam.se2 import compose, compose_inverse, inverse
from ingest.textlog import IngestError
from ingest.tf import FrameTree, Transform, planar_mount, quaternion_matrix
from pipelines.run.mount import LaserMount

pose = st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-math.pi, math.pi)).map(
    lambda t: np.array(t, dtype=float)
)


@settings(max_examples=60, deadline=None)
@given(pose, pose, pose)
def test_composition_is_associative_with_an_inverse(a, b, c):
    np.testing.assert_allclose(compose(compose(a, b), c), compose(a, compose(b, c)), atol=1e-9)
    np.testing.assert_allclose(compose(a, inverse(a)), np.zeros(3), atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(pose, pose)
def test_compose_inverse_of_one_pose_is_the_array_formula(a, b):
    got = np.array(compose_inverse(tuple(a), tuple(b)))
    want = compose(a, inverse(b))
    np.testing.assert_allclose(got[:2], want[:2], atol=1e-9)
    assert abs((got[2] - want[2] + math.pi) % (2 * math.pi) - math.pi) < 1e-12


def test_compose_by_hand():
    # A robot at (1, 2) facing +y; a laser 0.3 m ahead of it is at (1, 2.3), turned with it.
    np.testing.assert_allclose(
        compose(np.array([1.0, 2.0, math.pi / 2]), np.array([0.3, 0.0, 0.1])), [1.0, 2.3, math.pi / 2 + 0.1], atol=1e-12
    )


def test_mount_from_metadata():
    assert LaserMount.from_sensor({}) is None
    assert LaserMount.from_sensor({"mount": {"x_m": 0.0, "y_m": 0.0, "yaw_rad": 0.0}}) is None
    m = LaserMount.from_sensor({"mount": {"x_m": 0.3, "y_m": 0.0, "yaw_rad": 0.4, "base_frame": "base_link"}})
    assert m.base_frame == "base_link"
    base = np.array([[1.0, 1.0, 0.2], [-3.0, 4.0, 3.0]])
    np.testing.assert_allclose(m.base_of(m.laser_of(base)), base, atol=1e-12)


def test_odometry_composed_in_the_base_frame_moves_the_laser_rigidly():
    """A base turning on the spot carries a laser 0.3 m ahead round a circle; noise-free, the laser poses
    the runner's motion gives are exactly base (+) mount."""
    m = LaserMount(0.3, 0.0, 0.4)
    b0, b1 = np.array([2.0, 1.0, 0.0]), np.array([2.0, 1.0, 1.2])
    laser0 = m.laser_of(b0)[None]
    moved = m.laser_of(apply_odometry(m.base_of(laser0), odometry_delta(b0, b1), None, (0.1, 0.1, 0.1, 0.1)))
    np.testing.assert_allclose(moved[0], m.laser_of(b1), atol=1e-12)
    assert math.hypot(*(moved[0, :2] - b1[:2])) == pytest.approx(0.3)


def test_tf_chain_and_planar_projection():
    tree = FrameTree()
    q = (0.0, 0.0, math.sin(0.25), math.cos(0.25))  # yaw 0.5
    tree.add("/base_link", "mount_plate", Transform(np.eye(3), np.array([0.2, 0.0, 0.3])))
    tree.add("mount_plate", "laser", Transform(quaternion_matrix(*q), np.array([0.1, 0.05, 0.0])))
    t = tree.chain("base_link", "laser")
    m = planar_mount(t, "test")
    assert (m.x_m, m.y_m, m.yaw_rad, m.upside_down) == pytest.approx((0.3, 0.05, 0.5, False))
    assert tree.chain("odom", "laser") is None
    assert tree.path_up("laser") == ["laser", "mount_plate", "base_link"]


def test_upside_down_and_tilted_lasers():
    # Rz(0.3) Rx(pi): the laser's z axis points down.
    cz, sz = math.cos(0.15), math.sin(0.15)
    q = (cz, sz, 0.0, 0.0)  # x, y, z, w of Rz(0.3) Rx(pi) = (cos(a/2), sin(a/2), 0, 0)
    m = planar_mount(Transform(quaternion_matrix(*q), np.zeros(3)), "t")
    assert m.upside_down and m.yaw_rad == pytest.approx(0.3)
    tilt = (math.sin(math.radians(15) / 2), 0.0, 0.0, math.cos(math.radians(15) / 2))  # 15 deg roll
    with pytest.raises(IngestError, match="tilted 15.0 deg"):
        planar_mount(Transform(quaternion_matrix(*tilt), np.zeros(3)), "t")
