"""`gslam localise MAP IN OUT`: stream an ingested log through Monte Carlo localisation in a saved map and
write the result MCAP (and a Rerun recording).

Result channels (docs/CHANNELS.md): /localise/pose (foxglove.PoseInFrame, map frame, the base's pose at
every scan), /localise/state (JSON: tracking or not, fitness, particle count, covariance, recovery),
/localise/particles (foxglove.PosesInFrame at each update, at most 1000), /tf (map -> odom -> base_link
-> laser), /localise/map (the map's obstacles, foxglove.PointCloud, once). Metadata "localise" (map,
input, configuration, software version) and "result" (summary).
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gslam import __version__
from gslam.localise import LocaliseConfig, LocaliseStep, MonteCarloLocaliser
from gslam.motion import odometry_delta
from gslam.scan import Scan
from gslam.se2 import compose_inverse
from mcaplog import channels as ch
from mcaplog.mcapio import AtomicMcapWriter, to_ns
from mcaplog.tempfiles import create_temporary
from pipelines.errors import InputError
from pipelines.localise.maps import SavedMap, load_map
from pipelines.run.input_log import InputLog, OdomEvent, ScanEvent
from pipelines.run.odometry_check import ReversalCheck

POSE = "/localise/pose"
STATE = "/localise/state"
PARTICLES = "/localise/particles"
MAP = "/localise/map"
MAX_PARTICLES_WRITTEN = 1000

STATE_SCHEMA = {
    "type": "object",
    "title": "gslam.LocaliseState",
    "properties": {
        "t_s": {"type": "number"},
        "x_m": {"type": "number"},
        "y_m": {"type": "number"},
        "yaw_rad": {"type": "number"},
        "covariance": {"type": "array", "items": {"type": "number"}, "description": "x, y, yaw; row-major 3x3"},
        "tracking": {"type": "boolean", "description": "converged on one pose that fits the scan"},
        "state": {"type": "string", "enum": ["tracking", "lost"]},
        "fitness": {"type": "number", "description": "share of the scan's returns the map explains"},
        "particles": {"type": "integer"},
        "updated": {"type": "boolean"},
        "cluster_weight": {"type": "number"},
        "injected": {"type": "integer", "description": "particles drawn afresh over the map (recovery)"},
        "step_ms": {"type": "number"},
    },
}


@dataclass
class LocaliseRequest:
    map_path: Path
    input_path: Path
    output: Path
    rrd: Path | None = None
    initial_pose: tuple[float, float, float] | None = None
    """The base's pose in the map's frame; None: global localisation."""
    initial_sigma: tuple[float, float] | None = None
    """(sd in x and y [m], sd in heading [rad]) around the initial pose; None: the config's."""
    config: LocaliseConfig = dataclasses.field(default_factory=LocaliseConfig)
    skip_scans: int = 0
    """Start at this scan of the input (the earlier ones and their motion are not used)."""


@dataclass
class LocaliseSummary:
    scans: int
    updates: int
    tracked_share: float
    converged_at_m: float | None
    """Distance travelled (odometry) at the first scan from which the filter tracks to the end of its first
    tracking run; None when it never tracks."""
    wall_s: float
    log_duration_s: float
    ms_per_scan: float
    trajectory: np.ndarray
    """(T, 3) the base's estimated pose at each scan."""
    t_s: np.ndarray
    tracking: np.ndarray
    travelled_m: np.ndarray
    map_source: str

    @property
    def real_time_factor(self) -> float:
        return self.log_duration_s / self.wall_s if self.wall_s > 0 else float("nan")

    def describe(self) -> str:
        conv = "never converged" if self.converged_at_m is None else f"converged after {self.converged_at_m:.1f} m"
        return (
            f"{self.scans} scans, {self.updates} updates; {conv}; tracking {100 * self.tracked_share:.0f} % of "
            f"scans; {self.ms_per_scan:.2f} ms per scan; real-time factor {self.real_time_factor:.0f}"
        )


