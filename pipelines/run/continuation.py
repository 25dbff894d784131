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

A result can hold more than one map: a run that could not find itself (`--if-lost new`) maps in its own
frame, and the maps before it are kept apart, each with its graph (`/slam/earlier_maps`,
`/slam/earlier_graphs`, `/slam/earlier_graph_scans`). A later run is searched for in every one of them,
the result's own first, and continues the one it is found in (`PreviousRun.with_map_first`).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
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
class SavedGraph:
    """A pose graph as a result saves it (`/slam/graph` and `/slam/graph_scans`, or an earlier map's)."""

    poses: np.ndarray
    """(M, 3) the nodes' optimised base poses, in the frame of their map."""
    points: list[np.ndarray]
    """Each node's returns (K, 2), in that frame."""
    steps: np.ndarray
    """(M,) each node's step in its own run."""
    sessions: np.ndarray
    """(M,) the mapping run each node belongs to."""
    closures: list[tuple[int, int]] = field(default_factory=list)
    closure_scores: list[float] = field(default_factory=list)

    def for_backend(self, mount: LaserMount | None) -> PreviousGraph:
        """The graph as the back end takes it (`PoseGraphBackEnd.add_previous`), its poses the laser's on
        `mount` (the new run's)."""
        return PreviousGraph(
            laser_poses(mount, self.poses), self.points, self.steps, self.sessions, self.closures, self.closure_scores
        )

    def record(self, map_index: int) -> dict:
        """The graph as `/slam/earlier_graphs` holds it (`gslam.PoseGraph`, with the `map` it lies under)."""
        return {
            "map": int(map_index),
            "x_m": self.poses[:, 0].tolist(),
            "y_m": self.poses[:, 1].tolist(),
            "yaw_rad": self.poses[:, 2].tolist(),
            "step": [int(v) for v in self.steps],
            "session": [int(v) for v in self.sessions],
            "closures": [[int(i), int(j)] for i, j in self.closures],
            "closure_scores": [float(v) for v in self.closure_scores],
        }

    def returns(self) -> tuple[np.ndarray, np.ndarray]:
        """Every node's returns and the node each belongs to, as `/slam/graph_scans` holds them."""
        return node_returns(self.points)


