"""`gslam localise MAP IN OUT`: stream an ingested log through Monte Carlo localisation in a saved map and
write the result MCAP (and a Rerun recording).

Result channels (docs/CHANNELS.md): /localise/pose (foxglove.PoseInFrame, map frame, the base's pose at
every scan), /localise/state (JSON: tracking or not, fitness, particle count, covariance, recovery),
/localise/particles (foxglove.PosesInFrame at each update, at most 1000), /tf (map -> odom -> base_link
-> laser), /localise/map (the map's obstacles, foxglove.PointCloud, once). Metadata "localise" (map,
input, configuration, software version) and "result" (summary: scans done and in the input, interrupted and
by what signal, updates, tracking, time).

SIGINT and SIGTERM (`pipelines.run.interrupts`, as `gslam process`): the scans done are kept, both outputs
finished with them and the result marked interrupted; a scan is in the outputs whole or not at all.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

import numpy as np

from gslam import __version__
from gslam.localise import LocaliseConfig, LocaliseStep, MonteCarloLocaliser
from gslam.motion import odometry_delta
from gslam.se2 import compose_inverse
from mcaplog import channels as ch
from mcaplog.mcapio import AtomicMcapWriter, to_ns
from mcaplog.tempfiles import create_temporary
from mcaplog.tempfiles import replace as replace_temporary
from pipelines.errors import InputError, OptionError
from pipelines.evaluation.localisation import MAP_TOPIC, PARTICLES_TOPIC, POSE_TOPIC, STATE_TOPIC
from pipelines.localise.maps import MAX_COORDINATE_M, SavedMap, load_map
from pipelines.run import interrupts
from pipelines.run.input_log import InputLog
from pipelines.run.mount import base_poses, laser_poses
from pipelines.run.recorded_input import fingerprint
from pipelines.run.scans import scan_stream

POSE, STATE, PARTICLES, MAP = POSE_TOPIC, STATE_TOPIC, PARTICLES_TOPIC, MAP_TOPIC
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


RR_MAP = "world/map"
"""The map's obstacles (static): light points on the dark background, 2 screen points wide at any zoom."""
RR_ROBOT = "world/robot"
"""The base's estimate at each scan: an arrow 1 m long along its heading, green while tracking, red while lost."""
RR_FOOTPRINT = "world/footprint"
"""A ring of radius `FOOTPRINT_M` round the base, coloured as the arrow: the robot at a glance."""
RR_PATH = "world/path"
"""The estimate at each scan as a thin segment from the one before; the map view shows this entity from the
start of the timeline to the cursor: the path so far."""
RR_PARTICLES = "world/particles"
"""The particles' positions at each update."""
RR_STATS = {"fitness": "stats/fitness", "particles": "stats/particles", "tracking": "stats/tracking"}
"""The per-scan time series by name."""
FOOTPRINT_M = 0.35
TRACKING_RGB = (60, 220, 90)
LOST_RGB = (235, 60, 60)
_RING = np.column_stack([np.cos(np.linspace(0, 2 * math.pi, 25)), np.sin(np.linspace(0, 2 * math.pi, 25))])


def rerun_blueprint():
    """The recording's opening layout: the map view over most of the screen (dark background, the path so far
    up to the time cursor), and under it a strip of the three plots (fitness, particle count, tracking); the
    side panels collapsed so that the map has the room, the time panel compact."""
    import rerun.blueprint as rrb

    so_far = rrb.VisibleTimeRanges(
        [
            rrb.VisibleTimeRange(
                timeline, start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.cursor_relative()
            )
            for timeline in ("scan", "time")
        ]
    )
    everything = rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite())
    whole = rrb.TimeAxis(view_range=everything)  # the plots show the whole log, not a window at the cursor
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Spatial2DView(
                name="map (y up): green tracking, red lost",
                origin="/",
                contents="/world/**",
                overrides={RR_PATH: so_far},
                background=[18, 20, 26],
            ),
            rrb.Horizontal(
                rrb.TimeSeriesView(
                    name="fitness", origin=RR_STATS["fitness"], axis_x=whole, axis_y=rrb.ScalarAxis(range=(0.0, 1.05))
                ),
                rrb.TimeSeriesView(name="particles", origin=RR_STATS["particles"], axis_x=whole),
                rrb.TimeSeriesView(
                    name="tracking (1) / lost (0)",
                    origin=RR_STATS["tracking"],
                    axis_x=whole,
                    axis_y=rrb.ScalarAxis(range=(-0.05, 1.05)),
                ),
            ),
            row_shares=[4, 1],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline="time"),
    )


