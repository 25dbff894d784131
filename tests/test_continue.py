"""`gslam process NEW OUT --continue PREVIOUS`: a simulated robot's drive round an office, cut in three runs;
the second continues the first's result, the third the second's. Each finds itself in the map before it,
maps on in one map and one graph, and its result holds every run; `gslam localise` works in the continued
map; bad input gets one line and writes nothing."""

from __future__ import annotations

import math
import subprocess

import numpy as np
import pytest
from bagtools import bag_from_robot
from typer.testing import CliRunner
from worlds import corridor_world, office_world, simulate_robot_loop

from gslam.config import FilterConfig
from gslam.se2 import compose, inverse
from mcaplog import channels as ch
from mcaplog.mcapio import McapInput
from pipelines.bench.continuation import cut_input, mirrored_writer
from pipelines.cli.app import app
from pipelines.evaluation.evaluate import read_result
from pipelines.outputs import rerun_entities as entity
from pipelines.outputs.rerun_viewer import rerun_binary

MOUNT = (0.3, 0.0, math.radians(10.0))


def _invoke(*args: str):
    result = CliRunner().invoke(app, list(args))
    return result.exit_code, result.output


def _final(path, topic):
    values = [m.value for m in McapInput(path).messages([topic])]
    return values[-1] if values else None


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The drive (1.5 laps, laser 0.3 m ahead and turned 10 deg) cut in three; the first mapped, the second
    continued from it, the third from the second."""
    tmp = tmp_path_factory.mktemp("continue")
    sim = simulate_robot_loop(office_world(), np.random.default_rng(5), mount=MOUNT, laps=1.5)
    bag = bag_from_robot(sim, tmp / "robot.bag", "ros1", "topic")
    code, out = _invoke("ingest", str(bag), "-o", str(tmp / "in.mcap"))
    assert code == 0, out
    n = len(sim.t_s)
    cut_input(tmp / "in.mcap", n // 3, tmp / "a.mcap", tmp / "bc.mcap")
    cut_input(tmp / "bc.mcap", n // 3, tmp / "b.mcap", tmp / "c.mcap")
    outputs = {}
    for name, args in (
        ("a", ["process", str(tmp / "a.mcap"), str(tmp / "a-map.mcap"), "--no-rrd"]),
        ("b", ["process", str(tmp / "b.mcap"), str(tmp / "b-map.mcap"), "--occupancy", "--continue",
               str(tmp / "a-map.mcap")]),
        ("c", ["process", str(tmp / "c.mcap"), str(tmp / "c-map.mcap"), "--no-rrd", "--continue",
               str(tmp / "b-map.mcap")]),
    ):  # fmt: skip
        outputs[name] = _invoke(*args)
    return tmp, sim, outputs, (n // 3, 2 * (n // 3))


def test_a_continued_run_finds_itself_and_maps_on_in_one_map(runs):
    """The second run finds where it starts in the first run's map (its frame: the first scan's odometry,
    here the truth's), maps on there, and its closures tie it to the first run's nodes; its map holds the
    first run's places and its own."""
    tmp, sim, outputs, (b0, c0) = runs
    code, text = outputs["b"]
    assert code == 0, text
    assert "finding the run in" in text
    meta = read_result(tmp / "b-map.mcap").metadata
    start = meta["continuation"]["start"]
    assert start["how"] == "found"
    assert np.hypot(*(np.asarray(start["pose"][:2]) - sim.truth[b0, :2])) < 0.15
    assert abs(math.remainder(start["pose"][2] - sim.truth[b0, 2], 2 * math.pi)) < math.radians(3)
    b = read_result(tmp / "b-map.mcap")
    err = np.hypot(*(b.trajectory[:, :2] - sim.truth[b0:c0, :2]).T)
    assert np.median(err) < 0.15 and err.max() < 0.4
    closure = meta["result"]["loop_closure"]
    assert closure["sessions"] == 2 and closure["closures_between_runs"] >= 3
    assert len(b.map_p) > len(read_result(tmp / "a-map.mcap").map_p)


