"""LaserScan angles as converters print them: the increment rounded to 6 digits (a Freiburg log turned into
a ROS 1 bag states pi/180 as 0.017453, and angle_max one increment past the last beam), alone and with
two geometries interleaved on one topic. Ingest accepts them, places the beams where they truly are, and
still refuses angles that contradict the ranges (with one line)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bagtools import bag_of_scans
from hypothesis import given, settings
from hypothesis import strategies as st
from test_bad_input import assert_one_line_error
from test_rosbag_bad import assert_nothing_written, ingest_cli

from ingest.rosbag import beam_increment
from mcaplog import channels as ch
from mcaplog.mcapio import McapInput

F32 = np.float32
# The message: 180 ranges, angle_min -1.56643, angle_max 1.57516, angle_increment 0.017453.
FREIBURG = (180, -1.56643, 0.017453, 1.57516)


def decimals6(x: float) -> float:
    return round(x, 6)


def significant6(x: float) -> float:
    return float(f"{x:.6g}")


def printed(n: int, a0: float, inc: float, steps: int, fmt) -> tuple[int, float, float, float]:
    """The message a converter writes for n beams from a0 by inc, angle_max `steps` increments from a0
    (n - 1: at the last beam; n: one past it), each angle printed by `fmt`."""
    return n, fmt(a0), fmt(inc), fmt(a0 + steps * inc)


def f32(x: float) -> float:
    return float(F32(x))


def beam_angles(path) -> list[np.ndarray]:
    """Each scan's beam angles in the MCAP (foxglove.LaserScan: evenly from start_angle to end_angle)."""
    out = []
    for msg in McapInput(path).messages([ch.LASER]):
        v = msg.value
        out.append(np.linspace(v.start_angle, v.end_angle, len(v.ranges)))
    return out


def test_freiburg_bag_with_the_increment_rounded_to_6_digits_ingests(tmp_path):
    """The issue's bag: refused before (1.003 increments past the last beam). The beams are where its
    angle_min and angle_max put them, (angle_max - angle_min) / 180 apart: within 1e-6 rad of that
    geometry, and within angle_max's own rounding (2.7e-6 rad) of the 1 degree grid from angle_min;
    the message's increment would put beam 179 5e-5 rad off."""
    src = bag_of_scans(tmp_path / "freiburg.bag", [FREIBURG] * 6)
    out = tmp_path / "o.mcap"
    result = ingest_cli(src, out)
    assert result.exit_code == 0, result.output
    n, a0, inc, a1 = (FREIBURG[0], *map(f32, FREIBURG[1:]))  # a LaserScan's angles are float32
    stated = a0 + (a1 - a0) / n * np.arange(n)
    degree_grid = a0 + math.radians(1.0) * np.arange(n)
    scans = beam_angles(out)
    assert len(scans) == 6
    for got in scans:
        assert len(got) == n
        assert np.abs(got - stated).max() < 1e-6
        assert np.abs(got - degree_grid).max() < 3e-6
    assert np.abs(a0 + inc * np.arange(n) - degree_grid).max() > 5e-5  # what the message's increment gives
    sensor = McapInput(out).metadata()["sensor"]
    assert sensor["beam_count"] == n
    assert sensor["start_angle_rad"] == pytest.approx(a0, abs=1e-12)
    assert sensor["angle_increment_rad"] == pytest.approx(math.radians(1.0), abs=2e-8)
    assert sensor["end_angle_rad"] == pytest.approx(stated[-1], abs=1e-9)


# Two geometries interleaved on one topic, given truly (beams, first beam, increment, angle_max steps):
# 180 beams from -89.75 deg by 1 deg with angle_max one past the last beam (the Freiburg converter's),
# and 361 beams from -90 deg by 0.5 deg with angle_max at the last beam.
TRUE_GEOMETRIES = (
    (180, math.radians(-89.75), math.radians(1.0), 180),
    (361, -math.pi / 2, math.pi / 360, 360),
)


@pytest.mark.parametrize("upside_down", [False, True], ids=["level", "upside_down"])
@pytest.mark.parametrize("fmt", [decimals6, significant6])
def test_interleaved_geometries_with_rounded_angles_keep_their_true_beams(tmp_path, fmt, upside_down):
    """Every angle printed with 6 decimal places, or with 6 significant digits, then stored as float32.
    Each scan's beams are at their true angles within the rounding of its angle_min and angle_max: 1e-6
    rad with 6 decimals (the message's increments would put the 361-beam scan's last beam 1.3e-4 rad
    off); with 6 significant digits angle_min and angle_max themselves are up to 5e-6 rad off at +-1.57 rad,
    and the beams are within that. An upside-down laser's beams come reversed and negated."""
    messages = [printed(*g, fmt) for g in TRUE_GEOMETRIES]
    src = bag_of_scans(tmp_path / "b.bag", [messages[k % 2] for k in range(8)], upside_down=upside_down)
    out = tmp_path / "o.mcap"
    result = ingest_cli(src, out)
    assert result.exit_code == 0, result.output
    assert "interleaves 2 scan geometries" in result.output
    assert "180 beams from -89.75 deg by 1.000 deg: 4" in result.output
    assert "361 beams from -90.00 deg by 0.500 deg: 4" in result.output
    scans = beam_angles(out)
    assert len(scans) == 8
    for k, got in enumerate(scans):
        n, a0, inc, _ = TRUE_GEOMETRIES[k % 2]
        _, p0, _, p1 = messages[k % 2]
        truth = a0 + inc * np.arange(n)
        if upside_down:
            truth = -truth[::-1]
        bound = 1e-6 if fmt is decimals6 else max(abs(f32(p0) - a0), abs(f32(p1) - truth[-1]), 1e-6) + 2e-7
        assert len(got) == n
        assert np.abs(got - truth).max() < bound, (k, np.abs(got - truth).max(), bound)
    if fmt is decimals6:
        n, a0, inc, _ = TRUE_GEOMETRIES[1]
        _, p0, pinc, _ = messages[1]
        assert abs(f32(p0) + (n - 1) * f32(pinc) - (a0 + (n - 1) * inc)) > 1e-4