class _RerunOut:
    """The recording: the map once; the particles at each update as the run goes; at the end the robot, its
    footprint, the path and the state's time series for every scan, sent as columns (a few calls for the
    whole log rather than several per scan). Written to a temporary file with `rerun_blueprint` as its
    default layout, and moved into place at the end (after a signal, with the scans done), or dropped."""

    def __init__(self, path: Path, saved: SavedMap, t0_s: float) -> None:
        import rerun as rr

        self.rr = rr
        self.path = path
        self.tmp: Path | None = None
        self.rec = None
        try:
            with interrupts.deferred():  # a signal while the temporary exists but is not yet in self.tmp waits
                fd, self.tmp = create_temporary(path)
                os.close(fd)
            self._start(saved)
        except BaseException:  # an error or a signal while it starts: no temporary left behind
            self.abort()
            raise
        self.t0_s = t0_s  # the timeline "time" counts from the log's start, as `gslam process`'s
        self.scans: list[int] = []
        self.times_s: list[float] = []
        self.poses: list[np.ndarray] = []
        self.tracking: list[bool] = []
        self.fitness: list[float] = []
        self.particles: list[int] = []

    def _start(self, saved: SavedMap) -> None:
        """The recording stream into the temporary, with its layout and the static entities."""
        rr = self.rr
        self.rec = rr.RecordingStream("gslam-localise")
        # Only the log's timelines (`scan`, `time`), as `gslam process`'s recording.
        self.rec.set_log_time_enabled(False)
        self.rec.set_log_tick_enabled(False)
        self.rec.save(str(self.tmp), default_blueprint=rerun_blueprint())
        ui = rr.components.Radius.ui_points
        rec = self.rec
        rec.log("world", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)  # y up, as on the plots
        rec.log(RR_MAP, rr.Points2D(saved.points, colors=[[225, 228, 235]], radii=ui(2.0)), static=True)
        rec.log(RR_PARTICLES, rr.Points2D.from_fields(colors=[[255, 140, 0]], radii=ui(2.0)), static=True)
        rec.log(RR_ROBOT, rr.Arrows2D.from_fields(radii=ui(3.0)), static=True)
        rec.log(RR_FOOTPRINT, rr.LineStrips2D.from_fields(radii=ui(2.5)), static=True)
        rec.log(RR_PATH, rr.LineStrips2D.from_fields(colors=[[255, 215, 60]], radii=ui(1.0)), static=True)
        for name, colour in (("fitness", [90, 160, 255]), ("particles", [255, 140, 0]), ("tracking", [60, 220, 90])):
            rec.log(RR_STATS[name], rr.SeriesLines(colors=[colour], names=[name]), static=True)

    def step(self, k: int, st: LocaliseStep, base: np.ndarray, particles: np.ndarray | None) -> None:
        self.scans.append(k)
        self.times_s.append(st.t_s - self.t0_s)
        self.poses.append(np.asarray(base[:3], dtype=float))
        self.tracking.append(bool(st.tracking))
        self.fitness.append(float(st.fitness))
        self.particles.append(int(st.particles))
        if particles is not None:
            self.rec.set_time("scan", sequence=k)
            self.rec.set_time("time", duration=st.t_s - self.t0_s)
            self.rec.log(RR_PARTICLES, self.rr.Points2D(particles[:, :2]))

    def finish(self) -> None:
        """Send the scans done (all of them, or those before a signal) and move the recording into place."""
        rr, rec = self.rr, self.rec
        if self.poses:
            idx = [rr.TimeColumn("scan", sequence=self.scans), rr.TimeColumn("time", duration=self.times_s)]
            poses = np.array(self.poses)
            tracking = np.array(self.tracking)
            colours = np.where(tracking[:, None], TRACKING_RGB, LOST_RGB).astype(np.uint8)
            heading = np.column_stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])])
            rec.send_columns(
                RR_ROBOT,
                indexes=idx,
                columns=rr.Arrows2D.columns(origins=poses[:, :2], vectors=heading, colors=colours),
            )
            rings = poses[:, None, :2] + FOOTPRINT_M * _RING[None]
            rec.send_columns(
                RR_FOOTPRINT, indexes=idx, columns=rr.LineStrips2D.columns(strips=list(rings), colors=colours)
            )
            # The path joins two scans only where the filter tracks at both: while it is lost its estimate
            # jumps between candidate places, and a line through them would cross the walls.
            joined = tracking & np.r_[False, tracking[:-1]]
            before = np.where(joined[:, None], np.vstack([poses[:1, :2], poses[:-1, :2]]), poses[:, :2])
            segments = np.stack([before, poses[:, :2]], axis=1)
            rec.send_columns(RR_PATH, indexes=idx, columns=rr.LineStrips2D.columns(strips=list(segments)))
            series = {"fitness": self.fitness, "particles": self.particles, "tracking": tracking}
            for name, values in series.items():
                rec.send_columns(
                    RR_STATS[name], indexes=idx, columns=rr.Scalars.columns(scalars=np.asarray(values, float))
                )
        rec.flush()
        rec.disconnect()
        replace_temporary(self.tmp, self.path)

    def abort(self) -> None:
        """Drop the temporary (the recording at the final path, once finished, stays)."""
        try:
            if self.rec is not None:
                self.rec.disconnect()
        finally:
            if self.tmp is not None:
                Path(self.tmp).unlink(missing_ok=True)


