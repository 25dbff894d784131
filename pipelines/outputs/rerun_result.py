"""The Rerun recording (.rrd) of a run: steps gathered here, encoded and written by a process of its own
(`pipelines.outputs.rerun_recorder`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from gslam.filter import SlamFilter
from gslam.scan import ScanGeometry, inverse_measure
from mcaplog.tempfiles import replace as replace_temporary
from mcaplog.tempfiles import temporary_for
from pipelines.outputs import rerun_entities as entity
from pipelines.outputs.writer import RunEnd, RunStart
from pipelines.outputs.writer_child import WriterChild, start_rerun_writer
from pipelines.run import interrupts
from pipelines.run.runner import Step


def covariance_ellipses(mean: np.ndarray, cov: np.ndarray, sigmas: float = 3.0, n: int = 24) -> list[np.ndarray]:
    """Outlines (n points each) of the `sigmas`-sigma ellipses of 2-D Gaussians (K,2), (K,2,2)."""
    t = np.linspace(0, 2 * np.pi, n)
    circle = np.stack([np.cos(t), np.sin(t)])
    out = []
    for m, c in zip(mean, cov, strict=True):  # per landmark, a few dozen at most
        vals, vecs = np.linalg.eigh(0.5 * (c + c.T))
        out.append(m + (vecs @ (np.sqrt(np.maximum(vals, 0))[:, None] * sigmas * circle)).T)
    return out


_STATS_KEYS = {"effective_sample_size": "ess", "map_points": "map", "step_ms": "ms"}
"""The recording's statistics (`rerun_entities.STATS`) by the key this writer gathers them under."""


