"""`gslam localise` end to end: a simulated robot's bag is ingested, mapped with `gslam process`, exported as
a map_server map, and localised in both maps; the result MCAP's channels, the Rerun recording, and one
clear line for bad input. The result read back: `gslam eval` (tracking, error against the SLAM result),
`gslam plot`, `gslam export --tum` (what evo reads); and a raw CARMEN log localised directly."""

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


@pytest.fixture(scope="module")
def localised(mapped):
    """`localised(map_name)`: `gslam localise` with no initial pose in that saved map (run once per map, for
    every test that reads the result): (the result, exit code, output)."""
    tmp, _ = mapped
    runs = {}

    def run(map_name: str):
        if map_name not in runs:
            out = tmp / f"loc-{map_name.replace('/', '-')}.mcap"
            runs[map_name] = (out, *_invoke("localise", str(tmp / map_name), str(tmp / "in.mcap"), str(out)))
        return runs[map_name]

    return run


def _states(path):
    return [m.value for m in McapInput(path).messages([STATE])]


@pytest.mark.parametrize("map_name", ["map.mcap", "nav/map.yaml"])
def test_global_localisation_in_a_saved_map(mapped, localised, map_name):
    """No initial pose, in the point map or the exported grid: the filter converges within a few metres
    and then follows the base within a few centimetres of the truth (the map itself is SLAM's, in SLAM's
    frame, which starts at the first odometry pose: the truth here is the same frame)."""
    tmp, sim = mapped
    out, code, text = localised(map_name)
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


def _eval_json(*args: str) -> dict:
    import json

    code, text = _invoke("eval", *args, "--json")
    assert code == 0, text
    return json.loads(text)


def test_eval_scores_a_localisation_against_the_slam_result(mapped, localised):
    """`gslam eval` tells a localisation result by its metadata: scans, the share tracked, when it first
    tracked, fitness, time per scan; against the SLAM result (its final trajectory, matched by stamp) the
    error at the tracked scans, the same as computed here from the result's states; without a reference
    (this input has no truth) a note says what to give; a mapping result is evaluated as before."""
    tmp, sim = mapped
    out, code, text = localised("map.mcap")
    assert code == 0, text
    m = _eval_json(str(out), "--reference", str(tmp / "map.mcap"))
    assert m["kind"] == "localisation" and m["scans"] == len(sim.t_s)
    states = _states(out)
    tracking = np.array([s["tracking"] for s in states])
    assert m["tracked_share"] == pytest.approx(tracking.mean()) and m["tracked_share"] > 0.9
    assert m["first_tracking_scan"] == int(np.argmax(tracking))
    assert m["first_tracking_time_s"] == pytest.approx(sim.t_s[m["first_tracking_scan"]], abs=1e-3)
    assert 0 < m["first_tracking_travel_m"] < 10.0
    assert 0.9 < m["fitness_mean"] <= 1.0 and m["ms_per_scan"] > 0
    est = np.array([[s["x_m"], s["y_m"], s["yaw_rad"]] for s in states])
    slam = read_result(tmp / "map.mcap").trajectory
    err = np.hypot(*(est[tracking, :2] - slam[tracking, :2]).T)
    assert m["reference_scans"] == int(tracking.sum())
    assert m["error_trans_mean_m"] == pytest.approx(err.mean(), rel=1e-9)
    assert m["error_trans_max_m"] == pytest.approx(err.max(), rel=1e-9)
    # An honest bound: the SLAM run itself is a few centimetres off the truth here.
    assert m["error_trans_mean_m"] < 0.05 and m["error_trans_max_m"] < 0.2
    assert m["error_rot_mean_deg"] < 1.0 and m["error_rot_max_deg"] < 5.0
    code, text = _invoke("eval", str(out))
    assert code == 0 and "tracked_share" in text and "note: no reference" in text and "--reference" in text, text
    code, text = _invoke("eval", str(out), "--reference", str(out))
    assert code != 0 and "localisation result" in text and "Traceback" not in text
    code, text = _invoke("eval", str(tmp / "map.mcap"))  # the mapping result: as before
    assert code == 0 and "steps" in text and "kind" not in text, text


def test_plot_draws_a_localisation(mapped, localised, tmp_path):
    tmp, _ = mapped
    out, code, text = localised("map.mcap")
    assert code == 0, text
    for args in ([], ["--reference", str(tmp / "map.mcap")]):
        png = tmp_path / f"loc{len(args)}.png"
        code, text = _invoke("plot", str(out), "-o", str(png), *args)
        assert code == 0 and f"wrote {png}" in text, text
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    code, text = _invoke("plot", str(out), "-o", str(out))  # never over what it reads
    assert code != 0 and "Traceback" not in text