def check_options(initial_pose: tuple[float, float, float] | None, initial_sigma: tuple[float, float] | None) -> None:
    """Refuse an initial pose or spread the filter cannot start from (not finite, a negative spread), in one
    line naming the option: before the map is read and the first scan (a NaN pose would run the whole log
    lost; a negative spread is a spread all the same, and reported as tracking)."""

    def given(values) -> str:
        return " ".join(f"{float(v):g}" for v in values)

    if initial_pose is not None:
        x, y, yaw = (float(v) for v in initial_pose)
        if not all(math.isfinite(v) for v in (x, y, yaw)) or max(abs(x), abs(y)) > MAX_COORDINATE_M:
            raise OptionError(
                f"--initial-pose {given(initial_pose)}: X Y YAW must be finite numbers (m, m, rad), X and Y "
                f"within {MAX_COORDINATE_M:g} m of 0"
            )
    if initial_sigma is not None:
        if initial_pose is None:
            raise OptionError("--initial-sigma needs --initial-pose")
        sxy, syaw = (float(v) for v in initial_sigma)
        if not (math.isfinite(sxy) and math.isfinite(syaw) and sxy >= 0 and syaw >= 0) or sxy > MAX_COORDINATE_M:
            raise OptionError(
                f"--initial-sigma {given(initial_sigma)}: XY and YAW are standard deviations (m, rad): finite "
                "and not negative"
            )


@dataclass
class _Scans:
    """What the scans gave so far (the outputs hold exactly these), and how the loop over them ended."""

    t_s: list[float] = dataclasses.field(default_factory=list)
    poses: list[np.ndarray] = dataclasses.field(default_factory=list)
    tracking: list[bool] = dataclasses.field(default_factory=list)
    travelled: list[float] = dataclasses.field(default_factory=list)
    filter_s: float = 0.0
    total: int = 0
    """The scans the input holds from `skip_scans` on."""
    writing: bool = False
    """A scan's messages are being written: a stop now (a second signal, which aborts) leaves them torn."""
    torn: bool = False
    stopped: KeyboardInterrupt | None = None
    """The signal that stopped the scans before the end: the outputs are finished and marked interrupted."""
    after_last_scan: KeyboardInterrupt | None = None
    """A signal that came once every scan was done: the outputs are whole; raised after they are finished."""
    error: BaseException | None = None
    """An error: the outputs are dropped, the error raised."""

    @property
    def count(self) -> int:
        return len(self.t_s)


def localise(req: LocaliseRequest, progress: Callable[[int, int], None] | None = None) -> LocaliseSummary:
    """Run the localisation; writes req.output (and req.rrd), each atomically. SIGINT or SIGTERM mid-run
    (`pipelines.run.interrupts`, as `gslam process`) finishes both with the scans done, the result marked
    interrupted, and re-raises the signal with a note saying what was written; a signal once every scan is
    done finishes them whole, unmarked. An error (or a stop before the first scan) leaves nothing."""
    check_options(req.initial_pose, req.initial_sigma)
    saved = load_map(req.map_path)
    log = InputLog(req.input_path)
    mount = log.mount
    initial = None if req.initial_pose is None else laser_poses(mount, req.initial_pose)
    loc = MonteCarloLocaliser(saved.field, req.config, initial, req.initial_sigma)
    if req.rrd is not None:
        import rerun  # noqa: F401  (its import takes a while: before any temporary exists)
    scans = _Scans(total=max(0, log.scan_count - req.skip_scans))
    outputs = _Outputs()
    wall0 = time.perf_counter()
    _run_scans(req, log, loc, saved, outputs, scans, progress)
    summary = _finish(req, log, loc, saved, outputs, scans, time.perf_counter() - wall0)
    written = " and ".join(str(p) for p in (req.output, req.rrd) if p is not None)
    if scans.after_last_scan is not None:
        scans.after_last_scan.add_note(f"wrote {written}: every scan was processed before the signal")
        raise scans.after_last_scan
    if scans.stopped is not None:
        scans.stopped.add_note(
            f"wrote {written} with the {scans.count} of {scans.total} scans done, marked interrupted"
        )
        raise scans.stopped
    return summary


