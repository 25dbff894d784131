"""Bags as real drivers write them: a laser that interleaves four scan geometries (181 beams from -90 deg,
180 beams from -89.75, -89.5 and -89.25 deg, one degree apart), `angle_max` one increment past the last
beam, NaN, -inf and out-of-range readings, and a `range_max` that changes between messages. Ingest keeps
each scan's own beams and warns once with the counts; the map and the path come out right."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bagtools import BagBuilder
from typer.testing import CliRunner
from worlds import corridor_world, simulate_robot_loop

from mcaplog import channels as ch
from mcaplog.mcapio import McapInput
from pipelines.cli.app import app
from pipelines.demo.world import distance_to_obstacles, ray_cast
from pipelines.evaluation.evaluate import read_result

STARTS_DEG = (-90.0, -89.75, -89.5, -89.25)
RANGE_MAX_M = (12.0, 10.0)


def _interleaved_bag(path, sim, world, rng) -> dict[int, int]:
    """The drive of `sim` as a ROS 1 bag whose scan k has geometry k mod 4 and range_max k mod 2; returns
    the scans per beam count."""
    t_ns = np.round((1000.0 + sim.t_s) * 1e9).astype(np.int64)
    counts: dict[int, int] = {}
    with BagBuilder(path, "ros1") as bag:
        bag.tf(int(t_ns[0]) - 1000, [("base_link", "laser", 0.0, 0.0, 0.0, 0.2)], static=True)
        for k in range(len(t_ns)):
            bag.odometry(int(t_ns[k]), *sim.odometry[k])
            start = math.radians(STARTS_DEG[k % 4])
            inc = math.radians(1.0)
            n = 181 if k % 4 == 0 else 180
            bearings = start + inc * np.arange(n)
            r_max = RANGE_MAX_M[k % 2]
            r = ray_cast(world, sim.truth[k, :2], sim.truth[k, 2] + bearings, r_max)
            r = np.where(np.isfinite(r), r + rng.normal(0, 0.01, n), np.inf)
            odd = rng.random(n)
            r = np.where(odd < 0.01, np.nan, r)
            r = np.where((odd >= 0.01) & (odd < 0.015), -np.inf, r)
            r = np.where((odd >= 0.015) & (odd < 0.02), 50.0, r)  # beyond range_max: no return
            # angle_max one increment past the last beam, as some drivers state it
            bag.laser_scan(int(t_ns[k]), r, start, inc, angle_max=start + n * inc, range_max=r_max, range_min=0.05)
            counts[n] = counts.get(n, 0) + 1
    return counts


@pytest.fixture(scope="module")
def interleaved(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("interleaved")
    world = corridor_world()
    rng = np.random.default_rng(3)
    sim = simulate_robot_loop(world, rng)
    counts = _interleaved_bag(tmp / "robot.bag", sim, world, rng)
    cli = CliRunner()
    ingest = cli.invoke(app, ["ingest", str(tmp / "robot.bag"), "-o", str(tmp / "in.mcap")])
    assert ingest.exit_code == 0, ingest.output
    run = cli.invoke(app, ["process", str(tmp / "in.mcap"), str(tmp / "out.mcap"), "--occupancy"])
    assert run.exit_code == 0, run.output
    return tmp, world, sim, counts, ingest.output


def test_ingest_keeps_each_scans_geometry_and_warns_once_with_the_counts(interleaved):
    tmp, _, sim, counts, output = interleaved
    warnings = [line for line in output.splitlines() if "interleaves" in line]
    assert len(warnings) == 1 and "4 scan geometries" in warnings[0], output
    n = len(sim.t_s)
    assert f"181 beams from -90.00 deg by 1.000 deg: {len(range(0, n, 4))}" in warnings[0]
    assert f"180 beams from -89.75 deg by 1.000 deg: {len(range(1, n, 4))}" in warnings[0]
    assert "range_max differs between messages (10 m:" in output
    assert "NaN or below their message's range_min" in output
    seen = {}
    for msg in McapInput(tmp / "in.mcap").messages([ch.LASER]):
        v = msg.value
        n = len(v.ranges)
        inc = (v.end_angle - v.start_angle) / (n - 1)
        assert inc == pytest.approx(math.radians(1.0), abs=1e-6)  # angle_max's extra increment is not a beam
        seen.setdefault(round(math.degrees(v.start_angle), 4), set()).add(n)  # ROS angles are float32
    assert seen == {-90.0: {181}, -89.75: {180}, -89.5: {180}, -89.25: {180}}
    assert sum(counts.values()) == len(sim.t_s)


def test_the_filter_maps_interleaved_scans_onto_the_walls_and_follows_the_robot(interleaved):
    tmp, world, sim, _, _ = interleaved
    res = read_result(tmp / "out.mcap")
    err = np.hypot(*(res.trajectory[:, :2] - sim.truth[:, :2]).T)
    odo_err = np.hypot(*(sim.odometry[:, :2] - sim.truth[:, :2]).T)
    assert odo_err.mean() > 0.5  # the odometry drifts: the filter has work to do
    assert err.mean() < 0.2 and err.max() < 0.4, (err.mean(), err.max())
    xy = res.map_xy[res.map_p > 0.5]
    d = distance_to_obstacles(world, xy)
    assert len(xy) > 500
    assert np.median(d) < 0.05 and np.quantile(d, 0.9) < 0.15, (np.median(d), np.quantile(d, 0.9))
    assert ch.MAP_OCCUPANCY in {c.topic for c in McapInput(tmp / "out.mcap").summary().channels.values()}


def test_the_run_reads_every_scan_with_its_own_beams(interleaved):
    from pipelines.run.input_log import InputLog, ScanEvent

    tmp, _, sim, _, _ = interleaved
    log = InputLog(tmp / "in.mcap")
    scans = [ev for ev in log.events() if isinstance(ev, ScanEvent)]
    starts = [round(math.degrees(ev.geometry.start_angle_rad), 4) for ev in scans]
    assert starts[:8] == [*STARTS_DEG, *STARTS_DEG] and len(scans) == len(sim.t_s)
    assert all(len(ev.ranges_m) == ev.geometry.beam_count for ev in scans)
    assert scans[0].geometry is log.geometry  # the first scan's is the log's (metadata)
    assert {ev.geometry.max_range_m for ev in scans} == {RANGE_MAX_M[0]}  # the first scan's range