class RerunResultWriter:
    """Writes a Rerun recording (.rrd) with a default blueprint, on the `scan` and `time` timelines.

    The recording is encoded and written by a process of its own (`pipelines.outputs.rerun_recorder`), started here:
    this object gathers the steps, computes what needs the filter (scan end points, maps, trajectories)
    and sends plain arrays; rerun is never imported in the filter's process."""

    FLUSH_EVERY = 200
    """Steps whose scans and particles are sent to the recording together, as columns (one `log` call
    per step cost more than the filter on long logs)."""

    LIVE_FLUSH_EVERY = 25
    """The same when the recording is also streamed to a viewer (`live_url`): the view follows the run."""

    def __init__(
        self,
        path: Path,
        snapshot_every: int,
        app_id: str = "gslam",
        writer: WriterChild | None = None,
        live_url: str | None = None,
    ) -> None:
        """Starts the child writer, or takes `writer`, the one started beforehand by
        `writer_child.start_rerun_writer`. `live_url`: also stream to the viewer listening there."""
        self.path = Path(path)
        self.live_url = live_url
        self.flush_every = self.LIVE_FLUSH_EVERY if live_url else self.FLUSH_EVERY
        self.tmp: Path | None = None
        self.snapshot_every = snapshot_every
        self.app_id = app_id
        self.stats: dict[str, list[float]] = {k: [] for k in ("scan", "time", "ess", "map", "ms")}
        self.online: list[np.ndarray] = []
        self.pending_scans: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # ranges, laser pose, bearings
        self.pending_particles: list[np.ndarray] = []
        self.pending_poses: list[np.ndarray] = []  # x, y, heading, and the previous step's x, y
        self.finished = False
        self.writer = writer if writer is not None else start_rerun_writer(self.path)

    def start(self, run: RunStart) -> None:
        log = run.log
        self.open(log.geometry, log.start_s, log.gps_array(), log.landmarks_array())

    def open(self, geometry: ScanGeometry, t0_s: float, gps: np.ndarray | None, landmarks: np.ndarray | None) -> None:
        """Open the recording for scans of `geometry`, times counted from `t0_s`, with the static GPS track
        and landmarks."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with interrupts.deferred():  # a signal while the temporary exists but is not yet in self.tmp waits
            self.tmp = temporary_for(self.path)
        self.geometry = geometry
        self.t0_s = t0_s
        self.bearings = geometry.bearings_rad
        self.writer.open((str(self.tmp.resolve()), self.app_id, gps, landmarks, self.live_url))

    # --- the steps ----------------------------------------------------------------------------
    def step(self, st: Step, flt: SlamFilter) -> None:
        r = st.result
        g = st.event.geometry
        bearings = self.bearings if g is None or g == self.geometry else g.bearings_rad
        self.pending_scans.append((st.event.ranges_m, st.laser_pose, bearings))  # end points computed at _flush
        self.pending_particles.append(r.poses[:, :2].copy())
        previous = self.online[-1] if self.online else r.best_pose[:2]
        self.pending_poses.append(np.concatenate((r.best_pose[:3], previous)))  # np.r_ cost 20 us a step
        self.online.append(r.best_pose[:2].copy())
        for key, value in (
            ("scan", st.event.index),
            ("time", st.event.t_s - self.t0_s),
            ("ess", r.effective_sample_size),
            ("map", r.map_points),
            ("ms", st.step_ms),
        ):
            self.stats[key].append(value)
        if self.snapshot_every and st.event.index % self.snapshot_every == 0:
            # Sent on its own, not after a flush of the pending rows: every row and map carries its own
            # times, so the order they reach the recording in does not matter; rows are sent FLUSH_EVERY
            # steps at a time (a flush at every snapshot made 8 times as many, smaller, batches).
            xy, p = flt.map_points(r.best)
            # copies: a view would keep the filter's map buffer referenced until the sender thread has
            # pickled it, and the map update could not write that buffer again (gslam.mapupdate.windowed)
            xy, p = np.array(xy, dtype=np.float32), np.array(p, dtype=np.float32)
            self.writer.send(("map", st.event.index, st.event.t_s - self.t0_s, xy, p))
        if len(self.pending_scans) >= self.flush_every:
            self._flush()

    def _flush(self) -> None:
        """Send the steps not yet sent: the scan end points and the particles, one row per step."""
        n = len(self.pending_scans)
        if n == 0:
            return
        columns = {}
        for path, rows in ((entity.SCAN, self._scan_end_points()), (entity.PARTICLES, self.pending_particles)):
            # float32, as the recording stores positions: half the bytes through the pipe, same values
            columns[path] = (np.concatenate(rows).astype(np.float32), np.array([len(a) for a in rows]))
        scans = np.asarray(self.stats["scan"][-n:])
        times = np.asarray(self.stats["time"][-n:], dtype=float)
        stats = {name: np.asarray(self.stats[key][-n:], dtype=float) for name, key in _STATS_KEYS.items()}
        self.writer.send(("rows", scans, times, columns, np.asarray(self.pending_poses), stats))
        self.pending_scans, self.pending_particles, self.pending_poses = [], [], []

    def _scan_end_points(self) -> list[np.ndarray]:
        """The world-frame end points of the returns of each pending scan (each with its own beams),
        computed for all at once."""
        ranges = np.concatenate([r for r, _, _ in self.pending_scans])
        bearings = np.concatenate([b for _, _, b in self.pending_scans])
        poses = np.stack([pose for _, pose, _ in self.pending_scans])
        row = np.repeat(np.arange(len(poses)), [len(r) for r, _, _ in self.pending_scans])
        ok = np.isfinite(ranges) & (ranges < self.geometry.max_range_m)
        pts = inverse_measure(poses[row[ok]], ranges[ok], bearings[ok])
        return np.split(pts, np.cumsum(np.bincount(row[ok], minlength=len(poses)))[:-1])

    def finish(self, end: RunEnd) -> Path:
        """Send the rest and the final map and trajectories; the child writer's memory and processor time
        go to the result's record."""
        if self.finished:
            return self.path
        flt = end.filter
        self._flush()
        final: dict[str, Any] = {}
        if self.stats["scan"]:
            best = flt.best_particle()
            xy, p = flt.map_points(best)
            _, traj = flt.best_trajectory()
            occ = end.occupancy
            final = {
                "last": (int(self.stats["scan"][-1]), float(self.stats["time"][-1])),
                "navigation_grid": None if occ is None else (occ.state, occ.origin_xy_m, occ.resolution_m),
                "map": (np.asarray(xy), np.asarray(p)),
                "landmark_ellipses": covariance_ellipses(*flt.landmarks(best)) if hasattr(flt, "landmarks") else None,
                "occupancy_image": None,
                "trajectory": np.asarray(traj[:, :2]),
                "online": np.asarray(self.online),
                "graph": None if end.graph is None else graph_segments(end.graph),
                "sessions": [
                    (
                        s["session"],
                        np.asarray(s["t_s"], dtype=float),
                        np.column_stack([s["x_m"], s["y_m"], s["yaw_rad"]]),
                    )
                    for s in (end.sessions or [])
                    if s["x_m"] and s["map"] == 0  # in this map's frame (an earlier map's runs are not)
                ],
            }
            if hasattr(flt, "occupancy"):
                prob, _, _ = flt.occupancy(best)
                final["occupancy_image"] = (255 * (1 - prob.T[::-1])).astype(np.uint8)
        self.writer.finish(("finish", final))
        replace_temporary(self.tmp, self.path)
        self.finished = True
        end.result["peak_rss_mb_rrd_writer"] = self.writer.peak_rss_mb
        end.result["cpu_s_rrd_writer"] = self.writer.cpu_s
        return self.path

    def abort(self) -> None:
        try:
            self.writer.abort()
        finally:
            if self.tmp is not None:
                self.tmp.unlink(missing_ok=True)


def graph_segments(graph: dict[str, Any]) -> dict[str, np.ndarray]:
    """The pose graph as line segments (K, 2, 2) per kind of edge, and the nodes (N, 2), for the recording."""
    xy = np.column_stack([graph["x_m"], graph["y_m"]]).reshape(-1, 2)

    def segments(pairs: list[list[int]]) -> np.ndarray:
        ij = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        return np.stack([xy[ij[:, 0]], xy[ij[:, 1]]], axis=1)

    return {
        "nodes": xy,
        "sequential": segments(graph["sequential"]),
        "closures": segments(graph["closures"]),
        "rejected": segments(graph["rejected"]),
    }