def test_the_result_holds_every_run_and_a_third_continues_the_second(runs):
    """The third run's result: its own trajectory, the two earlier ones in /slam/sessions (the first run's
    as long as its log, each with its input), one graph over all three runs, and a Rerun recording of the
    second with the first run's path. The third run drives where the first did: the map's places seen again
    are updated, not added a second time."""
    tmp, sim, outputs, (b0, c0) = runs
    code, text = outputs["c"]
    assert code == 0, text
    sessions = _final(tmp / "c-map.mcap", ch.SLAM_SESSIONS)["sessions"]
    assert [s["session"] for s in sessions] == [0, 1]
    assert [len(s["t_s"]) for s in sessions] == [b0, c0 - b0]
    assert sessions[0]["input"].endswith("a.mcap") and sessions[1]["input"].endswith("b.mcap")
    first = np.column_stack([sessions[0]["x_m"], sessions[0]["y_m"]])
    assert np.allclose(ch.poses_of(_final(tmp / "c-map.mcap", ch.session_trajectory(0)))[:, :2], first)
    assert np.median(np.hypot(*(first - sim.truth[:b0, :2]).T)) < 0.15
    graph = _final(tmp / "c-map.mcap", ch.SLAM_GRAPH)
    assert set(graph["session"]) == {0, 1, 2}
    assert len(graph["closures"]) == len(graph["closure_scores"])
    scans = _final(tmp / "c-map.mcap", ch.SLAM_GRAPH_SCANS)
    xy, node = ch.node_returns_arrays(scans)
    assert node.max() == len(graph["x_m"]) - 1 and len(xy) > 10 * len(graph["x_m"])
    c = read_result(tmp / "c-map.mcap")
    assert len(c.map_p) < 1.1 * len(read_result(tmp / "b-map.mcap").map_p)
    assert np.median(np.hypot(*(c.trajectory[:, :2] - sim.truth[c0:, :2]).T)) < 0.15
    printed = subprocess.run(
        [rerun_binary(), "rrd", "print", "-vvv", str(tmp / "b-map.rrd")], capture_output=True, text=True, timeout=120
    )
    assert printed.returncode == 0, printed.stderr[-2000:]
    for name in (entity.session_trajectory(0), entity.session_robot(0), entity.session_timeline(0, "time")):
        assert name in printed.stdout, name


def test_the_continued_maps_grid_keeps_the_earlier_runs_walls(runs):
    """Points of the first run's map that the second run left as they were are saved at their own p, not at
    the cap it read them with, and stand as walls in the second result's occupancy grid; the free space
    the first run saw is free in it, in the grid `--occupancy` stores and in one built from the result."""
    from gslam.config import FilterConfig
    from pipelines.outputs.navigation_map import OCCUPIED_THRESH, grid_from_result, stored_grid
    from pipelines.outputs.occupancy_grid import FREE, OCCUPIED

    tmp, _, _, _ = runs
    a, b = read_result(tmp / "a-map.mcap"), read_result(tmp / "b-map.mcap")
    a_keys = np.ascontiguousarray(a.map_xy, dtype=np.float32).view(np.int64).ravel()
    b_keys = np.ascontiguousarray(b.map_xy, dtype=np.float32).view(np.int64).ravel()
    kept_a = np.flatnonzero(np.isin(a_keys, b_keys))  # where the second run drew nothing new
    at = {k: i for i, k in enumerate(b_keys)}
    in_b = np.array([at[k] for k in a_keys[kept_a]])
    p_a, p_b = a.map_p[kept_a], b.map_p[in_b]
    cap = np.float32(FilterConfig().continue_max_p)
    assert not np.any((p_b == cap) & (p_a > cap))  # none left at the cap it was read with
    same = p_b == p_a  # not seen again (the others were: updated from the cap by the second run's returns)
    walls = same & (p_a >= OCCUPIED_THRESH)
    assert walls.sum() > 50, (len(kept_a), same.sum(), walls.sum())
    # Where only the first run drove (3 m or more from the second's path) its scans' free space is in the
    # second result's grid too (cast from its graph nodes' returns): all of it free, not 29 % as before.
    only_a = a.trajectory[np.hypot(*(a.trajectory[:, None, :2] - b.trajectory[None, :, :2]).T).min(axis=0) > 3.0]
    assert len(only_a) > 50, len(only_a)
    stored = stored_grid(tmp / "b-map.mcap")  # `gslam process --occupancy`'s, built at the run's end
    rebuilt = grid_from_result(tmp / "b-map.mcap", resolution_m=0.1)  # `gslam export`'s, from the result
    for grid in (stored, rebuilt):
        assert np.mean(grid.state_at(b.map_xy[in_b[walls]]) == OCCUPIED) > 0.99
        assert np.mean(grid.state_at(only_a[:, :2]) == FREE) > 0.95