def node_returns(points: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Each node's returns (a list of (K_k, 2)) as one array (K, 2) and the node each belongs to (K,): the
    form of `/slam/graph_scans` (`mcaplog.channels.node_returns_cloud`; `_graph_of` splits it again)."""
    node = np.repeat(np.arange(len(points)), [len(p) for p in points])
    xy = np.concatenate(points) if points else np.empty((0, 2))
    return xy.reshape(-1, 2), node


@dataclass
class SavedMap:
    """One map of a result, in its own frame, and the pose graph under it (None: none was saved)."""

    xy: np.ndarray  # (K, 2)
    p: np.ndarray  # (K,)
    graph: SavedGraph | None = None


@dataclass
class PreviousRun:
    """What a `gslam process` result holds for a run that continues it."""

    path: Path
    maps: list[SavedMap]
    """The result's maps: 0 its own (`/slam/map_final` and `/slam/graph`), k >= 1 those of earlier runs that
    later ones could not find themselves in (`/slam/earlier_maps` and `/slam/earlier_graphs`), each in its
    own frame."""
    sessions: list[Session] = field(default_factory=list)
    """Every earlier run, the last one the result's own."""

    @property
    def map_xy(self) -> np.ndarray:
        return self.maps[0].xy

    @property
    def map_p(self) -> np.ndarray:
        return self.maps[0].p

    @property
    def earlier_maps(self) -> list[SavedMap]:
        return self.maps[1:]

    def graph(self, mount: LaserMount | None, k: int = 0) -> PreviousGraph | None:
        """Map k's graph for the back end, its poses the laser's on `mount` (the new run's); None where the
        result saved none."""
        g = self.maps[k].graph
        return None if g is None or len(g.poses) == 0 else g.for_backend(mount)

    def with_map_first(self, k: int) -> PreviousRun:
        """The same result with its map k as the one a new run continues: the others follow in their order,
        and each run says its map by the new numbers."""
        if k == 0:
            return self
        order = [k, *(m for m in range(len(self.maps)) if m != k)]
        renumber = {old: new for new, old in enumerate(order)}
        sessions = [replace(s, map=renumber[s.map]) for s in self.sessions]
        return PreviousRun(self.path, [self.maps[m] for m in order], sessions)


def load_previous(path: Path) -> PreviousRun:
    """The maps, graphs and trajectories of the `gslam process` result at `path`; InputError, naming the file,
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
    earlier_graphs: dict[int, dict] = {}
    earlier_scans: dict[int, object] = {}

    def read(msg) -> None:
        if msg.topic == ch.SLAM_POSE:
            t_s.append(msg.t_s)
        elif msg.topic == ch.SLAM_EARLIER_MAPS:
            earlier.append(ch.cloud_arrays(msg.value))
        elif msg.topic == ch.SLAM_EARLIER_GRAPHS and isinstance(msg.value, dict):
            earlier_graphs[int(msg.value.get("map", -1))] = msg.value
        elif msg.topic == ch.SLAM_EARLIER_GRAPH_SCANS:
            earlier_scans[ch.map_index(msg.value.frame_id)] = msg.value
        else:
            parts[msg.topic] = msg.value

    topics = [ch.SLAM_POSE, ch.SLAM_TRAJECTORY, ch.SLAM_MAP_FINAL, ch.SLAM_GRAPH, ch.SLAM_GRAPH_SCANS]
    more = [ch.SLAM_SESSIONS, ch.SLAM_EARLIER_MAPS, ch.SLAM_EARLIER_GRAPHS, ch.SLAM_EARLIER_GRAPH_SCANS]
    for msg in _result_messages(path, [*topics, *more], src):
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
    own = len(sessions) - 1
    maps = [SavedMap(map_xy, map_p, _graph_of(parts.get(ch.SLAM_GRAPH), parts.get(ch.SLAM_GRAPH_SCANS), own, path))]
    for k, (xy, p) in enumerate(earlier, start=1):
        maps.append(SavedMap(xy, p, _graph_of(earlier_graphs.get(k), earlier_scans.get(k), own, path)))
    for s in sessions:
        if not 0 <= s.map < len(maps):
            raise InputError(f"{path}: /slam/sessions puts run {s.index} in map {s.map}; the result holds {len(maps)}")
    return PreviousRun(path, maps, sessions)


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


def _graph_of(graph: object, scans: object, own_session: int, path: Path) -> SavedGraph | None:
    """A saved pose graph (`gslam.PoseGraph`) and its nodes' returns (`/slam/graph_scans`), or None where the
    result holds none (written with loop closure off, or by an older gslam); InputError where they do not
    agree. `own_session`: the run of nodes that do not say theirs (a result of a run that continued none)."""
    if not (isinstance(graph, dict) and graph.get("x_m") and scans is not None):
        return None
    try:
        poses = np.column_stack([graph["x_m"], graph["y_m"], graph["yaw_rad"]]).astype(float)
        steps = np.asarray(graph["step"], dtype=np.int64)
        sessions = np.asarray(graph.get("session", [own_session] * len(steps)), dtype=np.int64)
        xy, node = ch.node_returns_arrays(scans)
        closures = [(int(i), int(j)) for i, j in graph.get("closures", [])]
        scores = [float(v) for v in graph.get("closure_scores", [])]
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{path}: its pose graph is not what gslam writes ({e})") from None
    if len(steps) != len(poses) or len(sessions) != len(poses) or (len(node) and node.max() >= len(poses)):
        raise InputError(f"{path}: its pose graph's nodes and their scans do not agree")
    order = np.argsort(node, kind="stable")
    bounds = np.searchsorted(node[order], np.arange(len(poses) + 1))
    points = [xy[order[bounds[k] : bounds[k + 1]]] for k in range(len(poses))]
    return SavedGraph(poses, points, steps, sessions, closures, scores)


def earlier_node_scans(path: Path, mount: LaserMount | None) -> list[tuple[np.ndarray, np.ndarray]]:
    """The scans of the earlier mapping runs that the continued result at `path` holds in its own map: its
    pose graph's nodes of those runs, each as its laser's final pose (3,) on `mount` and its returns (K, 2,
    the back end's own: within 20 m, one per 0.1 m voxel) in that laser's frame. Empty for a result that
    continues nothing, or one whose run could not find itself in the earlier maps."""
    path = Path(path)
    parts = {msg.topic: msg.value for msg in _result_messages(path, [ch.SLAM_GRAPH, ch.SLAM_GRAPH_SCANS])}
    graph = _graph_of(parts.get(ch.SLAM_GRAPH), parts.get(ch.SLAM_GRAPH_SCANS), 0, path)
    if graph is None:
        return []
    lasers = laser_poses(mount, graph.poses)
    own = graph.sessions.max()  # the result's own run: the graph's last (its nodes come after the earlier ones)
    return [
        (lasers[k], transform_points(inverse(lasers[k]), graph.points[k])) for k in np.flatnonzero(graph.sessions < own)
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
    """Scans searched for in the old map (in all of them, where the result holds more than one)."""
    map: int = 0
    """The map of the previous result it was found in (`PreviousRun.maps`): 0 its own."""
    sigma_xy_m: float = 0.0
    sigma_phi_rad: float = 0.0
    """How far the start may be off for having been carried back from the scan found (sd; m, rad): the
    odometry's error over that travel and turn (`CARRY_SD_PER_M`, `CARRY_SD_PER_RAD`); 0 for a start found
    at the first scan or given."""

    def record(self) -> dict:
        return {
            "how": self.how,
            "map": self.map,
            "pose": None if self.pose is None else [float(v) for v in self.pose],
            "sigma_xy_m": round(self.sigma_xy_m, 4),
            "sigma_phi_rad": round(self.sigma_phi_rad, 4),
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
CARRY_SD_PER_M, CARRY_SD_PER_RAD = CONFIRM_PER_M / 3, CONFIRM_PER_RAD / 3
"""How far a start carried back by the odometry from the scan found to the first scan may be off (sd), per
metre of travel and per radian of turn: a third of the confirmation's tolerances (three sd). The filter's
particles start spread so (`SlamRunner`), so that the first scans' matches against the old map pick the
start out, rather than every particle taking the odometry's error over a turn as the map's frame."""


def find_start(
    prev: PreviousRun,
    log: InputLog,
    initial_pose: np.ndarray | None,
    workers: int = 1,
    vehicle: AckermannVehicle | None = None,
    laser_yaw_rad: float = 0.0,
) -> Start:
    """Where the new run's first scan stands in one of the previous result's maps (the base's pose): the
    `initial_pose` given (in the result's own map), or where two consecutive scans of its first
    `SEARCH_TRAVEL_M` of travel (one each `CANDIDATE_TRAVEL_M`) are found in a map, each searched over the
    whole map and every heading (`PoseGraphBackEnd.locate`), the two agreeing with the odometry between them;
    the first of them carried back to the first scan by the odometry. The result's own map is searched first,
    then each earlier one it keeps apart (`PreviousRun.maps`). An Ackermann log's odometry is its controls
    dead-reckoned with its `vehicle` (`pipelines.run.scans.scan_stream`); `laser_yaw_rad`: the laser's
    mounting yaw the run adds to every bearing (`RunConfig.laser_yaw_offset_rad`), so that the scans are
    searched as the run saw the old ones. `workers`: threads searching the map's regions at once."""
    if initial_pose is not None:
        return Start(np.asarray(initial_pose, dtype=float), "initial pose")
    graphs = [(k, prev.graph(log.mount, k)) for k in range(len(prev.maps))]
    if graphs[0][1] is None:
        raise InputError(
            f"{prev.path}: holds no pose graph with its scans (written with loop closure off, or by an older "
            "gslam), which finding the run in its map needs; give --initial-pose X Y YAW"
        )
    candidates = _Candidates(log, vehicle, laser_yaw_rad)
    searched = 0
    lost = Start(None, "lost")
    for k, graph in graphs:
        if graph is None:  # an earlier map saved without its graph (by an older gslam): it cannot be searched
            continue
        start = _find_in(graph, candidates, log.mount, workers)
        searched += start.scans_searched
        if start.pose is not None:
            return replace(start, map=k, scans_searched=searched)
        lost = replace(start, scans_searched=searched)
    return lost


class _Candidates:
    """The new run's scans that the start search looks for, (scan, travel, odometry, returns, turn) each: one every
    `CANDIDATE_TRAVEL_M` or `CANDIDATE_TURN_RAD` of its first `SEARCH_TRAVEL_M` of travel, the first scan
    first. Read from the log as far as a search asks for them, and kept, so that the next map's search takes
    the same ones without reading the log again."""

    def __init__(self, log: InputLog, vehicle: AckermannVehicle | None, laser_yaw_rad: float) -> None:
        self.taken: list[tuple[int, float, np.ndarray, np.ndarray, float]] = []
        self.travel_m = 0.0
        """The odometry's travel over the scans read so far."""
        self._rows = self._read(log, vehicle, laser_yaw_rad)

    def batches(self) -> Iterator[list[tuple[int, float, np.ndarray, np.ndarray, float]]]:
        """The candidates in order, `CANDIDATES_AT_ONCE` at a time (each region's field is built once for them)."""
        at = 0
        while True:
            while len(self.taken) < at + CANDIDATES_AT_ONCE and (row := next(self._rows, None)) is not None:
                self.taken.append(row)
            batch = self.taken[at : at + CANDIDATES_AT_ONCE]
            if not batch:
                return
            yield batch
            at += CANDIDATES_AT_ONCE

    def _read(
        self, log: InputLog, vehicle: AckermannVehicle | None, laser_yaw_rad: float
    ) -> Iterator[tuple[int, float, np.ndarray, np.ndarray, float]]:
        from pipelines.run.scans import scan_stream

        c, s = math.cos(laser_yaw_rad), math.sin(laser_yaw_rad)
        turned = np.array([[c, s], [-s, c]])  # rows (x, y) @ turned: each turned by the yaw
        last_odom = None
        turn = 0.0
        for index, _, odom, ends, _ in scan_stream(log, vehicle):
            if laser_yaw_rad:
                ends = ends @ turned
            if last_odom is not None:
                delta = odometry_delta(last_odom, odom)
                self.travel_m += math.hypot(delta[0], delta[1])
                turn += abs(delta[2])
            if self.travel_m > SEARCH_TRAVEL_M:
                return
            last_odom = odom
            taken = len(self.taken)
            if taken and self.travel_m < taken * CANDIDATE_TRAVEL_M and turn < taken * CANDIDATE_TURN_RAD:
                continue
            yield index, self.travel_m, np.asarray(odom, dtype=float), ends, turn


def _find_in(graph: PreviousGraph, candidates: _Candidates, mount: LaserMount | None, workers: int) -> Start:
    """`find_start` in one map, whose pose graph is `graph`."""
    backend = PoseGraphBackEnd(BackEndSettings())
    backend.add_previous(*graph)
    last_hit: tuple | None = None  # (base pose, odometry, scan, travel, turn) of the last candidate found
    searched = 0
    for batch in candidates.batches():
        hits = backend.locate([ends for _, _, _, ends, _ in batch], workers)
        for (index, at_m, odom, _, turn), hit in zip(batch, hits, strict=True):
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
                    # carried back from the first of the two, the nearer the first scan (the first candidate)
                    first, first_odom, first_index, first_m, first_turn = last_hit
                    back = compose(inverse(first_odom), candidates.taken[0][2])
                    return Start(
                        compose(first, back), "found", first_index, first_m, searched,
                        sigma_xy_m=CARRY_SD_PER_M * first_m, sigma_phi_rad=CARRY_SD_PER_RAD * first_turn,
                    )  # fmt: skip
            last_hit = (base, odom, index, at_m, turn)
    return Start(None, "lost", 0, candidates.travel_m, searched)
