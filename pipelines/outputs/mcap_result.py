"""The result MCAP: the /slam/* channels of docs/CHANNELS.md and the run's metadata, written to a
temporary file and moved into place on `finish()`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LaserScan_pb2 import LaserScan
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

from gslam.filter import SlamFilter
from gslam.se2 import compose_inverse
from mcaplog import channels as ch
from mcaplog import wire
from mcaplog.mcapio import AtomicMcapWriter, to_ns
from pipelines.outputs.writer import RunEnd, RunStart
from pipelines.run import interrupts
from pipelines.run.runner import Step

PATH_POSES_MAX = 512
"""Most poses in one /slam/path message: past it the updates are thinned by a power-of-two stride."""


def path_levels(update_levels: np.ndarray, last_level: int, poses_max: int = PATH_POSES_MAX) -> np.ndarray:
    """The levels (steps) a /slam/path message shows: the map updates so far (the filter's keyframes,
    GMapping's linearUpdate nodes), every 2^k-th of them when there are more than `poses_max` (the same
    updates stay in from one message to the next, so the drawn path does not shimmer), and the last step.
    """
    levels = np.asarray(update_levels, dtype=np.intp)
    stride = 1
    while len(levels) > stride * (poses_max - 1):
        stride *= 2
    levels = levels[::stride]
    return levels if len(levels) and levels[-1] == last_level else np.append(levels, last_level)


class McapResultWriter:
    """Writes /slam/* channels (docs/CHANNELS.md) and the run's metadata."""

    def __init__(self, path: Path, snapshot_every: int) -> None:
        self.path = Path(path)
        self.snapshot_every = snapshot_every
        self.writer: AtomicMcapWriter | None = None
        self.last_ns = 0
        self.steps_written = 0
        self._update_levels = np.empty(1024, dtype=np.intp)  # steps at which the map was updated, in [:_updates]
        self._updates = 0

    def start(self, run: RunStart) -> None:
        self.geometry = run.log.geometry
        mount = run.log.mount
        self.mount = (0.0, 0.0, 0.0) if mount is None else (mount.x_m, mount.y_m, mount.yaw_rad)
        with interrupts.deferred():  # a signal while the temporary exists but is not yet in self.writer waits
            self.writer = AtomicMcapWriter(self.path)
        for name, data in run.metadata.items():
            self.writer.add_metadata(name, data)

    def step(self, st: Step, flt: SlamFilter) -> None:
        r = st.result
        ns = to_ns(st.event.t_s)
        self.last_ns = ns
        w = self.writer
        w.write_proto_bytes(
            ch.SLAM_POSE, PoseInFrame, wire.pose_in_frame(st.event.stamp_s, *r.best_pose, ch.MAP_FRAME), ns
        )
        self._frames(st, ns)
        self.steps_written += 1  # the trajectory in finish() covers exactly the poses written
        particles = ch.poses_in_frame_bytes(st.event.stamp_s, r.poses, ch.MAP_FRAME)
        w.write_proto_bytes(ch.SLAM_PARTICLES, ch.PosesInFrame, particles, ns)
        stats = ch.step_stats_json(
            st.event.index,
            st.event.t_s,
            r.effective_sample_size,
            r.resampled,
            r.updated,
            r.map_points,
            r.map_points_total,
            st.step_ms,
            r.best,
            r.matched,
        )
        w.write_json_bytes(ch.SLAM_STATS, "gslam.StepStats", ch.STATS_SCHEMA, stats, ns)
        if r.updated and len(flt.tree):
            self._path(st, flt, ns)
        if self.snapshot_every and st.event.index % self.snapshot_every == 0:
            xy, p = flt.map_points(r.best)
            w.write_proto(ch.SLAM_MAP, ch.point_cloud(st.event.stamp_s, xy, p), ns)

    def finish(self, end: RunEnd) -> Path:
        """The navigation grid (if built), the final map and trajectory (and the baselines' landmarks or
        grid), and the result's record; then the file is moved into place."""
        flt = end.filter
        if end.occupancy is not None:
            occ = end.occupancy
            msg = ch.navigation_grid(occ.t_s, occ.state, occ.origin_xy_m, occ.resolution_m)
            self.writer.write_proto(ch.MAP_OCCUPANCY, msg, self.last_ns)
        best = flt.best_particle()
        times, traj = flt.best_trajectory()
        # An interruption can fall between the filter's step and its writing: publish the steps written.
        times, traj = times[: self.steps_written], traj[: self.steps_written]
        ns = self.last_ns
        t_last = float(times[-1]) if len(times) else 0.0
        xy, p = flt.map_points(best)
        self.writer.write_proto(ch.SLAM_MAP_FINAL, ch.point_cloud(t_last, xy, p), ns)
        trajectory = ch.poses_in_frame_bytes(t_last, traj, ch.MAP_FRAME)
        self.writer.write_proto_bytes(ch.SLAM_TRAJECTORY, ch.PosesInFrame, trajectory, ns)
        if hasattr(flt, "landmarks"):
            mean, cov = flt.landmarks(best)
            self.writer.write_json(
                ch.SLAM_LANDMARKS,
                "gslam.LandmarkMap",
                ch.SLAM_LANDMARKS_SCHEMA,
                {
                    "x_m": mean[:, 0].tolist(),
                    "y_m": mean[:, 1].tolist(),
                    "cov": cov.reshape(-1, 4).tolist(),
                },
                ns,
            )
        if hasattr(flt, "occupancy"):
            prob, origin, cell = flt.occupancy(best)
            self.writer.write_proto(ch.SLAM_GRID, ch.occupancy_grid(t_last, prob, origin, cell), ns)
        if end.graph is not None:
            self.writer.write_json(ch.SLAM_GRAPH, "gslam.PoseGraph", ch.SLAM_GRAPH_SCHEMA, end.graph, ns)
        if end.graph_scans is not None:
            scans_xy, node = end.graph_scans
            self.writer.write_proto(ch.SLAM_GRAPH_SCANS, ch.node_returns_cloud(t_last, scans_xy, node), ns)
        for k, (earlier_xy, earlier_p) in enumerate(end.earlier_maps or [], start=1):
            frame = ch.map_frame(k)
            self.writer.write_proto(ch.SLAM_EARLIER_MAPS, ch.point_cloud(t_last, earlier_xy, earlier_p, frame), ns)
        for k, earlier in enumerate(end.earlier_graphs or [], start=1):
            if earlier is None:
                continue
            graph, (scans_xy, node) = earlier
            self.writer.write_json(ch.SLAM_EARLIER_GRAPHS, "gslam.PoseGraph", ch.SLAM_GRAPH_SCHEMA, graph, ns)
            cloud = ch.node_returns_cloud(t_last, scans_xy, node, ch.map_frame(k))
            self.writer.write_proto(ch.SLAM_EARLIER_GRAPH_SCANS, cloud, ns)
        for k, run in enumerate(end.sessions or []):  # each earlier run's path, for the viewers
            poses = np.column_stack([run["x_m"], run["y_m"], run["yaw_rad"]]).reshape(-1, 3)
            path = ch.poses_in_frame_bytes(t_last, poses, ch.map_frame(run["map"]))
            self.writer.write_proto_bytes(ch.session_trajectory(k), ch.PosesInFrame, path, ns)
        if end.sessions:
            sessions = {"sessions": end.sessions}
            self.writer.write_json(ch.SLAM_SESSIONS, "gslam.Sessions", ch.SLAM_SESSIONS_SCHEMA, sessions, ns)
        self.writer.add_metadata("result", end.result)
        return self.writer.finish()

    def _path(self, st: Step, flt: SlamFilter, ns: int) -> None:
        """/slam/path: the best particle's path as it stands at this update (earlier poses move as the
        particle's history is corrected), at the updates so far and this step (`path_levels`)."""
        level = len(flt.tree) - 1
        if self._updates == len(self._update_levels):  # grown by doubling: not a list turned into an array each time
            self._update_levels = np.concatenate([self._update_levels, np.empty_like(self._update_levels)])
        self._update_levels[self._updates] = level
        self._updates += 1
        # The step's best particle is node `best` of the level it recorded (resampling came after).
        levels = path_levels(self._update_levels[: self._updates], level)
        _, poses = flt.tree.node_trajectory(st.result.best, levels)
        msg = ch.poses_in_frame_bytes(st.event.stamp_s, poses, ch.MAP_FRAME)
        self.writer.write_proto_bytes(ch.SLAM_PATH, ch.PosesInFrame, msg, ns)

    def _frames(self, st: Step, ns: int) -> None:
        """The transform tree at the step (/tf) and the scan in the laser frame (/slam/scan): map -> odom is
        the SLAM correction (the best base pose composed with the odometry's inverse), odom -> base_link
        the input's odometry, base_link -> laser the mount. Logs of controls (no odometry pose) give
        map -> base_link directly."""
        best = tuple(float(v) for v in st.result.best_pose[:3])
        t = st.event.stamp_s
        if st.odom_pose is not None:
            odom = tuple(float(v) for v in st.odom_pose[:3])
            correction = compose_inverse(best, odom)
            links = [(ch.MAP_FRAME, ch.ODOM_FRAME, *correction), (ch.ODOM_FRAME, ch.BASE_FRAME, *odom)]
        else:
            links = [(ch.MAP_FRAME, ch.BASE_FRAME, *best)]
        links.append((ch.BASE_FRAME, ch.LASER_FRAME, *self.mount))
        self.writer.write_proto_bytes(ch.TF, FrameTransforms, wire.frame_transforms(t, links), ns)
        g = st.event.geometry or self.geometry
        scan = wire.laser_scan(t, st.event.ranges_m, (g.start_angle_rad, g.end_angle_rad), ch.LASER_FRAME)
        self.writer.write_proto_bytes(ch.SLAM_SCAN, LaserScan, scan, ns)

    def abort(self) -> None:
        if self.writer is not None:
            self.writer.abort()