def test_localise_in_a_continued_map(runs):
    """`gslam localise` takes a continued result as its map: the third run's scans, localised in it from
    no initial pose, are tracked."""
    tmp, _, _, _ = runs
    code, text = _invoke("localise", str(tmp / "c-map.mcap"), str(tmp / "c.mcap"), str(tmp / "loc.mcap"), "--no-rrd")
    assert code == 0, text
    states = [m.value for m in McapInput(tmp / "loc.mcap").messages(["/localise/state"])]
    assert np.mean([s["tracking"] for s in states]) > 0.7


def test_an_initial_pose_starts_the_run_there(runs, tmp_path):
    """--initial-pose skips the search: the run starts at the pose given (the base's, in the old map)."""
    tmp, sim, _, (b0, _) = runs
    truth = sim.truth[b0]
    out = tmp_path / "given.mcap"
    code, text = _invoke("process", str(tmp / "b.mcap"), str(out), "--no-rrd", "--max-scans", "30", "--continue",
                         str(tmp / "a-map.mcap"), "--initial-pose", *(f"{v:.4f}" for v in truth))  # fmt: skip
    assert code == 0, text
    start = read_result(out).metadata["continuation"]["start"]
    assert start["how"] == "initial pose" and np.allclose(start["pose"], truth, atol=1e-4)
    first = read_result(out).trajectory[0]
    assert np.hypot(*(first[:2] - truth[:2])) < 0.1


@pytest.fixture(scope="module")
def corridor_map(runs):
    """A map of another building (a corridor), where the office's scans are found nowhere."""
    tmp = runs[0]
    sim = simulate_robot_loop(corridor_world(), np.random.default_rng(1), laps=0.4)
    bag = bag_from_robot(sim, tmp / "corridor.bag", "ros1", "topic")
    assert _invoke("ingest", str(bag), "-o", str(tmp / "corridor.mcap"))[0] == 0
    code, text = _invoke("process", str(tmp / "corridor.mcap"), str(tmp / "corridor-map.mcap"), "--no-rrd")
    assert code == 0, text
    return tmp / "corridor-map.mcap"


@pytest.fixture
def short_search(monkeypatch):
    """A lost run gives up after 5 m of search, not 30 (the tests' run is lost wherever it searches)."""
    monkeypatch.setattr("pipelines.run.continuation.SEARCH_TRAVEL_M", 5.0)


def test_bad_continuations_get_one_line_and_write_nothing(runs, corridor_map, short_search, tmp_path):
    """--initial-pose or --if-lost alone, a PREVIOUS that is not a mapping result, OUTPUT over PREVIOUS, and
    a run in another building: each refused in one line naming the file, and no output left behind."""
    tmp, _, _, _ = runs
    out = tmp_path / "out.mcap"
    cases = [
        (["--initial-pose", "0", "0", "0"], "--initial-pose goes with --continue"),
        (["--if-lost", "new"], "--if-lost goes with --continue"),
        (["--continue", str(tmp / "a-map.mcap"), "--if-lost", "maybe"], "--if-lost maybe: expected stop or new"),
        (["--continue", str(tmp / "a.mcap")], "no 'result'/'config' metadata"),
        (["--continue", str(tmp_path / "missing.mcap")], "no such result to continue"),
    ]
    for extra, said in cases:
        code, text = _invoke("process", str(tmp / "b.mcap"), str(out), "--no-rrd", *extra)
        assert code != 0 and said in text, text
        assert "Traceback" not in text and not out.exists()
    code, text = _invoke("process", str(tmp / "b.mcap"), str(tmp / "a-map.mcap"), "--continue", str(tmp / "a-map.mcap"))
    assert code != 0 and "would be overwritten" in text
    code, text = _invoke("process", str(tmp / "b.mcap"), str(out), "--continue", str(corridor_map))
    assert code != 0 and "could not find itself in the map of" in text and "--if-lost new" in text, text
    assert not out.exists() and not out.with_suffix(".rrd").exists()