@dataclass
class _Outputs:
    """The result MCAP and the recording, each None until it is open on its temporary."""

    out: AtomicMcapWriter | None = None
    rrd: _RerunOut | None = None

    def abort(self) -> None:
        """Drop both temporaries (an output already moved into place stays)."""
        try:
            if self.out is not None:
                self.out.abort()
        finally:
            if self.rrd is not None:
                self.rrd.abort()


def _open_outputs(req: LocaliseRequest, saved: SavedMap, log: InputLog, outputs: _Outputs) -> None:
    """Open the result MCAP (its "localise" metadata and the map written) and the recording in `outputs`,
    each set there as soon as its temporary exists, so that whatever stops the run can drop it."""
    with interrupts.deferred():  # a signal while its temporary exists but is not yet in `outputs` waits
        outputs.out = out = AtomicMcapWriter(req.output, profile="gslam-localise")
    if req.rrd is not None:
        outputs.rrd = _RerunOut(req.rrd, saved, log.start_s)
    out.add_metadata(
        "localise",
        {
            "version": __version__,
            "map": str(req.map_path),
            "map_source": saved.source,
            "input": str(req.input_path),
            "input_fingerprint": fingerprint(req.input_path),
            "initial_pose": list(req.initial_pose) if req.initial_pose is not None else None,
            "initial_sigma": list(req.initial_sigma) if req.initial_sigma is not None else None,
            "skip_scans": req.skip_scans,
            "config": dataclasses.asdict(req.config),
        },
    )
    first_t = log.start_s
    cloud = ch.point_cloud(first_t, saved.points, np.ones(len(saved.points)))
    out.write_proto(MAP, cloud, to_ns(first_t))


