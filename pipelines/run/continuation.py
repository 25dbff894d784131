"""`gslam process NEW OUT --continue PREVIOUS`: a mapping run that goes on from an earlier run's result.

The earlier result holds what the new run needs, without its log: the final map (`/slam/map_final`), the
pose graph (`/slam/graph`) with each node's returns (`/slam/graph_scans`, in the map frame), its final
trajectory (`/slam/trajectory`, the stamps of `/slam/pose`), and the trajectories of the runs it itself
continued (`/slam/sessions`). `load_previous` reads those channels only (the MCAP's index takes it to
them), so loading takes a tenth of a second, not a replay of the old log.

The new run first finds itself in the old map (`find_start`): at `--initial-pose`, or where two of its
first scans are found, each searched for over the whole old map. The filter then starts there
with the old map as every particle's map (`GSlamFilter.seed_map`), and the run's end adds the old graph's
nodes to its pose graph (`PoseGraphBackEnd.add_previous`), so that closures between the runs are searched
and the one map moves with the one graph.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gslam.backend import BackEndSettings, PoseGraphBackEnd, PreviousGraph
from gslam.motion import odometry_delta, wrap_angle_scalar
from gslam.scan import transform_points
from gslam.se2 import compose, inverse
from gslam.vehicle import AckermannVehicle
from mcaplog import channels as ch
from mcaplog.mcapio import McapInput, Message, read_error
from pipelines.errors import InputError
from pipelines.run.input_log import InputLog
from pipelines.run.mount import LaserMount, base_poses, laser_poses
from pipelines.run.recorded_input import process_result_metadata


@dataclass
class Session:
    """One earlier mapping run: where its input was and its final trajectory (the base's poses)."""

    index: int
    input: str
    t_s: np.ndarray  # (T,) log times
    poses: np.ndarray  # (T, 3)
    map: int = 0
    """The map it belongs to: 0 the result's map (`/slam/map_final`), k >= 1 the k-th of `/slam/earlier_maps`
    (a map that a later run could not find itself in, kept in its own frame)."""

    @property
    def connected(self) -> bool:
        """Whether it shares the frame of the result's map."""
        return self.map == 0


@dataclass
class PreviousRun:
    """What a `gslam process` result holds for a run that continues it."""

    path: Path
    map_xy: np.ndarray  # (K, 2) the final map
    map_p: np.ndarray  # (K,)
    node_poses: np.ndarray | None  # (M, 3) the graph's optimised base poses; None: no graph was saved
    node_points: list[np.ndarray] = field(default_factory=list)  # each node's returns (K, 2), map frame
    node_steps: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    node_sessions: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    closures: list[tuple[int, int]] = field(default_factory=list)
    closure_scores: list[float] = field(default_factory=list)
    sessions: list[Session] = field(default_factory=list)
    """Every earlier run, the last one the result's own."""
    earlier_maps: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    """The maps of earlier runs that later ones could not find themselves in (`/slam/earlier_maps`): (points,
    probabilities) each, in their own frames."""

    def graph(self, mount: LaserMount | None) -> PreviousGraph | None:
        """The old graph for the back end, its poses the laser's on `mount` (the new run's)."""
        if self.node_poses is None or len(self.node_poses) == 0:
            return None
        return PreviousGraph(
            laser_poses(mount, self.node_poses),
            self.node_points,
            self.node_steps,
            self.node_sessions,
            self.closures,
            self.closure_scores,
        )


def load_previous(path: Path) -> PreviousRun:
    """The map, graph and trajectories of the `gslam process` result at `path`; InputError, naming the file,
    for anything that is not one that can be continued."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such result to continue (--continue takes a `gslam process` result .mcap)")
    src = McapInput(path)
    meta = process_result_metadata(src, path, "--continue takes")
    method = meta.get("gslam", {}).get("method", "gslam")
    if method != "gslam":
        raise InputError(f"{path}: a result of --method {method}; only a G-SLAM point map can be continued")
    parts: dict[str, object] = {}
    t_s: list[float] = []
    earlier: list[tuple[np.ndarray, np.ndarray]] = []

    def read(msg) -> None:
        if msg.topic == ch.SLAM_POSE:
            t_s.append(msg.t_s)
        elif msg.topic == ch.SLAM_EARLIER_MAPS:
            earlier.append(ch.cloud_arrays(msg.value))
        else:
            parts[msg.topic] = msg.value

    topics = [ch.SLAM_POSE, ch.SLAM_TRAJECTORY, ch.SLAM_MAP_FINAL, ch.SLAM_GRAPH, ch.SLAM_GRAPH_SCANS]
    for msg in _result_messages(path, [*topics, ch.SLAM_SESSIONS, ch.SLAM_EARLIER_MAPS], src):
        read(msg)
    if ch.SLAM_MAP_FINAL not in parts:
        raise InputError(f"{path}: no final map (/slam/map_final); was the run stopped before its first scan?")
    map_xy, map_p = ch.cloud_arrays(parts[ch.SLAM_MAP_FINAL])
    if len(map_xy) == 0:
        raise InputError(f"{path}: the final map has no points; there is nothing to continue")
    trajectory = ch.poses_of(parts[ch.SLAM_TRAJECTORY]) if ch.SLAM_TRAJECTORY in parts else None
    if trajectory is None or len(trajectory) != len(t_s):
        raise InputError(f"{path}: no final trajectory matching its {len(t_s)} steps")
    sessions = _sessions(parts.get(ch.SLAM_SESSIONS), path)
    own_input = str(meta.get("input", {}).get("path", "")) if isinstance(meta.get("input"), dict) else ""
    sessions.append(Session(len(sessions), own_input, np.asarray(t_s, dtype=float), trajectory))
    prev = PreviousRun(path, map_xy, map_p, None, sessions=sessions, earlier_maps=earlier)
    _graph_into(prev, parts, path)
    return prev


def _result_messages(path: Path, topics: list[str], src: McapInput | None = None) -> Iterator[Message]:
    """The messages of `topics` in the result at `path` (opened as `src` already, or here); InputError, naming
    it, where it cannot be read."""
    try:
        yield from (McapInput(path) if src is None else src).messages(topics)
    except InputError:
        raise
    except Exception as e:
        raise InputError(f"{path}: cannot read the result ({read_error(e)})") from None


def _sessions(value: object, path: Path) -> list[Session]:
    if value is None:
        return []
    try:
        return [
            Session(
                int(s["session"]),
                str(s.get("input", "")),
                np.asarray(s["t_s"], dtype=float),
                np.column_stack([s["x_m"], s["y_m"], s["yaw_rad"]]).astype(float).reshape(-1, 3),
                int(s.get("map", 0)),
            )
            for s in value["sessions"]
        ]
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{path}: /slam/sessions is not what gslam writes ({e})") from None


def _graph_into(prev: PreviousRun, parts: dict[str, object], path: Path) -> None:
    """The pose graph and its nodes' returns of a result (`parts` by topic) into `prev`, where it holds one
    (`prev.node_poses` stays None where it does not)."""
    graph, scans = parts.get(ch.SLAM_GRAPH), parts.get(ch.SLAM_GRAPH_SCANS)
    if isinstance(graph, dict) and graph.get("x_m") and scans is not None:
        _read_graph(prev, graph, scans, path)


def _read_graph(prev: PreviousRun, graph: dict, scans: object, path: Path) -> None:
    try:
        poses = np.column_stack([graph["x_m"], graph["y_m"], graph["yaw_rad"]]).astype(float)
        steps = np.asarray(graph["step"], dtype=np.int64)
        sessions = np.asarray(graph.get("session", [len(prev.sessions) - 1] * len(steps)), dtype=np.int64)
        xy, node = ch.node_returns_arrays(scans)
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{path}: its pose graph is not what gslam writes ({e})") from None
    if len(steps) != len(poses) or len(sessions) != len(poses) or (len(node) and node.max() >= len(poses)):
        raise InputError(f"{path}: its pose graph's nodes and their scans do not agree")
    order = np.argsort(node, kind="stable")
    bounds = np.searchsorted(node[order], np.arange(len(poses) + 1))
    prev.node_poses = poses
    prev.node_points = [xy[order[bounds[k] : bounds[k + 1]]] for k in range(len(poses))]
    prev.node_steps = steps
    prev.node_sessions = sessions
    prev.closures = [(int(i), int(j)) for i, j in graph.get("closures", [])]
    prev.closure_scores = [float(s) for s in graph.get("closure_scores", [])]


def earlier_node_scans(path: Path, mount: LaserMount | None) -> list[tuple[np.ndarray, np.ndarray]]:
    """The scans of the earlier mapping runs that the continued result at `path` holds: its pose graph's
    nodes of those runs, each as its laser's final pose (3,) on `mount` and its returns (K, 2, the back
    end's own: within 20 m, one per 0.1 m voxel) in that laser's frame. Empty for a result that continues
    nothing, or one whose run could not find itself in the earlier map (their nodes are not kept)."""
    path = Path(path)
    parts = {msg.topic: msg.value for msg in _result_messages(path, [ch.SLAM_GRAPH, ch.SLAM_GRAPH_SCANS])}
    prev = PreviousRun(path, np.empty((0, 2)), np.empty(0), None)  # (its graph and scans only)
    _graph_into(prev, parts, path)
    if prev.node_poses is None:
        return []
    lasers = laser_poses(mount, prev.node_poses)
    own = prev.node_sessions.max()  # the result's own run: the graph's last (its nodes come after the earlier ones)
    return [
        (lasers[k], transform_points(inverse(lasers[k]), prev.node_points[k]))
        for k in np.flatnonzero(prev.node_sessions < own)
    ]


@dataclass
class Start:
    """Where a continued run starts: its first scan's base pose in the old map, and how it was found."""

    pose: np.ndarray | None
    """None: the run could not find itself."""
    how: str
    """"initial pose" (given), "found" (two of its scans found in the old map), or "lost"."""
    scan: int = 0
    """The scan found in the old map from which the start was carried back (0 for a given pose); the next
    candidate confirmed it."""
    travel_m: float = 0.0
    """The odometry's travel up to that scan."""
    scans_searched: int = 0
    """Scans searched for in the old map."""

    def record(self) -> dict:
        return {
            "how": self.how,
            "pose": None if self.pose is None else [float(v) for v in self.pose],
            "found_at_scan": self.scan,
            "travel_m": round(self.travel_m, 3),
            "scans_searched": self.scans_searched,
        }


SEARCH_TRAVEL_M = 30.0
"""How far the new run's first scans may go, by its odometry, before a run that has not found itself in
the old map is given up as lost."""
CANDIDATE_TRAVEL_M = 0.5
CANDIDATE_TURN_RAD = 0.5
"""A scan is searched for in the old map every this much travel or turn of the new run (as the graph's
nodes are taken)."""
CANDIDATES_AT_ONCE = 4
"""Scans searched for together (each region's field is built once for them)."""
CONFIRM_M, CONFIRM_PER_M = 0.2, 0.1
CONFIRM_RAD, CONFIRM_PER_RAD = 0.05, 0.2
"""Two scans found in the old map confirm each other when the odometry between them takes the first one's
pose to within 0.2 m + 0.1 of the distance and 0.05 rad + 0.2 of the turn (three standard deviations of the
motion model's rotation noise) of the second one's: a look-alike place is not found twice, consistently."""


def find_start(
    prev: PreviousRun,
    log: InputLog,
    initial_pose: np.ndarray | None,
    workers: int = 1,
    vehicle: AckermannVehicle | None = None,
    laser_yaw_rad: float = 0.0,
) -> Start:
    """Where the new run's first scan stands in the old map (the base's pose): the `initial_pose` given, or
    where two consecutive scans of its first `SEARCH_TRAVEL_M` of travel (one each `CANDIDATE_TRAVEL_M`) are
    found in the old map, each searched over the whole map and every heading (`PoseGraphBackEnd.locate`),
    the two agreeing with the odometry between them; the first of them carried back to the first scan by the
    odometry. An Ackermann log's odometry is its controls dead-reckoned with its `vehicle`
    (`pipelines.run.scans.scan_stream`); `laser_yaw_rad`: the laser's mounting yaw the run adds to every
    bearing (`RunConfig.laser_yaw_offset_rad`), so that the scans are searched as the run saw the old ones.
    `workers`: threads searching the map's regions at once (`PoseGraphBackEnd.locate`)."""
    if initial_pose is not None:
        return Start(np.asarray(initial_pose, dtype=float), "initial pose")
    mount = log.mount
    graph = prev.graph(mount)
    if graph is None:
        raise InputError(
            f"{prev.path}: holds no pose graph with its scans (written with loop closure off, or by an older "
            "gslam), which finding the run in its map needs; give --initial-pose X Y YAW"
        )
    from pipelines.run.scans import scan_stream

    backend = PoseGraphBackEnd(BackEndSettings())
    backend.add_previous(*graph)
    odom0 = last_odom = None
    candidates: list[tuple[int, float, np.ndarray, np.ndarray]] = []  # (scan, travel, odometry, returns)
    last_hit: tuple | None = None  # (base pose, odometry, scan, travel) of the last candidate found
    travel = turn = 0.0
    searched = 0

    def search() -> Start | None:
        """The candidates found in the old map, in order; the start once two consecutive ones agree."""
        nonlocal last_hit, searched
        hits = backend.locate([ends for _, _, _, ends in candidates], workers)
        for (index, at_m, odom, _), hit in zip(candidates, hits, strict=True):
            searched += 1
            if hit is None:
                last_hit = None
                continue
            base = base_poses(mount, hit[0])
            if last_hit is not None:
                moved = compose(inverse(last_hit[1]), odom)
                expected = compose(last_hit[0], moved)
                if math.hypot(expected[0] - base[0], expected[1] - base[1]) <= CONFIRM_M + CONFIRM_PER_M * math.hypot(
                    moved[0], moved[1]
                ) and abs(wrap_angle_scalar(expected[2] - base[2])) <= CONFIRM_RAD + CONFIRM_PER_RAD * abs(moved[2]):
                    # carried back from the first of the two, the nearer the first scan
                    first, first_odom, first_index, first_m = last_hit
                    back = compose(inverse(first_odom), np.asarray(odom0, dtype=float))
                    return Start(compose(first, back), "found", first_index, first_m, searched)
            last_hit = (base, odom, index, at_m)
        candidates.clear()
        return None

    c, s = math.cos(laser_yaw_rad), math.sin(laser_yaw_rad)
    turned = np.array([[c, s], [-s, c]])  # rows (x, y) @ turned: each turned by the yaw
    for index, _, odom, ends, _ in scan_stream(log, vehicle):
        if laser_yaw_rad:
            ends = ends @ turned
        if odom0 is None:
            odom0 = odom
        else:
            delta = odometry_delta(last_odom, odom)
            travel += math.hypot(delta[0], delta[1])
            turn += abs(delta[2])
        if travel > SEARCH_TRAVEL_M:
            break
        last_odom = odom
        taken = searched + len(candidates)
        if taken and travel < taken * CANDIDATE_TRAVEL_M and turn < taken * CANDIDATE_TURN_RAD:
            continue
        candidates.append((index, travel, np.asarray(odom, dtype=float), ends))
        if len(candidates) == CANDIDATES_AT_ONCE:
            start = search()
            if start is not None:
                return start
    if candidates:
        start = search()
        if start is not None:
            return start
    return Start(None, "lost", 0, travel, searched)