@pytest.fixture(scope="module")
def apart(runs, corridor_map):
    """`--if-lost new`: the office's second run continued from the corridor's map, lost there (after 5 m of
    search) and mapped apart: (the result, exit code, output)."""
    tmp = runs[0]
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("pipelines.run.continuation.SEARCH_TRAVEL_M", 5.0)
        code, text = _invoke("process", str(tmp / "b.mcap"), str(tmp / "apart.mcap"), "--no-rrd", "--continue",
                             str(corridor_map), "--if-lost", "new")  # fmt: skip
    return tmp / "apart.mcap", code, text


def _rewritten(src, dst, topic: str, change) -> None:
    """A copy of the MCAP `src` at `dst` with each JSON message on `topic` replaced by `change(value)`."""
    import json

    from mcap.reader import make_reader

    with open(src, "rb") as f, open(dst, "wb") as out:
        reader = make_reader(f)
        w, channels = mirrored_writer(out, reader)
        for _, c, m in reader.iter_messages(log_time_order=True):
            data = json.dumps(change(json.loads(m.data))).encode() if c.topic == topic else m.data
            w.add_message(channels[c.id], m.log_time, data, m.publish_time)
        w.finish()


def test_a_result_whose_runs_and_maps_do_not_agree_gets_one_line(runs, apart, tmp_path):
    """A continued result whose /slam/sessions names a map it does not hold, or whose earlier graph's nodes
    and scans do not agree: refused in one line naming the file, nothing written."""
    tmp = runs[0]
    path, code, text = apart
    assert code == 0, text

    def far_map(v):
        v["sessions"][0]["map"] = 5
        return v

    def short_graph(v):
        v["x_m"] = v["x_m"][:-1]
        return v

    out = tmp_path / "out.mcap"
    for topic, change, said in (
        (ch.SLAM_SESSIONS, far_map, "/slam/sessions puts run 0 in map 5; the result holds 2"),
        (ch.SLAM_EARLIER_GRAPHS, short_graph, "its pose graph is not what gslam writes"),
    ):
        bad = tmp_path / "bad.mcap"
        _rewritten(path, bad, topic, change)
        code, text = _invoke("process", str(tmp / "c.mcap"), str(out), "--no-rrd", "--continue", str(bad))
        assert code != 0 and said in text and str(bad) in text, text
        assert "Traceback" not in text and not out.exists()


def test_a_run_that_cannot_find_itself_maps_a_new_trajectory_beside_the_old_map(runs, corridor_map, apart):
    """--if-lost new: the office's run, lost in the corridor's map, maps the office in its own frame; the
    corridor's map and run stay in the result apart from it (`/slam/earlier_maps`, map 1), and a run that
    continues that result finds itself in the office's map and keeps the corridor's too."""
    tmp, sim, _, (b0, _) = runs
    apart, code, text = apart
    assert code == 0, text
    assert "mapping it as a new trajectory" in text
    corridor = read_result(corridor_map)
    earlier = [ch.cloud_arrays(m.value) for m in McapInput(apart).messages([ch.SLAM_EARLIER_MAPS])]
    assert len(earlier) == 1 and np.allclose(earlier[0][0], corridor.map_xy, atol=1e-4)
    sessions = _final(apart, ch.SLAM_SESSIONS)["sessions"]
    assert [(s["map"], s["connected"]) for s in sessions] == [(1, False)]
    assert set(_final(apart, ch.SLAM_GRAPH)["session"]) == {1}
    # the corridor's graph kept under its map, in that map's frame, as the corridor's result saved it
    kept = _final(apart, ch.SLAM_EARLIER_GRAPHS)
    saved = _final(corridor_map, ch.SLAM_GRAPH)
    assert kept["map"] == 1 and set(kept["session"]) == {0} and np.allclose(kept["x_m"], saved["x_m"])
    scans = _final(apart, ch.SLAM_EARLIER_GRAPH_SCANS)
    assert scans.frame_id == "map_1"
    assert np.allclose(
        ch.node_returns_arrays(scans)[0], ch.node_returns_arrays(_final(corridor_map, ch.SLAM_GRAPH_SCANS))[0]
    )
    meta = read_result(apart).metadata["continuation"]
    assert meta["connected"] is False and meta["start"]["how"] == "lost"
    # its own frame: the first scan's odometry pose
    assert np.allclose(read_result(apart).trajectory[0], sim.odometry[b0], atol=0.1)
    on = tmp / "on.mcap"
    code, text = _invoke("process", str(tmp / "c.mcap"), str(on), "--no-rrd", "--continue", str(apart))
    assert code == 0, text
    sessions = _final(on, ch.SLAM_SESSIONS)["sessions"]
    assert [(s["session"], s["map"]) for s in sessions] == [(0, 1), (1, 0)]
    assert len(list(McapInput(on).messages([ch.SLAM_EARLIER_MAPS]))) == 1
    assert read_result(on).metadata["continuation"]["start"]["how"] == "found"