def test_export_tum_of_a_localisation_is_what_evo_reads(mapped, localised, tmp_path):
    """`export --tum` writes the estimate at every scan at the scans' stamps, the stamps of the SLAM result's
    export (so evo pairs them); `eval --reference` that TUM file gives what the SLAM result gives; a
    localisation result has no map of its own to export."""
    from evo.tools import file_interface

    tmp, sim = mapped
    out, code, text = localised("map.mcap")
    assert code == 0, text
    code, text = _invoke("export", str(out), "--tum", str(tmp_path / "loc.txt"))
    assert code == 0, text
    code, text = _invoke("export", str(tmp / "map.mcap"), "--tum", str(tmp_path / "slam.txt"))
    assert code == 0, text
    loc = file_interface.read_tum_trajectory_file(str(tmp_path / "loc.txt"))
    slam = file_interface.read_tum_trajectory_file(str(tmp_path / "slam.txt"))
    assert loc.num_poses == len(sim.t_s) and np.all(np.diff(loc.timestamps) > 0)
    np.testing.assert_allclose(loc.timestamps, slam.timestamps, atol=1e-9)
    est = np.array([[s["x_m"], s["y_m"]] for s in _states(out)])
    np.testing.assert_allclose(loc.positions_xyz[:, :2], est, atol=1e-5)
    by_mcap = _eval_json(str(out), "--reference", str(tmp / "map.mcap"))
    by_tum = _eval_json(str(out), "--reference", str(tmp_path / "slam.txt"))
    assert by_tum["reference_scans"] == by_mcap["reference_scans"]
    assert by_tum["error_trans_mean_m"] == pytest.approx(by_mcap["error_trans_mean_m"], abs=1e-5)
    assert by_tum["error_rot_mean_deg"] == pytest.approx(by_mcap["error_rot_mean_deg"], abs=1e-3)
    code, text = _invoke("export", str(out), "--map", str(tmp_path / "m.csv"))
    assert code != 0 and "no map of its own" in text and not (tmp_path / "m.csv").exists()
    code, text = _invoke("export", str(out), "--reference", str(tmp_path / "ref.txt"))  # this input has no truth
    assert code != 0 and "no GPS or true trajectory" in text and "Traceback" not in text


def _carmen_drive(path, laps: float = 0.6):
    """A drive round the office world as a CARMEN log (181 beams over 180 deg, the laser at the base), and
    its true poses as a TUM file beside it; the world's frame is the SLAM map's (see above)."""
    sim = simulate_robot_loop(office_world(), np.random.default_rng(5), laps=laps, beam_count=181, fov_rad=math.pi)
    lines, truth = [], []
    for k, t in enumerate(100.0 + sim.t_s):
        r = " ".join(f"{v:.3f}" for v in np.where(np.isfinite(sim.ranges[k]), sim.ranges[k], 81.9))
        x, y, th = sim.odometry[k]
        lines.append(f"FLASER 181 {r} {x:.4f} {y:.4f} {th:.5f} {x:.4f} {y:.4f} {th:.5f} {t:.3f} sim {t:.3f}")
        tx, ty, tth = sim.truth[k]
        truth.append(f"{t:.3f} {tx:.5f} {ty:.5f} 0 0 0 {math.sin(tth / 2):.8f} {math.cos(tth / 2):.8f}")
    path.write_text("\n".join(lines) + "\n")
    path.with_suffix(".truth.txt").write_text("\n".join(truth) + "\n")
    return sim


def test_localise_takes_a_raw_log(mapped, tmp_path):
    """IN may be a log, as for `gslam process`: ingested into OUT.input.mcap (said in one line), used
    again on the next run; the result localises the drive in the map (scored against its true poses by
    stamp) and `gslam eval` finds its input. What is no log is refused in one line."""
    tmp, _ = mapped
    log = tmp_path / "drive.clf"
    sim = _carmen_drive(log)
    out = tmp_path / "loc.mcap"
    code, text = _invoke("localise", str(tmp / "map.mcap"), str(log), str(out), "--no-rrd")
    ingested = tmp_path / "loc.input.mcap"
    assert code == 0, text
    assert f"IN {log} is a carmen log: ingested it into {ingested}" in text and ingested.exists()
    m = _eval_json(str(out), "--reference", str(log.with_suffix(".truth.txt")))
    assert m["scans"] == len(sim.t_s) and m["tracked_share"] > 0.8 and m["first_tracking_travel_m"] < 10.0
    assert m["reference_scans"] == round(m["tracked_share"] * m["scans"])
    assert m["error_trans_mean_m"] < 0.05 and m["error_rot_mean_deg"] < 1.0
    assert McapInput(out).metadata()["localise"]["input"] == str(ingested)
    code, text = _invoke("eval", str(out))  # the input it names is the ingest: found, no truth in it
    assert code == 0 and f"the input {ingested.name} holds no true poses" in text, text
    code, text = _invoke("localise", str(tmp / "map.mcap"), str(log), str(out), "--no-rrd", "--initial-pose",
                         *(str(v) for v in sim.truth[0]))  # fmt: skip
    assert code == 0 and "using the earlier ingest" in text, text
    (tmp_path / "notes.bin").write_bytes(b"not a log\n")
    code, text = _invoke("localise", str(tmp / "map.mcap"), str(tmp_path / "notes.bin"), str(tmp_path / "o.mcap"))
    assert code != 0 and "IN " in text and "not a log gslam reads" in text and "Traceback" not in text
    assert not (tmp_path / "o.mcap").exists()