def _run_scans(
    req: LocaliseRequest,
    log: InputLog,
    loc: MonteCarloLocaliser,
    saved: SavedMap,
    outputs: _Outputs,
    scans: _Scans,
    progress: Callable[[int, int], None] | None,
) -> None:
    """Open the outputs, then every scan through the filter and into them, kept in `scans`. A signal or an
    error ends the loop and is kept there (not raised), so that the outputs are finished (or dropped) with the
    scans done. Each scan's messages are written as one: a signal meanwhile waits for them
    (`interrupts.whole_step`, as `gslam process` writes its steps)."""
    mount = log.mount
    odom_prev = None
    travel = 0.0
    done = False
    try:
        _open_outputs(req, saved, log, outputs)
        out, rrd = outputs.out, outputs.rrd
        for index, t_s, odom_last, ends, stamp_s in scan_stream(log):
            interrupts.check()  # a signal whose exception was swallowed on its way (e.g. in a compiled kernel)
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
            base = base_poses(mount, st.pose)
            particles = None
            if st.updated:
                thin = loc.poses[:: max(1, len(loc.poses) // MAX_PARTICLES_WRITTEN)]
                particles = base_poses(mount, thin)
            scans.writing = True
            with interrupts.whole_step:  # the scan's pose, state, transforms and particles, and its count: all or none
                _write_step(out, t_s, stamp_s, st, base, odom_last, mount, step_ms)
                if particles is not None:
                    out.write_proto_bytes(PARTICLES, ch.PosesInFrame, ch.poses_in_frame_bytes(stamp_s, particles,
                                          ch.MAP_FRAME), to_ns(t_s))  # fmt: skip
                if rrd is not None:
                    rrd.step(scans.count, st, base, particles)
                scans.t_s.append(t_s)
                scans.poses.append(base)
                scans.tracking.append(st.tracking)
                scans.travelled.append(travel)
                scans.filter_s += step_ms / 1e3
                scans.writing = False
            if progress is not None:
                progress(scans.count, scans.total)
        done = True
        interrupts.check()  # a signal swallowed in the last scan
        interrupts.hold()  # from here a signal waits for the outputs (one before it is caught below)
    except (KeyboardInterrupt, Exception) as e:  # SIGINT, SIGTERM (interrupts.Stopped) or an error
        interrupts.hold()
        interrupts.acknowledge()
        e = interrupts.as_stop(e)
        if not isinstance(e, KeyboardInterrupt):
            scans.error = e
        elif scans.writing:  # a second signal that aborts: the scan's messages may be torn
            scans.torn = True
            scans.stopped = e
        elif done or scans.count >= scans.total > 0:
            scans.after_last_scan = e
        else:
            scans.stopped = e


def _finish(
    req: LocaliseRequest,
    log: InputLog,
    loc: MonteCarloLocaliser,
    saved: SavedMap,
    outputs: _Outputs,
    scans: _Scans,
    wall: float,
) -> LocaliseSummary:
    """Finish both outputs with the scans done (a signal meanwhile waits for them; a second one within
    `interrupts.ABORT_WITHIN_S` aborts them), or drop them (`_drop`). An output that cannot be finished is
    dropped, the other kept, and its error raised."""
    if scans.error is not None or scans.torn or scans.count == 0:
        _drop(req, log, outputs, scans)
    errors: list[Exception] = []
    finished = False
    try:
        with interrupts.deferred():
            k = scans.count
            track = np.array(scans.tracking)
            summary = LocaliseSummary(
                scans=k,
                updates=loc.updates,
                tracked_share=float(track.mean()),
                converged_at_m=_converged_at(track, np.array(scans.travelled)),
                wall_s=wall,
                log_duration_s=float(scans.t_s[-1] - scans.t_s[0]),
                ms_per_scan=1e3 * scans.filter_s / k,
                trajectory=np.array(scans.poses),
                t_s=np.array(scans.t_s),
                tracking=track,
                travelled_m=np.array(scans.travelled),
                map_source=saved.source,
            )
            outputs.out.add_metadata(
                "result",
                {
                    "scans": k,
                    "scans_in_input": scans.total,
                    "interrupted": scans.stopped is not None,
                    "error": None if scans.stopped is None else repr(scans.stopped),
                    "updates": loc.updates,
                    "tracked_share": summary.tracked_share,
                    "converged_at_m": summary.converged_at_m,
                    "wall_s": wall,
                    "ms_per_scan": summary.ms_per_scan,
                },
            )
            for w in (outputs.out, outputs.rrd):
                if w is None:
                    continue
                try:
                    w.finish()
                except Exception as e:  # this output is lost, not the other: finish it, then say so
                    w.abort()
                    errors.append(e)
            finished = True
    except KeyboardInterrupt as stop:
        if finished and scans.stopped is None and not errors:  # the signal waited for the finish
            written = " and ".join(str(p) for p in (req.output, req.rrd) if p is not None)
            stop.add_note(f"wrote {written}: every scan was processed before the signal")
        else:  # a second signal: abort
            outputs.abort()
        raise
    except BaseException:
        outputs.abort()
        raise
    if errors:
        raise errors[0]
    return summary


def _drop(req: LocaliseRequest, log: InputLog, outputs: _Outputs, scans: _Scans) -> NoReturn:
    """Drop both outputs and raise why: the error that stopped the scans; a signal before the first scan,
    or one that tore a scan's messages (a second signal, which aborts); no scan in the input."""
    with interrupts.deferred():
        outputs.abort()
    if scans.error is not None:
        raise scans.error
    stop = scans.stopped or scans.after_last_scan
    if stop is not None:
        why = "in the middle of writing a scan" if scans.torn else "before the first scan"
        stop.add_note(f"stopped {why}: nothing written")
        raise stop
    raise InputError(f"{req.input_path}: no scans to localise (the input has {log.scan_count})")


def _converged_at(tracking: np.ndarray, travelled: np.ndarray) -> float | None:
    """The odometry distance at the first scan the filter tracks from; None if it never does."""
    idx = np.flatnonzero(tracking)
    return None if len(idx) == 0 else float(travelled[idx[0]])


def _write_step(
    out, t_s: float, stamp_s: float, st: LocaliseStep, base: np.ndarray, odom: np.ndarray, mount, step_ms: float
) -> None:
    """The scan's pose, state and transforms, at its log time `t_s`; the messages' own stamps are the scan's
    `stamp_s`, as `gslam process` stamps /slam/pose and /tf (so `gslam eval` matches the two by stamp)."""
    ns = to_ns(t_s)
    out.write_proto(POSE, ch.pose_in_frame(stamp_s, *base, ch.MAP_FRAME), ns)
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
    out.write_proto(ch.TF, ch.frame_transforms(stamp_s, links), ns)