def test_a_run_found_in_an_earlier_map_maps_on_in_that_one(runs, corridor_map, apart, short_search):
    """A third run that goes back to the first building of a result holding two (the office mapped apart
    from the corridor): not found in the office's map, it is found in the corridor's, which it continues; the
    office's map and graph are kept apart, and every run says which map it belongs to."""
    tmp = runs[0]
    apart, code, text = apart
    assert code == 0, text
    back = tmp / "back.mcap"
    code, text = _invoke("process", str(tmp / "corridor.mcap"), str(back), "--no-rrd", "--continue", str(apart))
    assert code == 0, text
    assert "found the run in earlier map 1" in text, text
    start = read_result(back).metadata["continuation"]["start"]
    assert start["how"] == "found" and start["map"] == 1
    # the same drive as the corridor's first run: found where that run's first scan was
    corridor = read_result(corridor_map)
    assert np.hypot(*(np.asarray(start["pose"][:2]) - corridor.trajectory[0, :2])) < 0.3
    sessions = _final(back, ch.SLAM_SESSIONS)["sessions"]
    assert [(s["session"], s["map"], s["connected"]) for s in sessions] == [(0, 0, True), (1, 1, False)]
    assert set(_final(back, ch.SLAM_GRAPH)["session"]) == {0, 2}
    closure = read_result(back).metadata["result"]["loop_closure"]
    assert closure["sessions"] == 2 and closure["closures_between_runs"] >= 3
    # the corridor seen again is updated, not doubled; the office's map and graph are kept apart
    assert len(read_result(back).map_p) < 1.2 * len(corridor.map_p)
    office = read_result(apart)
    earlier = [ch.cloud_arrays(m.value) for m in McapInput(back).messages([ch.SLAM_EARLIER_MAPS])]
    assert len(earlier) == 1 and np.allclose(earlier[0][0], office.map_xy, atol=1e-4)
    kept = _final(back, ch.SLAM_EARLIER_GRAPHS)
    assert kept["map"] == 1 and set(kept["session"]) == {1}
    assert len(kept["x_m"]) == len(_final(apart, ch.SLAM_GRAPH)["x_m"])


def test_the_start_search_gives_the_same_start_on_any_number_of_threads(runs):
    """`find_start`'s regions searched by one thread or three: the same start, bit for bit, where it is."""
    from pipelines.run.continuation import find_start, load_previous
    from pipelines.run.input_log import InputLog

    tmp, sim, _, (b0, _) = runs
    prev = load_previous(tmp / "a-map.mcap")
    one, three = (find_start(prev, InputLog(tmp / "b.mcap"), None, workers=w) for w in (1, 3))
    assert one.how == three.how == "found" and one.scans_searched == three.scans_searched
    np.testing.assert_array_equal(one.pose, three.pose)
    assert np.hypot(*(one.pose[:2] - sim.truth[b0, :2])) < 0.15


def test_the_start_is_carried_back_to_the_first_scan():
    """`find_start`'s last step: the pose found at a later scan, moved back by the odometry between them."""
    found = np.array([2.0, 1.0, 0.5])
    odom_first, odom_later = np.array([10.0, 0.0, 0.2]), np.array([11.0, 0.5, 0.7])
    back = compose(inverse(odom_later), odom_first)
    start = compose(found, back)
    # the odometry's motion from the start to the later scan, applied to the start, gives the pose found
    assert np.allclose(compose(start, compose(inverse(odom_first), odom_later)), found)


