"""Result writers: the output MCAP and the Rerun recording. Both write to a temporary file and move it
into place on `finish()`, which also runs on interruption, so a result always holds the steps done."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from gslam.filter import SlamFilter
from gslam.scan import ScanGeometry, inverse_measure
from mcaplog import channels as ch
from mcaplog.mcapio import AtomicMcapWriter, to_ns
from mcaplog.tempfiles import temporary_for

from .runner import Step


def probability_colors(p: np.ndarray) -> np.ndarray:
    """RGBA uint8 colours from blue (low) through green to red (high) for p scaled to its maximum."""
    if len(p) == 0:
        return np.empty((0, 4), dtype=np.uint8)
    v = np.clip(p / max(float(p.max()), 1e-300), 0.0, 1.0)
    r = np.clip(2 * v - 0.5, 0, 1)
    g = np.clip(1.5 - np.abs(4 * v - 2), 0, 1)
    b = np.clip(1.5 - 2 * v, 0, 1)
    return (np.column_stack([r, g, b, np.ones_like(v)]) * 255).astype(np.uint8)


def covariance_ellipses(mean: np.ndarray, cov: np.ndarray, sigmas: float = 3.0, n: int = 24) -> list[np.ndarray]:
    """Outlines (n points each) of the `sigmas`-sigma ellipses of 2-D Gaussians (K,2), (K,2,2)."""
    t = np.linspace(0, 2 * np.pi, n)
    circle = np.stack([np.cos(t), np.sin(t)])
    out = []
    for m, c in zip(mean, cov, strict=True):  # per landmark, a few dozen at most
        vals, vecs = np.linalg.eigh(0.5 * (c + c.T))
        out.append(m + (vecs @ (np.sqrt(np.maximum(vals, 0))[:, None] * sigmas * circle)).T)
    return out


class McapResultWriter:
    """Writes /slam/* channels (docs/CHANNELS.md) and the run's metadata."""

    def __init__(self, path: Path, metadata: dict[str, dict[str, Any]], snapshot_every: int) -> None:
        self.writer = AtomicMcapWriter(path)
        for name, data in metadata.items():
            self.writer.add_metadata(name, data)
        self.snapshot_every = snapshot_every
        self.last_ns = 0
        self.steps_written = 0

    def step(self, st: Step, flt: SlamFilter) -> None:
        r = st.result
        ns = to_ns(st.event.t_s)
        self.last_ns = ns
        w = self.writer
        w.write_proto(ch.SLAM_POSE, ch.pose_in_frame(st.event.stamp_s, *r.best_pose, ch.MAP_FRAME), ns)
        self.steps_written += 1  # the trajectory in finish() covers exactly the poses written
        particles = ch.poses_in_frame_bytes(st.event.stamp_s, r.poses, ch.MAP_FRAME)
        w.write_proto_bytes(ch.SLAM_PARTICLES, ch.PosesInFrame, particles, ns)
        w.write_json(
            ch.SLAM_STATS,
            "gslam.StepStats",
            ch.STATS_SCHEMA,
            {
                "scan_index": st.event.index,
                "t_s": st.event.t_s,
                "effective_sample_size": r.effective_sample_size,
                "resampled": r.resampled,
                "updated": r.updated,
                "map_points": r.map_points,
                "map_points_total": r.map_points_total,
                "step_ms": st.step_ms,
                "best_particle": r.best,
                "matched": r.matched,
            },
            ns,
        )
        if self.snapshot_every and st.event.index % self.snapshot_every == 0:
            xy, p = flt.map_points(r.best)
            w.write_proto(ch.SLAM_MAP, ch.point_cloud(st.event.stamp_s, xy, p), ns)

    def finish(self, flt: SlamFilter, result_meta: dict[str, Any]) -> Path:
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
        self.writer.add_metadata("result", result_meta)
        return self.writer.finish()

    def abort(self) -> None:
        self.writer.abort()


class RerunResultWriter:
    """Writes a Rerun recording (.rrd) with a default blueprint, on the `scan` and `time` timelines."""

    def __init__(
        self,
        path: Path,
        geometry: ScanGeometry,
        snapshot_every: int,
        t0_s: float,
        gps: np.ndarray | None,
        landmarks: np.ndarray | None,
        app_id: str = "gslam",
    ) -> None:
        import rerun as rr

        self.rr = rr
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = temporary_for(self.path)
        self.rec = rr.RecordingStream(app_id)
        self.rec.save(str(self.tmp), default_blueprint=self.blueprint())
        self.geometry = geometry
        self.snapshot_every = snapshot_every
        self.t0_s = t0_s
        self.bearings = geometry.bearings_rad
        self.stats: dict[str, list[float]] = {k: [] for k in ("scan", "time", "ess", "map", "ms")}
        self.online: list[np.ndarray] = []
        self.pending_scans: list[np.ndarray] = []
        self.pending_particles: list[np.ndarray] = []
        self.finished = False
        # Colours and sizes of the per-step points, once for the whole recording.
        self.rec.log("world/scan", rr.Points2D.from_fields(colors=[[255, 60, 200]], radii=0.06), static=True)
        self.rec.log("world/particles", rr.Points2D.from_fields(colors=[[255, 140, 0]], radii=0.12), static=True)
        if gps is not None and len(gps):
            self.rec.log("world/gps", rr.LineStrips2D([gps[:, 1:3]], colors=[[40, 200, 40]], radii=0.08), static=True)
        if landmarks is not None and len(landmarks):
            self.rec.log(
                "world/landmarks",
                rr.Points2D(
                    landmarks,
                    colors=[[255, 200, 0]],
                    radii=0.4,
                    labels=[f"pole {i + 1}" for i in range(len(landmarks))],
                ),
                static=True,
            )

    def blueprint(self):
        import rerun.blueprint as rrb

        return rrb.Blueprint(
            rrb.Horizontal(
                rrb.Spatial2DView(name="map", origin="world"),
                rrb.Vertical(
                    rrb.TimeSeriesView(name="effective sample size", origin="stats/effective_sample_size"),
                    rrb.TimeSeriesView(name="map points", origin="stats/map_points"),
                    rrb.TimeSeriesView(name="step time [ms]", origin="stats/step_ms"),
                ),
                column_shares=[3, 1],
            ),
            collapse_panels=True,
        )

    FLUSH_EVERY = 200
    """Steps whose scans and particles are sent to the recording together, as columns (one `log` call
    per step cost more than the filter on long logs)."""

    def step(self, st: Step, flt: SlamFilter) -> None:
        r = st.result
        self.pending_scans.append((st.event.ranges_m, st.laser_pose))  # end points computed at _flush
        self.pending_particles.append(r.poses[:, :2].copy())
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
            self._flush()
            self.rec.set_time("scan", sequence=st.event.index)
            self.rec.set_time("time", duration=st.event.t_s - self.t0_s)
            self._log_map(*flt.map_points(r.best))
        if len(self.pending_scans) >= self.FLUSH_EVERY:
            self._flush()

    def _flush(self) -> None:
        """Send the steps not yet sent: the scan end points and the particles, one row per step."""
        n = len(self.pending_scans)
        if n == 0:
            return
        rr = self.rr
        idx = [
            rr.TimeColumn("scan", sequence=self.stats["scan"][-n:]),
            rr.TimeColumn("time", duration=self.stats["time"][-n:]),
        ]
        for path, rows in (("world/scan", self._scan_end_points()), ("world/particles", self.pending_particles)):
            columns = rr.Points2D.columns(positions=np.concatenate(rows)).partition([len(a) for a in rows])
            self.rec.send_columns(path, indexes=idx, columns=columns)
        self.pending_scans, self.pending_particles = [], []

    def _scan_end_points(self) -> list[np.ndarray]:
        """The world-frame end points of the returns of each pending scan, computed for all at once."""
        ranges = np.stack([r for r, _ in self.pending_scans])
        poses = np.stack([pose for _, pose in self.pending_scans])
        ok = np.isfinite(ranges) & (ranges < self.geometry.max_range_m)
        row, beam = np.nonzero(ok)
        pts = inverse_measure(poses[row], ranges[row, beam], self.bearings[beam])
        return np.split(pts, np.cumsum(ok.sum(axis=1))[:-1])

    def _log_map(self, xy: np.ndarray, p: np.ndarray) -> None:
        self.rec.log("world/map", self.rr.Points2D(xy, colors=probability_colors(p), radii=0.07))

    def finish(self, flt: SlamFilter) -> Path:
        if self.finished:
            return self.path
        rr, rec = self.rr, self.rec
        self._flush()
        if self.stats["scan"]:
            idx = [
                rr.TimeColumn("scan", sequence=self.stats["scan"]),
                rr.TimeColumn("time", duration=self.stats["time"]),
            ]
            for name, key in (("effective_sample_size", "ess"), ("map_points", "map"), ("step_ms", "ms")):
                rec.send_columns(f"stats/{name}", indexes=idx, columns=rr.Scalars.columns(scalars=self.stats[key]))
            rec.set_time("scan", sequence=self.stats["scan"][-1])
            rec.set_time("time", duration=self.stats["time"][-1])
            self._log_map(*flt.map_points(flt.best_particle()))
            best = flt.best_particle()
            if hasattr(flt, "landmarks"):
                rec.log(
                    "world/landmark_ellipses",
                    rr.LineStrips2D(covariance_ellipses(*flt.landmarks(best)), colors=[[0, 200, 255]], radii=0.03),
                )
            if hasattr(flt, "occupancy"):
                prob, _, _ = flt.occupancy(best)
                rec.log("grid/occupancy", rr.Image((255 * (1 - prob.T[::-1])).astype(np.uint8)))
            _, traj = flt.best_trajectory()
            rec.log("world/trajectory", rr.LineStrips2D([traj[:, :2]], colors=[[230, 30, 30]], radii=0.1))
            rec.log("world/online", rr.LineStrips2D([np.asarray(self.online)], colors=[[60, 120, 255]], radii=0.05))
        rec.flush()
        rec.disconnect()
        os.replace(self.tmp, self.path)
        self.finished = True
        return self.path

    def abort(self) -> None:
        try:
            self.rec.disconnect()
        finally:
            Path(self.tmp).unlink(missing_ok=True)