class _RerunOut:
    """The recording: the map once, then per scan the pose, the path so far, particles at updates and the
    state as scalars; written to a temporary file and moved into place at the end."""

    def __init__(self, path: Path, saved: SavedMap, t0_s: float) -> None:
        import rerun as rr

        self.rr = rr
        self.path = path
        fd, self.tmp = create_temporary(path)
        os.close(fd)
        self.rec = rr.RecordingStream("gslam-localise")
        self.rec.save(str(self.tmp))
        self.rec.log("world", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        self.rec.log("world/map", rr.Points2D(saved.points, colors=[[200, 200, 200]], radii=0.04), static=True)
        self.path_xy: list[np.ndarray] = []
        self.t0_s = t0_s  # the timeline "time" counts from the log's start, as `gslam process`'s

    def step(self, k: int, st: LocaliseStep, base: np.ndarray, particles: np.ndarray | None) -> None:
        rr, rec = self.rr, self.rec
        rec.set_time("scan", sequence=k)
        rec.set_time("time", duration=st.t_s - self.t0_s)
        colour = [60, 220, 90] if st.tracking else [230, 60, 60]
        heading = 0.6 * np.array([[math.cos(base[2]), math.sin(base[2])]])
        rec.log("world/robot", rr.Arrows2D(origins=[base[:2]], vectors=heading, colors=[colour], radii=0.06))
        self.path_xy.append(base[:2].copy())
        if k % 200 == 0:  # the whole path so far (every scan would grow the file with the square of the log)
            rec.log("world/path", rr.LineStrips2D([np.array(self.path_xy)], colors=[[255, 215, 60]], radii=0.03))
        if particles is not None:
            rec.log("world/particles", rr.Points2D(particles[:, :2], colors=[[255, 140, 0]], radii=0.05))
        rec.log("stats/fitness", rr.Scalars(st.fitness))
        rec.log("stats/particles", rr.Scalars(float(st.particles)))
        rec.log("stats/tracking", rr.Scalars(1.0 if st.tracking else 0.0))

    def finish(self) -> None:
        self.rec.log("world/path", self.rr.LineStrips2D([np.array(self.path_xy)], colors=[[255, 215, 60]], radii=0.03))
        self.rec.flush()
        self.rec.disconnect()
        os.replace(self.tmp, self.path)

    def abort(self) -> None:
        try:
            self.rec.disconnect()
        finally:
            Path(self.tmp).unlink(missing_ok=True)


def scan_stream(log: InputLog) -> Iterator[tuple[int, float, np.ndarray, np.ndarray]]:
    """(scan index, log time, the odometry pose then (the base's, fr079's reversal check applied), the
    scan's end points in the laser frame (K, 2)) for every scan of an odometry log."""
    reversal = ReversalCheck()
    odom = None
    for ev in log.events():
        if isinstance(ev, OdomEvent):
            odom = reversal.update(ev.pose, ev.tv_mps)
        elif isinstance(ev, ScanEvent):
            if odom is None:
                raise InputError(f"{log.path}: scan {ev.index} has no odometry before it")
            scan = Scan(ev.stamp_s, ev.ranges_m, ev.geometry or log.geometry, log.self_return_range_m)
            _, r, b = scan.return_polar()
            yield ev.index, ev.t_s, np.asarray(odom, dtype=float), np.column_stack([r * np.cos(b), r * np.sin(b)])


def localise(req: LocaliseRequest, progress: Callable[[int, int], None] | None = None) -> LocaliseSummary:
    """Run the localisation; writes req.output (and req.rrd) atomically, nothing on failure."""
    saved = load_map(req.map_path)
    log = InputLog(req.input_path)
    if log.motion_model != "odometry":
        raise InputError(f"{req.input_path}: localisation needs odometry poses (this log has {log.motion_model})")
    mount = log.mount
    laser_of = (lambda p: p) if mount is None else (lambda p: mount.laser_of(np.asarray(p)[None])[0])
    base_of = (lambda p: p) if mount is None else mount.base_of
    initial = None if req.initial_pose is None else laser_of(np.asarray(req.initial_pose, dtype=float))
    loc = MonteCarloLocaliser(saved.field, req.config, initial, req.initial_sigma)
    out = AtomicMcapWriter(req.output, profile="gslam-localise")
    rrd = _RerunOut(req.rrd, saved, log.start_s) if req.rrd is not None else None
    t_list, poses, tracking, travelled = [], [], [], []
    odom_prev = odom_last = None
    travel = 0.0
    wall0 = time.perf_counter()
    filter_s = 0.0
    k = 0
    try:
        out.add_metadata(
            "localise",
            {
                "version": __version__,
                "map": str(req.map_path),
                "map_source": saved.source,
                "input": str(req.input_path),
                "initial_pose": list(req.initial_pose) if req.initial_pose is not None else None,
                "initial_sigma": list(req.initial_sigma) if req.initial_sigma is not None else None,
                "skip_scans": req.skip_scans,
                "config": dataclasses.asdict(req.config),
            },
        )
        first_t = log.start_s
        cloud = ch.point_cloud(first_t, saved.points, np.ones(len(saved.points)))
        out.write_proto(MAP, cloud, to_ns(first_t))
        for index, t_s, odom_last, ends in scan_stream(log):
            if index < req.skip_scans:
                odom_prev = odom_last
                continue
            t0 = time.perf_counter()
            if odom_prev is not None:
                delta = odometry_delta(odom_prev, odom_last)
                travel += math.hypot(delta[0], delta[1])
                if mount is None:
                    loc.predict(delta)
                else:  # the odometry moves the base; the particles are laser poses
                    loc.poses = mount.base_of(loc.poses)
                    loc.predict(delta)
                    loc.poses = mount.laser_of(loc.poses)
            odom_prev = odom_last
            st = loc.step(t_s, ends)
            step_ms = (time.perf_counter() - t0) * 1e3
            filter_s += step_ms / 1e3
            base = np.asarray(base_of(st.pose[None])[0] if mount is not None else st.pose)
            _write_step(out, t_s, st, base, odom_last, mount, step_ms)
            particles = None
            if st.updated:
                thin = loc.poses[:: max(1, len(loc.poses) // MAX_PARTICLES_WRITTEN)]
                particles = np.asarray(base_of(thin) if mount is not None else thin)
                out.write_proto_bytes(PARTICLES, ch.PosesInFrame, ch.poses_in_frame_bytes(t_s, particles,
                                      ch.MAP_FRAME), to_ns(t_s))  # fmt: skip
            if rrd is not None:
                rrd.step(k, st, base, particles)
            t_list.append(t_s)
            poses.append(base)
            tracking.append(st.tracking)
            travelled.append(travel)
            k += 1
            if progress is not None:
                progress(k, log.scan_count - req.skip_scans)
        if k == 0:
            raise InputError(f"{req.input_path}: no scans to localise (the input has {log.scan_count})")
        wall = time.perf_counter() - wall0
        track = np.array(tracking)
        summary = LocaliseSummary(
            scans=k,
            updates=loc.updates,
            tracked_share=float(track.mean()),
            converged_at_m=_converged_at(track, np.array(travelled)),
            wall_s=wall,
            log_duration_s=float(t_list[-1] - t_list[0]),
            ms_per_scan=1e3 * filter_s / k,
            trajectory=np.array(poses),
            t_s=np.array(t_list),
            tracking=track,
            travelled_m=np.array(travelled),
            map_source=saved.source,
        )
        out.add_metadata(
            "result",
            {
                "scans": k,
                "updates": loc.updates,
                "tracked_share": summary.tracked_share,
                "converged_at_m": summary.converged_at_m,
                "wall_s": wall,
                "ms_per_scan": summary.ms_per_scan,
            },
        )
        out.finish()
        if rrd is not None:
            rrd.finish()
        return summary
    except BaseException:
        out.abort()
        if rrd is not None:
            rrd.abort()
        raise


def _converged_at(tracking: np.ndarray, travelled: np.ndarray) -> float | None:
    """The odometry distance at the first scan the filter tracks from; None if it never does."""
    idx = np.flatnonzero(tracking)
    return None if len(idx) == 0 else float(travelled[idx[0]])


def _write_step(out, t_s: float, st: LocaliseStep, base: np.ndarray, odom: np.ndarray, mount, step_ms: float) -> None:
    ns = to_ns(t_s)
    out.write_proto(POSE, ch.pose_in_frame(t_s, *base, ch.MAP_FRAME), ns)
    state = {
        "t_s": t_s,
        "x_m": float(base[0]),
        "y_m": float(base[1]),
        "yaw_rad": float(base[2]),
        "covariance": [float(v) for v in st.covariance.ravel()],
        "tracking": bool(st.tracking),
        "state": "tracking" if st.tracking else "lost",
        "fitness": float(st.fitness),
        "particles": int(st.particles),
        "updated": bool(st.updated),
        "cluster_weight": float(st.cluster_weight),
        "injected": int(st.injected),
        "step_ms": step_ms,
    }
    out.write_json(STATE, "gslam.LocaliseState", STATE_SCHEMA, state, ns)
    map_to_odom = compose_inverse(tuple(float(v) for v in base), tuple(float(v) for v in odom))
    links = [(ch.MAP_FRAME, ch.ODOM_FRAME, *map_to_odom), (ch.ODOM_FRAME, ch.BASE_FRAME, *odom)]
    if mount is not None:
        links.append((ch.BASE_FRAME, ch.LASER_FRAME, *mount.pose))
    out.write_proto(ch.TF, ch.frame_transforms(t_s, links), ns)
