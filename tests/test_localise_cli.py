"""`gslam localise` end to end: a simulated robot's bag is ingested, mapped with `gslam process`, exported as
a map_server map, and localised in both maps; the result MCAP's channels, the Rerun recording, and one
clear line for bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bagtools import bag_from_robot
from typer.testing import CliRunner
from worlds import office_world, simulate_robot_loop

from mcaplog import channels as ch
from mcaplog.mcapio import McapInput
from pipelines.cli.app import app
from pipelines.evaluation.evaluate import read_result
from pipelines.localise.run import PARTICLES, POSE, STATE

MOUNT = (0.3, 0.0, math.radians(10.0))


def _invoke(*args: str):
    result = CliRunner().invoke(app, list(args))
    return result.exit_code, result.output


@pytest.fixture(scope="module")
def mapped(tmp_path_factory):
    """The drive (laser 0.3 m ahead, turned 10 deg), its MCAP, the map of `gslam process --occupancy`, and
    that map exported for map_server."""
    tmp = tmp_path_factory.mktemp("localise")
    sim = simulate_robot_loop(office_world(), np.random.default_rng(2), mount=MOUNT, laps=1.3)
    bag = bag_from_robot(sim, tmp / "robot.bag", "ros1", "topic")
    for args in (
        ["ingest", str(bag), "-o", str(tmp / "in.mcap")],
        ["process", str(tmp / "in.mcap"), str(tmp / "map.mcap"), "--no-rrd", "--occupancy"],
        ["export", str(tmp / "map.mcap"), "--occupancy", str(tmp / "nav" / "map.yaml")],
    ):
        code, out = _invoke(*args)
        assert code == 0, out
    return tmp, sim


def _states(path):
    return [m.value for m in McapInput(path).messages([STATE])]


@pytest.mark.parametrize("map_name", ["map.mcap", "nav/map.yaml"])
def test_global_localisation_in_a_saved_map(mapped, map_name):
    """No initial pose, in the point map or the exported grid: the filter converges within a few metres
    and then follows the base within a few centimetres of the truth (the map itself is SLAM's, in SLAM's
    frame, which starts at the first odometry pose: the truth here is the same frame)."""
    tmp, sim = mapped
    out = tmp / f"loc-{map_name.replace('/', '-')}.mcap"
    code, text = _invoke("localise", str(tmp / map_name), str(tmp / "in.mcap"), str(out))
    assert code == 0, text
    assert "tracking" in text and out.exists() and out.with_suffix(".rrd").exists()
    states = _states(out)
    assert len(states) == len(sim.t_s)
    tracking = np.array([s["tracking"] for s in states])
    first = int(np.argmax(tracking))
    assert tracking.any() and tracking[first:].mean() > 0.95
    est = np.array([[s["x_m"], s["y_m"], s["yaw_rad"]] for s in states])
    slam = read_result(tmp / "map.mcap").trajectory  # the base's path in the map's frame
    err = np.hypot(*(est[first:, :2] - slam[first:, :2]).T)
    assert err.mean() < 0.05, err.mean()
    travelled = np.r_[0, np.cumsum(np.hypot(*np.diff(sim.truth[:, :2], axis=0).T))]
    assert travelled[first] < 10.0
    topics = {m.topic for m in McapInput(out).messages()}
    assert {POSE, STATE, PARTICLES, ch.TF, "/localise/map"} <= topics
    meta = McapInput(out).metadata()
    assert "localise" in meta and "result" in meta


def test_initial_pose_in_the_base_frame(mapped):
    tmp, sim = mapped
    slam = read_result(tmp / "map.mcap").trajectory
    x, y, yaw = slam[0]
    out = tmp / "loc-init.mcap"
    code, text = _invoke(
        "localise", str(tmp / "map.mcap"), str(tmp / "in.mcap"), str(out), "--no-rrd",
        "--initial-pose", str(x + 0.2), str(y - 0.1), str(yaw + 0.05), "--initial-sigma", "0.3", "0.1",
    )  # fmt: skip
    assert code == 0, text
    states = _states(out)
    assert all(s["tracking"] for s in states[5:])
    est = np.array([[s["x_m"], s["y_m"]] for s in states])
    assert np.hypot(*(est[5:] - slam[5:, :2]).T).mean() < 0.05


def test_bad_input_gets_one_line(mapped, tmp_path):
    tmp, _ = mapped
    code, text = _invoke("localise", str(tmp_path / "none.mcap"), str(tmp / "in.mcap"), str(tmp_path / "o.mcap"))
    assert code != 0 and "Traceback" not in text and "no such" in text.lower()
    (tmp_path / "bad.yaml").write_text("image: missing.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    code, text = _invoke("localise", str(tmp_path / "bad.yaml"), str(tmp / "in.mcap"), str(tmp_path / "o.mcap"))
    assert code != 0 and "missing.pgm" in text and "Traceback" not in text
    code, text = _invoke("localise", str(tmp / "in.mcap"), str(tmp / "in.mcap"), str(tmp_path / "o.mcap"))
    assert code != 0 and "gslam process" in text and "Traceback" not in text
    code, text = _invoke(
        "localise", str(tmp / "map.mcap"), str(tmp / "in.mcap"), str(tmp_path / "o.mcap"), "--initial-sigma", "1", "1"
    )
    assert code != 0 and "--initial-pose" in text
    assert not (tmp_path / "o.mcap").exists()
