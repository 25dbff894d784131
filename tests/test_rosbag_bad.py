"""Bad ROS bags: one clear line, a non-zero exit, no traceback, and no output left behind."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from bagtools import BagBuilder
from test_bad_input import assert_one_line_error, run_cli

from ingest import ingest
from mcaplog import channels as ch
from mcaplog.mcapio import McapInput

T0 = 1_700_000_000 * 10**9
BEAMS = 181
INC = math.pi / (BEAMS - 1)


def small_bag(
    path,
    kind: str = "ros1",
    scans: int = 6,
    scan_topics: tuple[str, ...] = ("/scan",),
    odom_topics: tuple[str, ...] = ("/odom",),
    odom_offset_s: float = 0.0,
    tf_static: bool = True,
    bad_scan: int | None = None,
):
    """Scans at 5 Hz, odometry at 10 Hz around them (shifted by `odom_offset_s`), base_link -> laser on
    /tf_static; scan `bad_scan` gets an angle_max one increment short per ... (a broken message)."""
    ranges = np.full(BEAMS, 4.0)
    with BagBuilder(path, kind) as bag:
        if tf_static:
            bag.tf(T0 - 10**8, [("base_link", "laser", 0.1, 0.0, 0.0)], static=True)
        events = []
        for k in range(2 * scans + 2):
            t = T0 + int((k * 0.1 + odom_offset_s) * 1e9)
            events += [(t, 0, topic, None) for topic in odom_topics]
        for k in range(scans):
            t = T0 + int((k * 0.2 + 0.05) * 1e9)
            events += [(t, 1, topic, k) for topic in scan_topics]
        for t, _, topic, k in sorted(events, key=lambda e: (e[0], e[1])):
            if k is None:
                bag.odometry(t, (t - T0) / 1e9 * 0.5, 0.0, 0.0, topic=topic)
            elif k == bad_scan:
                bag.laser_scan(t, ranges[:-30], -math.pi / 2, INC, angle_max=math.pi / 2, topic=topic)
            else:
                bag.laser_scan(t, ranges, -math.pi / 2, INC, topic=topic)
    return path


def ingest_cli(src, out, *extra):
    return run_cli("ingest", str(src), "-o", str(out), *extra)


def assert_nothing_written(out) -> None:
    assert not out.exists()
    assert not list(out.parent.glob(f".{out.name}*")), "temporary file left behind"


def test_a_good_small_bag_ingests(tmp_path):
    """The base case the bad ones break: every scan gets its interpolated odometry."""
    report = ingest(small_bag(tmp_path / "good.bag"), tmp_path / "good.mcap")
    assert report.counts == {ch.ODOM_POSE: 6, ch.ODOM: 6, ch.LASER: 6}
    odom = [m.value for m in McapInput(tmp_path / "good.mcap").messages([ch.ODOM_POSE])]
    # The same poses as foxglove.PoseInFrame in the odom frame, for viewers.
    shown = [m.value for m in McapInput(tmp_path / "good.mcap").messages([ch.ODOM])]
    assert {p.frame_id for p in shown} == {"odom"}
    np.testing.assert_allclose([p.pose.position.x for p in shown], [o["x_m"] for o in odom], atol=1e-12)
    # Odometry x = 0.5 m/s * t; scans at 0.05 s + 0.2 k: interpolated between the 10 Hz samples.
    np.testing.assert_allclose([o["x_m"] for o in odom], [0.5 * (0.05 + 0.2 * k) for k in range(6)], atol=1e-9)
    assert {o["source"] for o in odom} == {"interpolated"}


def test_not_a_bag(tmp_path):
    for name in ("notes.bag", "notes.db3", "notes.mcap"):
        src = tmp_path / name
        src.write_text("just some text\n")
        out = tmp_path / "o.mcap"
        assert_one_line_error(ingest_cli(src, out), name, "not a readable ROS bag")
        assert_nothing_written(out)


@pytest.mark.parametrize("kind", ["ros1", "mcap", "sqlite3"])
def test_truncated_bag(tmp_path, kind):
    path = small_bag(tmp_path / ("b.bag" if kind == "ros1" else "b"), kind, scans=30)
    if kind != "ros1":
        path = next(p for p in path.iterdir() if p.suffix in (".mcap", ".db3"))  # the storage file alone
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * 0.6)])
    out = tmp_path / "o.mcap"
    result = ingest_cli(path, out)
    assert_one_line_error(result, path.name)
    assert "not a readable ROS bag" in result.output or "truncated" in result.output
    assert_nothing_written(out)


def test_damaged_bag_fails_mid_stream_with_the_message_index(tmp_path):
    """A bag whose index opens but whose data is damaged fails where the damage is; the MCAP written up
    to there is dropped."""
    path = small_bag(tmp_path / "b.bag", scans=60)
    data = bytearray(path.read_bytes())
    at = int(len(data) * 0.4)
    data[at : at + 64] = b"\xff" * 64
    path.write_bytes(bytes(data))
    out = tmp_path / "o.mcap"
    result = ingest_cli(path, out)
    assert_one_line_error(result, "b.bag: /odom message ", "unreadable, damaged or truncated bag")
    assert re.search(r"/odom message \d+: ", result.output)
    assert_nothing_written(out)


def test_no_laser_scan_topic(tmp_path):
    src = small_bag(tmp_path / "b.bag", scan_topics=())
    out = tmp_path / "o.mcap"
    assert_one_line_error(
        ingest_cli(src, out), "no sensor_msgs/msg/LaserScan topic", "/odom (nav_msgs/msg/Odometry, 14 messages)"
    )
    assert_nothing_written(out)


def test_several_scan_topics_need_a_choice(tmp_path):
    src = small_bag(tmp_path / "b.bag", scan_topics=("/scan", "/scan_rear"))
    out = tmp_path / "o.mcap"
    assert_one_line_error(
        ingest_cli(src, out),
        "2 sensor_msgs/msg/LaserScan topics, choose one with --scan-topic",
        "/scan (sensor_msgs/msg/LaserScan, 6 messages), /scan_rear (sensor_msgs/msg/LaserScan, 6 messages)",
    )
    assert_nothing_written(out)
    assert_one_line_error(ingest_cli(src, out, "--scan-topic", "/nope"), "--scan-topic /nope: no such topic")
    assert_one_line_error(ingest_cli(src, out, "--scan-topic", "/odom"), "is nav_msgs/msg/Odometry, not")
    result = ingest_cli(src, out, "--scan-topic", "/scan_rear")
    assert result.exit_code == 0, result.output
    assert McapInput(out).metadata()["bag"]["scan_topic"] == "/scan_rear"


def test_several_odometry_topics_need_a_choice(tmp_path):
    src = small_bag(tmp_path / "b.bag", odom_topics=("/odom", "/wheel_odom"))
    assert_one_line_error(ingest_cli(src, tmp_path / "o.mcap"), "choose one with --odom-topic", "/wheel_odom")
    assert ingest_cli(src, tmp_path / "o.mcap", "--odom-topic", "/wheel_odom").exit_code == 0


@pytest.mark.parametrize("bad", [0, 3])
def test_angle_increment_disagrees_with_ranges(tmp_path, bad):
    src = small_bag(tmp_path / "b.bag", bad_scan=bad)
    out = tmp_path / "o.mcap"
    assert_one_line_error(
        ingest_cli(src, out), f"/scan message {bad}", "angle_increment", "181.0 beams, the message has 151 ranges"
    )
    assert_nothing_written(out)


def test_odometry_never_overlaps_the_scans(tmp_path):
    src = small_bag(tmp_path / "b.bag", odom_offset_s=100.0)
    out = tmp_path / "o.mcap"
    assert_one_line_error(ingest_cli(src, out), "odometry never overlaps the scans in time", "/odom", "/scan")
    assert_nothing_written(out)


def test_missing_mount_transform(tmp_path):
    src = small_bag(tmp_path / "b.bag", tf_static=False)
    out = tmp_path / "o.mcap"
    assert_one_line_error(ingest_cli(src, out), "missing transform base_link -> laser", "/tf_static")
    assert_nothing_written(out)


def test_tf_without_an_odom_frame(tmp_path):
    """Odometry from /tf needs the odom frame (REP 105) above the laser, or --base-frame."""
    with BagBuilder(tmp_path / "b.bag", "ros1") as bag:
        bag.tf(T0, [("base_link", "laser", 0.0, 0.0, 0.0)], static=True)
        for k in range(8):
            bag.tf(T0 + k * 10**8, [("world", "base_link", 0.1 * k, 0.0, 0.0)])
            bag.laser_scan(T0 + k * 10**8 + 1, np.full(BEAMS, 3.0), -math.pi / 2, INC)
    out = tmp_path / "o.mcap"
    assert_one_line_error(ingest_cli(tmp_path / "b.bag", out), "no odom frame above the laser frame laser")
    result = ingest_cli(tmp_path / "b.bag", out, "--base-frame", "base_link")
    assert result.exit_code == 0, result.output
    assert McapInput(out).metadata()["bag"]["odometry"] == "/tf (world -> base_link)"


def test_bag_options_on_other_logs(tmp_path):
    log = tmp_path / "x.clf"
    log.write_text("FLASER 2 1.0 1.0 0 0 0 0 0 0 1.0 host 1.0\n")
    assert_one_line_error(ingest_cli(log, tmp_path / "o.mcap", "--scan-topic", "/scan"), "apply to ROS bags only")