CONTRADICTIONS = {
    # The angles make 181.0 beams (angle_max one past the last of 180): two or more off is refused.
    "178 ranges": ((178, *FREIBURG[1:]), "makes 181.0 beams, the message has 178 ranges"),
    "183 ranges": ((183, *FREIBURG[1:]), "makes 181.0 beams, the message has 183 ranges"),
    # Increment 1 % off: 1.8 increments over 180 beams.
    "increment 1% short": ((180, -1.56643, 0.017453 * 0.99, 1.57516), "makes 182.8 beams, the message has 180"),
    "increment 1% long, angle_max at the last beam": (
        (181, -math.pi / 2, math.pi / 180 * 1.01, math.pi / 2),
        "makes 179.2 beams, the message has 181 ranges",
    ),
}


@pytest.mark.parametrize("bad", [0, 3])
@pytest.mark.parametrize("case", CONTRADICTIONS)
def test_angles_contradicting_the_ranges_are_still_refused(tmp_path, case, bad):
    """Between rounded Freiburg scans, a message whose angles contradict its ranges: one line naming it."""
    message, says = CONTRADICTIONS[case]
    scans = [message if k == bad else FREIBURG for k in range(6)]
    out = tmp_path / "o.mcap"
    result = ingest_cli(bag_of_scans(tmp_path / "b.bag", scans), out)
    assert_one_line_error(result, f"/scan message {bad}: angle_increment", "disagrees with the ranges", says)
    assert_nothing_written(out)


LASERS = (
    # (beams, first beam, increment): SICK LMS 1 deg and 0.5 deg, Hokuyo UTM-30LX, 360 deg lidars
    (180, math.radians(-89.75), math.radians(1.0)),
    (181, -math.pi / 2, math.pi / 180),
    (361, -math.pi / 2, math.pi / 360),
    (541, math.radians(-135.0), math.radians(0.5)),
    (1081, math.radians(-135.0), math.radians(0.25)),
    (720, -math.pi, 2 * math.pi / 720),
    (1440, -math.pi, 2 * math.pi / 1440),
    (2, -0.5, 1.0),
)
PRINTS = {"exact": lambda x: x, "float32": f32, "6 decimals": decimals6, "6 significant": significant6}


@settings(max_examples=300, deadline=None)
@given(
    laser=st.sampled_from(LASERS),
    fmt=st.sampled_from(sorted(PRINTS)),
    past=st.booleans(),
    sign=st.sampled_from([1, -1]),
)
def test_rounded_angles_give_the_true_increment_and_contradictions_stay_refused(laser, fmt, past, sign):
    """Any common laser, counter-clockwise or clockwise, angle_max at or one past the last beam, printed
    exactly, as float32, with 6 decimals or 6 significant digits: accepted, with an increment that puts
    the last beam (and so every beam: the error is linear in the beam index) within the rounding of
    angle_min and angle_max, whatever the beam count (the message's increment puts it up to the beam count
    times the increment's rounding off); two ranges more or fewer than the angles make: refused."""
    n, a0, inc = laser
    a0, inc = sign * a0, sign * inc
    steps = n if past else n - 1
    p = PRINTS[fmt]
    m0, minc, m1 = f32(p(a0)), f32(p(inc)), f32(p(a0 + steps * inc))
    used = beam_increment(n, m0, m1, minc)
    assert used is not None
    last = a0 + (n - 1) * inc
    rounding = max(abs(m0 - a0), abs(m1 - (a0 + steps * inc)))
    assert abs(m0 + (n - 1) * used - last) <= rounding + 1e-9
    implied = steps + 1
    for wrong in (implied - 2, implied + 2):
        if wrong >= 2:
            assert beam_increment(wrong, m0, m1, minc) is None, wrong


def test_an_exact_message_keeps_its_increment():
    """A driver's exact message: its own increment (to float precision); angle_max off the beams' grid
    (half an increment past the last beam): the message's increment as written."""
    inc = f32(math.radians(0.25))
    a0 = f32(math.radians(-135.0))
    assert beam_increment(1081, a0, f32(a0 + 1080 * inc), inc) == pytest.approx(inc, rel=1e-6)
    assert beam_increment(1081, a0, a0 + 1080.5 * inc, inc) == inc
