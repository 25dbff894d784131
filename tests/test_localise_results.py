"""A localisation result for the viewers and the tools: the Foxglove layout for it names only what a real
result holds, its Rerun recording opens with its own blueprint (the map large, the plots in a strip), and
`gslam export` reports its progress on the slow parts."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
from bagtools import bag_from_robot
from typer.testing import CliRunner
from worlds import office_world, simulate_robot_loop

from pipelines.cli.app import app

LAYOUT = Path(__file__).parents[1] / "docs" / "foxglove" / "gslam-localise-layout.json"


def _invoke(*args) -> tuple[int, str]:
    result = CliRunner().invoke(app, [str(a) for a in args])
    return result.exit_code, result.output


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    """A short drive (the laser mounted off the base) mapped by `gslam process --occupancy`, and localised in
    that map from a known start, with its Rerun recording: (directory, the localisation result)."""
    tmp = tmp_path_factory.mktemp("localise-results")
    sim = simulate_robot_loop(office_world(), np.random.default_rng(4), mount=(0.3, 0.0, math.radians(10)), laps=0.4)
    bag = bag_from_robot(sim, tmp / "robot.bag", "ros1", "topic")
    x, y, yaw = sim.truth[0]  # the map's frame is the first odometry pose's, which is the true start here
    for args in (
        ["ingest", bag, "-o", tmp / "in.mcap"],
        ["process", tmp / "in.mcap", tmp / "map.mcap", "--no-rrd", "--occupancy"],
        ["localise", tmp / "map.mcap", tmp / "in.mcap", tmp / "loc.mcap", "--initial-pose", x, y, yaw],
    ):
        code, out = _invoke(*args)
        assert code == 0, out
    return tmp, tmp / "loc.mcap"


def test_the_localisation_layout_names_what_the_result_holds(result):
    """docs/foxglove/gslam-localise-layout.json: every panel of its tree is configured; every topic of its 3-D
    panel is a channel of the result with a Foxglove schema, every frame it configures is in the result's
    /tf, the followed frame among them; every plotted path is a field of /localise/state."""
    from mcap.reader import make_reader

    layout = json.loads(LAYOUT.read_text())

    def leaves(node) -> list[str]:
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(layout["configById"])
    scenes = [c for k, c in layout["configById"].items() if k.startswith("3D!")]
    assert len(scenes) == 1
    scene = scenes[0]
    plotted = [p["value"] for k, c in layout["configById"].items() if k.startswith("Plot!") for p in c["paths"]]
    assert {p.split(".", 1)[1] for p in plotted} == {"fitness", "particles", "tracking"}
    _, loc = result
    with open(loc, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schema_of = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        state = json.loads(next(m for _, _, m in reader.iter_messages(topics=["/localise/state"])).data)
        f.seek(0)
        from mcap_protobuf.decoder import DecoderFactory

        decoded = make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(topics=["/tf"])
        frames = {
            name for _, _, _, tf in decoded for t in tf.transforms for name in (t.parent_frame_id, t.child_frame_id)
        }
    assert set(scene["topics"]) == {"/localise/map", "/localise/pose", "/localise/particles"}
    for topic in scene["topics"]:
        assert schema_of.get(topic, "").startswith("foxglove."), (topic, schema_of.get(topic))
    assert schema_of["/tf"] == "foxglove.FrameTransforms"
    configured = {k.removeprefix("frame:") for k in scene["transforms"]}
    assert configured <= frames and scene["followTf"] in frames, (configured, frames)
    for path in plotted:
        topic, field = path.split(".", 1)
        assert topic == "/localise/state" and field in state and isinstance(state[field], bool | int | float), path


def test_the_recording_opens_with_its_blueprint(result):
    """The .rrd carries the default blueprint (read back with rerun's own `rrd print`): a 2-D map view over
    four fifths of the height and a strip of three time series (fitness, particles, tracking) under it;
    the robot, its footprint, the path and the particles are logged under `world`."""
    import rerun.blueprint as rrb

    from pipelines.localise.run import RR_FOOTPRINT, RR_MAP, RR_PARTICLES, RR_PATH, RR_ROBOT, RR_STATS, rerun_blueprint
    from pipelines.outputs.rerun_viewer import rerun_binary

    root = rerun_blueprint().root_container
    assert isinstance(root, rrb.Vertical)
    map_view, strip = root.contents
    assert isinstance(map_view, rrb.Spatial2DView) and isinstance(strip, rrb.Horizontal)
    assert [type(v) for v in strip.contents] == [rrb.TimeSeriesView] * 3
    shares = [float(v) for v in root.row_shares]
    assert shares[0] / sum(shares) >= 0.75
    _, loc = result
    printed = subprocess.run(
        [rerun_binary(), "rrd", "print", "-vvv", str(loc.with_suffix(".rrd"))],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert printed.returncode == 0, printed.stderr[-2000:]
    text = printed.stdout
    assert "Blueprint" in text and text.count("[TimeSeries]") == 3 and text.count("[2D]") == 1
    for name in ("fitness", "particles", "tracking (1) / lost (0)"):
        assert f"[{name}]" in text, name
    for entity in (RR_MAP, RR_ROBOT, RR_FOOTPRINT, RR_PATH, RR_PARTICLES, *RR_STATS.values()):
        assert f" - /{entity} - " in text, entity


def test_exports_report_progress_on_the_slow_parts(result, tmp_path, monkeypatch):
    """Off a terminal, a progress line every GSLAM_PROGRESS_EVERY_S (here every report, to see them on a short
    log): reading the result, casting the input's scans into a grid of another size; a localisation's reading.
    At the default interval a short export says only what it wrote."""
    tmp, loc = result
    code, text = _invoke("export", tmp / "map.mcap", "--tum", tmp_path / "a.txt")
    assert code == 0 and "export:" not in text, text
    monkeypatch.setenv("GSLAM_PROGRESS_EVERY_S", "0")
    code, text = _invoke("export", tmp / "map.mcap", "--tum", tmp_path / "t.txt", "--occupancy", tmp_path / "m.yaml",
                         "--resolution", "0.1")  # fmt: skip
    assert code == 0, text
    steps = sum(1 for line in (tmp_path / "t.txt").read_text().splitlines() if not line.startswith("#"))
    assert f"export: reading the result: {steps}/{steps} steps (100%)" in text, text
    assert f"export: occupancy grid from the input's scans: {steps}/{steps} scans (100%)" in text, text
    assert text.count("export: occupancy grid") > 2 and (tmp_path / "m.pgm").exists()
    code, text = _invoke("export", loc, "--tum", tmp_path / "loc.txt")
    assert code == 0 and f"export: reading the localisation: {steps}/{steps} scans (100%)" in text, text


def test_a_reference_pairs_by_stamp_or_interpolates_by_time(tmp_path):
    """A trajectory reference (a SLAM result, a TUM file) gives each scan the pose whose stamp is nearest,
    within 0.01 s, and none otherwise; an input's truth (true poses, GPS) is interpolated at the scans' log
    times inside its span. A TUM file that is not one is refused naming the line."""
    from pipelines.errors import InputError
    from pipelines.evaluation.localisation import LocalisationData, Reference, load_reference, pose_errors

    n = 5
    loc = LocalisationData({}, 10.0 + np.arange(n), 500.0 + np.arange(n), np.zeros((n, 3)), np.ones(n, bool),
                           np.ones(n), np.full(n, 100.0), np.ones(n), np.empty((0, 2)))  # fmt: skip
    stamps = np.array([500.004, 501.0, 502.02, 504.0])  # scan 2: 20 ms off (unpaired); scan 3: none
    poses = np.column_stack([np.arange(4.0), np.zeros(4), np.zeros(4)])
    has, paired = Reference("tum", stamps, poses, True, True).at(loc)
    assert has.tolist() == [True, True, False, False, True]
    np.testing.assert_allclose(paired[:, 0], [0.0, 1.0, 3.0])
    truth_t = np.array([10.5, 12.5])  # log times: scans 1 and 2 lie inside
    truth = np.array([[0.0, 0.0, 0.0], [2.0, 4.0, math.pi / 2]])
    has, paired = Reference("gps", truth_t, truth, False, False).at(loc)
    assert has.tolist() == [False, True, True, False, False]
    np.testing.assert_allclose(paired, [[0.5, 1.0, math.pi / 8], [1.5, 3.0, 3 * math.pi / 8]])
    trans, rot = pose_errors(np.array([[3.0, 4.0, math.pi - 0.01]]), np.array([[0.0, 0.0, -math.pi + 0.01]]))
    assert trans[0] == pytest.approx(5.0) and rot[0] == pytest.approx(math.degrees(0.02))
    bad = tmp_path / "bad.txt"
    bad.write_text("# t x y z qx qy qz qw\n1 2 3 4 0 0 0 1\n2 oops\n")
    with pytest.raises(InputError, match="line 3 is not a TUM pose"):
        load_reference(tmp_path / "r.mcap", {}, bad)