def test_a_continued_map_yields_to_the_new_runs_returns():
    """`continue_max_p`: a wall saved 4 cm behind where the new run's scans see it (the earlier run's pose
    error), at the saved map's full p. Capped on load, the old points give way in their cells to points
    drawn at this run's returns at the first sightings; held at their saved p, they never do."""
    from gslam.config import FilterConfig
    from gslam.filter import GSlamFilter
    from gslam.scan import Scan, ScanGeometry

    geom = ScanGeometry(181, -math.pi / 2, math.pi / 180, 30.0)
    bearings = geom.bearings_rad
    ranges = np.where(np.abs(bearings) < 1.0, 5.0 / np.cos(bearings), np.inf)  # a wall at x = 5 m
    y = np.arange(-8.0, 8.0, 0.1) + 0.05
    saved_xy = np.column_stack([np.full_like(y, 5.04), y])  # in the cells x 5.0 to 5.1
    saved_p = np.full(len(y), 1 - 1e-6)

    def wall_x(max_p: float) -> np.ndarray:
        cfg = FilterConfig(particles=3, seed=0, proposal="motion", update_schedule="every_scan", continue_max_p=max_p)
        flt = GSlamFilter(cfg, np.zeros(3))
        flt.seed_map(saved_xy, saved_p)
        assert flt.maps[0].p.max() <= max_p
        for k in range(3):
            flt.step(Scan(float(k), ranges, geom))
        m = flt.maps[flt.best_particle()]
        band = (m.xy[:, 0] >= 5.0) & (m.xy[:, 0] < 5.1) & (np.abs(m.xy[:, 1]) < 3.0)
        return m.xy[band, 0]

    capped, saved = wall_x(FilterConfig().continue_max_p), wall_x(1.0)
    np.testing.assert_allclose(saved, 5.04, atol=1e-6)  # every old point kept where it was saved
    assert len(capped) > 40 and np.median(np.abs(capped - 5.0)) < 0.015  # the new run's returns replaced them


def test_places_only_an_earlier_run_saw_keep_their_saved_p():
    """The cap is for the continued run's matching and updates: at the run's end (`restore_saved_p`) a wall
    it never saw (behind its laser) is put back at the p it was saved with, bit for bit, so the saved map and
    the occupancy grid (threshold 0.65, above the cap) keep it; the wall it saw is its own again."""
    from gslam.config import FilterConfig
    from gslam.filter import GSlamFilter
    from gslam.scan import Scan, ScanGeometry

    geom = ScanGeometry(181, -math.pi / 2, math.pi / 180, 30.0)
    ranges = np.where(np.abs(geom.bearings_rad) < 1.0, 5.0 / np.cos(geom.bearings_rad), np.inf)  # x = 5 m
    y = np.arange(-8.0, 8.0, 0.1) + 0.05
    behind = np.column_stack([np.full_like(y, -5.05), y])  # never in the laser's view
    ahead = np.column_stack([np.full_like(y, 5.05), y])
    saved_p = np.linspace(0.7, 1 - 1e-6, len(y))
    cfg = FilterConfig(particles=3, seed=0, proposal="motion", update_schedule="every_scan")
    flt = GSlamFilter(cfg, np.zeros(3))
    flt.seed_map(np.vstack([behind, ahead]), np.r_[saved_p, saved_p])
    for k in range(3):
        flt.step(Scan(float(k), ranges, geom))
    xy, p = flt.map_points(flt.best_particle())
    assert p[xy[:, 0] < 0].max() <= np.float32(cfg.continue_max_p)  # as the filter holds it while it runs
    assert flt.restore_saved_p() == len(y) and flt.restore_saved_p() == 0  # at the run's end, once
    xy, p = flt.map_points(flt.best_particle())
    old = xy[:, 0] < 0
    order = np.argsort(xy[old, 1])
    np.testing.assert_array_equal(xy[old][order], behind.astype(np.float32))
    np.testing.assert_array_equal(p[old][order], saved_p.astype(np.float32))
    seen = (xy[:, 0] > 4.9) & (np.abs(xy[:, 1]) < 3.0)
    assert seen.sum() > 40 and not np.isin(xy[seen, 0], np.float32(5.05)).any()  # drawn by this run


