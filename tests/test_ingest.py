"""Ingest on the shared real data: counts, values against the source files, text == .mat, CARMEN."""

from __future__ import annotations

import gzip
import math

import numpy as np
import pytest
from conftest import CARPARK, INTEL, VICTORIA, require

from ingest import ingest, read_log
from mcaplog import channels as ch
from mcaplog.mcapio import McapInput
from pipelines.evaluation.mcap_info import mcap_info


def test_carpark_text_counts_and_values(tmp_path):
    src = require(CARPARK) / "text"
    out = tmp_path / "cp.mcap"
    report = ingest(src, out)
    info = mcap_info(out)
    assert info["channels"][ch.LASER] == 586
    assert info["channels"][ch.ODOM_ACKERMANN] == 5001
    assert info["channels"][ch.GPS] == 626
    assert info["channels"][ch.LANDMARKS_TRUTH] == 1
    assert report.log.source_format == "sydney-text"
    first_drs = (src / "DRS.txt").read_text().splitlines()[0].split(",")
    last_gps = (src / "GPS.txt").read_text().splitlines()[-1].split(",")
    msgs = McapInput(out)
    odo = next(m for m in msgs.messages([ch.ODOM_ACKERMANN]))
    assert odo.value["t_s"] == pytest.approx(float(first_drs[0]))
    assert odo.value["speed_mps"] == pytest.approx(float(first_drs[1]))
    assert odo.value["steering_rad"] == pytest.approx(float(first_drs[2]))
    gps = list(msgs.messages([ch.GPS]))[-1]
    assert gps.t_s == pytest.approx(float(last_gps[0]))
    assert gps.value.pose.position.x == pytest.approx(float(last_gps[1]))
    assert gps.value.pose.position.y == pytest.approx(float(last_gps[2]))
    assert info["start_s"] == pytest.approx(45.024)
    meta = msgs.metadata()
    assert meta["dataset"]["name"] == "carpark"
    assert meta["vehicle"]["preset"] == "carpark" and meta["vehicle"]["wheelbase_m"] == 2.83
    assert meta["sensor"]["beam_count"] == 361
    assert meta["sensor"]["start_angle_rad"] == pytest.approx(-math.pi / 2)
    assert meta["sensor"]["angle_increment_rad"] == pytest.approx(math.radians(0.5))
    assert meta["sensor"]["max_range_m"] == 80.0


def test_carpark_laser_scan_message(carpark_mcap):
    src = require(CARPARK) / "text" / "LASER.txt"
    first = [float(v) for v in src.read_text().splitlines()[0].split(",")]
    scan = next(m for m in McapInput(carpark_mcap).messages([ch.LASER]))
    assert scan.t_s == pytest.approx(first[0])
    assert ch.t_of(scan.value.timestamp) == pytest.approx(first[0])
    assert scan.value.start_angle == pytest.approx(-math.pi / 2)
    assert scan.value.end_angle == pytest.approx(math.pi / 2)
    ranges = np.array(scan.value.ranges)
    expected = np.array(first[1:])
    no_return = expected >= 80.0
    assert np.isinf(ranges[no_return]).all()
    np.testing.assert_allclose(ranges[~no_return], expected[~no_return])
    assert len(scan.value.intensities) == 361


def test_text_and_mat_give_the_same_messages(tmp_path):
    a, b = tmp_path / "text.mcap", tmp_path / "mat.mcap"
    ingest(require(CARPARK) / "text", a)
    ingest(require(CARPARK), b)
    ma = list(McapInput(a).messages())
    mb = list(McapInput(b).messages())
    assert len(ma) == len(mb)
    for x, y in zip(ma, mb, strict=True):
        assert (x.topic, x.log_time_ns) == (y.topic, y.log_time_ns)
        # The text export is lossless at its stored precision (6 decimals), the .mat holds doubles.
        if x.topic == ch.LASER:
            np.testing.assert_allclose(x.value.ranges, y.value.ranges, atol=1e-9)
            np.testing.assert_allclose(x.value.intensities, y.value.intensities)
            assert (x.value.start_angle, x.value.end_angle) == (y.value.start_angle, y.value.end_angle)
        elif x.topic == ch.GPS:
            px, py = x.value.pose.position, y.value.pose.position
            assert (px.x, px.y) == pytest.approx((py.x, py.y), abs=1e-6)
        elif x.topic == ch.ODOM_ACKERMANN:
            assert x.value == pytest.approx(y.value, rel=1e-6, abs=1e-7)
        else:
            np.testing.assert_allclose(x.value["x_m"], y.value["x_m"], atol=1e-6)


def test_victoria_park_without_laser(tmp_path):
    out = tmp_path / "vp.mcap"
    report = ingest(require(VICTORIA), out)
    info = mcap_info(out)
    assert ch.LASER not in info["channels"]
    assert info["channels"][ch.ODOM_ACKERMANN] == 61945
    assert info["channels"][ch.GPS] == 4466
    assert any("no laser" in w for w in report.log.warnings)
    text = read_log(VICTORIA / "text")
    assert text.ackermann.shape == report.log.ackermann.shape
    # The published text export keeps 5 significant digits: after 1000 s its times are rounded to 0.1 s
    # (three samples share 1570.5), which ingest keeps in file order.
    np.testing.assert_allclose(text.ackermann[:, 1:], report.log.ackermann[:, 1:], rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(text.ackermann[:, 0], report.log.ackermann[:, 0], atol=0.05 + 1e-9)
    assert np.all(np.abs(text.ackermann[:1000, 0] - report.log.ackermann[:1000, 0]) < 1e-9)


def test_mit_csail_geometry_and_relations(mit_mcap):
    info = mcap_info(mit_mcap)
    assert info["channels"][ch.LASER] == 1988
    assert info["channels"][ch.RELATIONS_TRUTH] == 1
    meta = McapInput(mit_mcap).metadata()
    assert meta["sensor"]["beam_count"] == 361
    assert meta["sensor"]["angle_increment_rad"] == pytest.approx(math.radians(0.5))
    rel = next(m for m in McapInput(mit_mcap).messages([ch.RELATIONS_TRUTH])).value
    assert len(rel["t1_s"]) == 1172
    assert rel["t1_s"][0] == pytest.approx(1134864645.90321)


def test_intel_counts_backwards_times_and_geometry(tmp_path):
    out = tmp_path / "intel.mcap"
    report = ingest(require(INTEL), out)
    info = mcap_info(out)
    assert info["channels"][ch.LASER] == 13631
    assert any("631 scans have non-increasing timestamps" in w for w in report.log.warnings)
    assert report.log.geometry.beam_count == 180
    assert report.log.geometry.angle_increment_rad == pytest.approx(math.radians(1.0))
    # File order is kept: scans come back in the order of the file, with the original stamps.
    stamps = [ch.t_of(m.value.timestamp) for m in McapInput(out).messages([ch.LASER])]
    with gzip.open(INTEL, "rt") as f:  # each FLASER line's ipc_timestamp, in file order
        in_file = [float(p[int(p[1]) + 8]) for p in (ln.split() for ln in f) if p and p[0] == "FLASER"]
    np.testing.assert_allclose(stamps, in_file, rtol=0, atol=1e-6)