def test_an_ackermann_log_finds_its_start_by_its_controls(carpark_mcap, tmp_path):
    """The Car Park (a Sydney log: a car's controls, no odometry poses) cut at its middle scan, the second half
    continued from the first half's result with no --initial-pose: its controls, dead-reckoned with the
    vehicle's model, carry the scans it searches for in the old map, and the start found lies within 0.5 m
    of the GPS fix there (the map is in GPS's frame: the first half started from GPS); over the half the
    GPS error stays under 0.5 m. Measured (N 8 and 30, seeds 0-2): the start 0.12 to 0.22 m from the fix,
    the error 0.16 to 0.38 m (the whole log mapped at once: 0.19 to 0.27 m over the same half). The half
    mapped alone starts from its own GPS fixes, though they begin a minute after its file's first message
    (the surveyed poles, kept at the log's start by the cut). `gslam localise` tracks the half in the first
    half's map from a global start (seed 0: 84 % of its scans, median error 0.20 m against GPS)."""
    from pipelines.evaluation.localisation import evaluate_localisation
    from pipelines.run.continuation import CARRY_SD_PER_M
    from pipelines.run.input_log import InputLog

    at = 293
    cut_s = cut_input(carpark_mcap, at, tmp_path / "a.mcap", tmp_path / "b.mcap")
    common = ["-N", "8", "--seed", "0", "--no-rrd"]
    code, out = _invoke("process", str(tmp_path / "a.mcap"), str(tmp_path / "a-map.mcap"), *common)
    assert code == 0, out
    code, out = _invoke("process", str(tmp_path / "b.mcap"), str(tmp_path / "b-map.mcap"), *common,
                        "--continue", str(tmp_path / "a-map.mcap"))  # fmt: skip
    assert code == 0, out
    start = McapInput(tmp_path / "b-map.mcap").metadata()["continuation"]["start"]
    assert start["how"] == "found", start
    # found metres in and carried back over a turn: the particles start spread by what that carry may be off
    assert start["found_at_scan"] > 0 and start["travel_m"] > 1.0, start
    assert start["sigma_xy_m"] == pytest.approx(CARRY_SD_PER_M * start["travel_m"], abs=1e-3), start
    assert start["sigma_phi_rad"] > 0.02, start
    gps = InputLog(carpark_mcap).gps_array()
    fix = [np.interp(cut_s, gps[:, 0], gps[:, k]) for k in (1, 2)]
    assert math.dist(start["pose"][:2], fix) < 0.5, (start, fix)
    res = read_result(tmp_path / "b-map.mcap")
    later = gps[(gps[:, 0] >= res.t_s[0]) & (gps[:, 0] <= res.t_s[-1])]
    xy = np.column_stack([np.interp(later[:, 0], res.t_s, res.trajectory[:, k]) for k in (0, 1)])
    error = float(np.mean(np.hypot(*(xy - later[:, 1:]).T)))
    assert error < 0.5, error
    code, out = _invoke("process", str(tmp_path / "b.mcap"), str(tmp_path / "alone.mcap"), *common)
    assert code == 0, out
    init = McapInput(tmp_path / "alone.mcap").metadata()["initialisation"]
    assert init["from_gps"] and init["t_s"] > cut_s - 2.0, init
    # and `gslam localise` follows the half in the first half's map, its motion dead-reckoned the same way
    code, out = _invoke("localise", str(tmp_path / "a-map.mcap"), str(tmp_path / "b.mcap"), str(tmp_path / "loc.mcap"),
                        "--no-rrd", "--seed", "0")  # fmt: skip
    assert code == 0, out
    m = evaluate_localisation(tmp_path / "loc.mcap")
    assert m["tracked_share"] > 0.6 and m["error_trans_median_m"] < 0.5, m


def test_a_start_known_only_so_well_spreads_the_particles(carpark_mcap):
    """A continued run's start carried back by the odometry (`Start.sigma_xy_m`, `sigma_phi_rad`) starts the
    particles spread by those standard deviations around it, drawn from the filter's seeded generator; a
    start found at the first scan (no spread) leaves them at the pose, bit for bit."""
    from pipelines.run.input_log import InputLog
    from pipelines.run.runner import RunConfig, SlamRunner

    log = InputLog(carpark_mcap)
    start = np.array([3.0, -2.0, 0.5])
    cfg = RunConfig(filter=FilterConfig(particles=400, seed=1))
    spread = SlamRunner(log, cfg, start, (0.4, 0.1)).filter.poses
    assert np.std(spread[:, :2] - start[:2]) == pytest.approx(0.4, rel=0.15)
    assert np.std(spread[:, 2] - start[2]) == pytest.approx(0.1, rel=0.15)
    assert np.allclose(spread.mean(axis=0), start, atol=0.06)
    again = SlamRunner(log, cfg, start, (0.4, 0.1)).filter.poses
    assert np.array_equal(spread, again)  # seeded
    exact = SlamRunner(log, cfg, start).filter.poses
    assert np.array_equal(exact, np.tile(start, (400, 1)))
