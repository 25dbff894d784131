"""Drive the filter core from an input event stream: motion between scans, initialisation, timing."""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from gslam.config import FilterConfig, check_fields
from gslam.filter import GSlamFilter, StepResult
from gslam.initialisation import fit_initial_heading
from gslam.livebackend import LiveBackEnd
from gslam.motion import apply_odometry, integrate_ackermann, odometry_delta, wrap_angle
from gslam.scan import Scan, ScanGeometry
from gslam.se2 import compose
from gslam.vehicle import VEHICLE_PRESETS
from pipelines.errors import InputError
from pipelines.methods import make_filter, method
from pipelines.run.input_log import ControlEvent, GpsEvent, InputLog, OdomEvent, ScanEvent
from pipelines.run.live_graph import CorrectedView
from pipelines.run.mount import BaseFrameView, laser_poses
from pipelines.run.odometry_check import ReversalCheck

MAX_THREADS = max(64, 4 * (os.cpu_count() or 1))
"""The most threads a run may ask for (`RunConfig.threads`): more than the cores only adds work spaces."""


@dataclass
class RunConfig:
    """What `gslam process` runs: the filter options plus the pipeline's own."""

    filter: FilterConfig = field(default_factory=FilterConfig)
    method: str = "gslam"
    """gslam, or a baseline (`pipelines.methods`): fastslam1, fastslam2 (landmarks: poles, from intensity or
    geometry), grid (about 3000 cells) or grid-hr (about 48000 cells) occupancy RBPF."""
    vehicle: str | None = None
    """Vehicle preset for Ackermann logs (default: the one named in the input's metadata)."""
    init_heading_window_s: float = 5.0
    """Seconds of GPS at the start used to fit the initial heading (Sydney logs)."""
    map_snapshot_every: int = 25
    """Write the best particle's map every this many scans (0: final map only)."""
    max_scans: int | None = None
    """Stop after this many scans (None: the whole log)."""
    grid_cells: int | None = None
    """Cells of the grid baselines (default: 3000 for grid, 48000 for grid-hr, as in the paper)."""
    laser_yaw_offset_rad: float = 0.0
    """Mounting yaw of the laser relative to the vehicle axis, added to every bearing (calibration)."""
    threads: int | None = None
    """Worker threads of the filter's compiled particle loops (None: every core; at most `MAX_THREADS`,
    each holds a work space of its own). Results do not depend on it."""
    odometry_reversal_check: bool = True
    """Turn around the odometry increments whose direction contradicts the velocity logged with them (a
    driver that reports backing up as going forward; `pipelines.run.odometry_check`). Odometry without
    velocities, or whose velocities agree, is used as it is."""
    occupancy: bool = False
    """Also write the final trinary occupancy grid on /map/occupancy (pipelines.outputs.navigation_map)."""
    occupancy_resolution_m: float = 0.05
    """Cell size of that grid [m]."""
    live_url: str | None = None
    """Also stream the Rerun recording to the viewer listening at this gRPC address while the run goes
    (`gslam process --live`; e.g. "rerun+http://127.0.0.1:9876/proxy"). None: the .rrd file only."""

    RUN_OPTIONS: ClassVar[tuple[str, ...]] = ()
    """The run options (every field but `filter`): what a TOML file may set besides [filter], and what a
    result records (set below, from the fields, so that a new option cannot be left out)."""
    LIMITS = {
        "init_heading_window_s": (0.0, 3600.0, False),
        "max_scans": (1, math.inf, True),
        "grid_cells": (16, 10_000_000, True),
        "laser_yaw_offset_rad": (-math.pi, math.pi, True),
        "threads": (1, MAX_THREADS, True),
        "occupancy_resolution_m": (0.0, 10.0, False),
    }

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Every run option checked by type and range (as FilterConfig's), method and vehicle by name."""
        if not isinstance(self.filter, FilterConfig):
            raise ValueError(f"filter must be a FilterConfig, got {type(self.filter).__name__}")
        check_fields(self, self.LIMITS, skip=("filter",))
        method(self.method)  # a registered method (pipelines.methods)
        if self.live_url is not None and not (
            str(self.live_url).startswith(("rerun://", "rerun+http://", "rerun+https://"))
            and str(self.live_url).rstrip("/").endswith("/proxy")
        ):
            raise ValueError(
                "live_url must be a Rerun gRPC address such as rerun+http://127.0.0.1:9876/proxy, "
                f"got {self.live_url!r}"
            )
        if self.vehicle is not None and self.vehicle not in VEHICLE_PRESETS:
            raise ValueError(f"vehicle must be one of {', '.join(VEHICLE_PRESETS)}, got {self.vehicle!r}")

    def as_dict(self) -> dict:
        return {"filter": self.filter.as_dict(), **{k: getattr(self, k) for k in self.RUN_OPTIONS}}


RunConfig.RUN_OPTIONS = tuple(f.name for f in dataclasses.fields(RunConfig) if f.name != "filter")


@dataclass
class Step:
    event: ScanEvent
    result: StepResult
    """The filter's step; its poses are the base's where the input records a laser mount."""
    step_ms: float
    laser_pose: np.ndarray
    """The best particle's laser pose (where the scan was taken)."""
    odom_pose: np.ndarray | None = None
    """The base's odometry pose at the scan (odometry logs; None for logs of controls)."""


class SlamRunner:
    """Streams an `InputLog` through a `GSlamFilter`, one scan at a time."""

    def __init__(
        self, log: InputLog, cfg: RunConfig, start: np.ndarray | None = None, start_sigma: tuple[float, float] = (0, 0)
    ) -> None:
        """`start`: the base's pose at the first scan, in the map of the run this one continues (`gslam process
        --continue`); None: the run's own frame (odometry logs: the first scan's odometry pose).
        `start_sigma`: how far that start may be off (sd; m, rad): the particles start spread so."""
        self.log = log
        self.cfg = cfg
        self.start = None if start is None else np.asarray(start, dtype=float)
        self.vehicle = log.vehicle(cfg.vehicle)
        if cfg.vehicle is not None and self.vehicle is None:
            raise InputError(
                f"{log.path}: vehicle {cfg.vehicle!r} given, but this log has {log.motion_model} poses, not an "
                f"Ackermann vehicle's controls; the vehicle preset applies to Sydney logs only (drop --vehicle)"
            )
        self.initialised_from_gps = False
        """Whether the initial pose was fitted to GPS (the map is then in the GPS and survey frame)."""
        if self.start is not None and self.vehicle is not None:
            # the start is the first scan's pose (`--initial-pose`, `find_start`): no scan is left out before it
            self.initial_pose, self.t_init_s = self.start, next(log.events(scans_only=True)).t_s
        else:
            self.initial_pose, self.t_init_s = self._initial_pose()
        self.min_range_m = cfg.filter.min_range_m if cfg.filter.min_range_m is not None else log.self_return_range_m
        self._made_at = np.zeros(3) if self.initial_pose is None else np.asarray(self.initial_pose, dtype=float)
        """The pose the filter's particles start from (spread round it by `initial_sigma_*`)."""
        self.filter = make_filter(cfg, self._made_at, log.self_return_range_m)
        if self.start is not None and any(start_sigma) and isinstance(self.filter, GSlamFilter):
            self.filter.spread_poses(*start_sigma)
        self.mount = log.mount
        fcfg = cfg.filter
        self.live: LiveBackEnd | None = None
        """The back end while the run goes (`loop_closure_live`): it moves the outputs onto its graph."""
        if isinstance(self.filter, GSlamFilter) and fcfg.loop_closure and fcfg.loop_closure_live:
            self.live = LiveBackEnd()
        view = self.filter if self.live is None else CorrectedView(self.filter, self.live)
        self.output_filter = view if self.mount is None else BaseFrameView(view, self.mount)
        """What the outputs read: the filter, moved onto the live graph where it corrects the front end, and
        seen from the base when the laser is mounted off it."""
        self.gps: list[tuple[float, float, float]] = []
        self._turned: ScanGeometry | None = None  # the log's geometry turned by the mounting yaw

    def _place_particles(self, pose: np.ndarray) -> None:
        """At an odometry log's first scan: the particles moved to `pose` (its odometry, or the start found in
        a continued map), each keeping its spread around the pose the filter was made at (`initial_sigma_*`)."""
        poses = self.filter.poses
        spread = poses - self._made_at
        spread[:, 2] = wrap_angle(spread[:, 2])
        poses[:] = pose
        if spread.any():  # else the pose as given, bit for bit
            poses += spread
            poses[:, 2] = wrap_angle(poses[:, 2])

    def _initial_pose(self) -> tuple[np.ndarray | None, float | None]:
        if self.vehicle is None:
            return None, None  # odometry logs start at the first scan's odometry pose
        controls, gps = self.log.head_controls_and_gps(self.cfg.init_heading_window_s + 1.0)
        if len(controls) == 0:
            raise InputError(f"{self.log.path}: no odometry in the first seconds; cannot start the filter")
        if len(gps) >= 3:
            self.initialised_from_gps = True
            return fit_initial_heading(controls, gps, self.vehicle, self.cfg.init_heading_window_s), float(gps[0, 0])
        return np.zeros(3), float(controls[0, 0])

    def _onto_live_graph(self, scan: Scan, result: StepResult) -> StepResult:
        """Offer the step to the live back end (it takes a node every half metre) and move its poses onto
        the graph's latest correction, if the graph has one for the front end (`gslam.livebackend`)."""
        flt, live = self.filter, self.live
        step, best = flt.steps - 1, result.best  # the step's level in the tree; its best node there

        def history(levels: np.ndarray) -> np.ndarray:
            return flt.tree.node_trajectory(best, levels)[1]

        live.offer(step, result.best_pose, lambda: flt.node_points(scan), history)
        corr = live.correction
        if corr is None:
            return result
        live.note_applied(step)
        move = corr.latest(history)
        return dataclasses.replace(result, poses=compose(move, result.poses), best_pose=compose(move, result.best_pose))

    def stop_live(self) -> dict | None:
        """Stop the live back end (its record for the result; None without one). The outputs read the
        filter as it is from here (the run's end corrects it once more, `GSlamFilter.close_loops`)."""
        if self.live is None:
            return None
        record = self.live.stop()
        self.live.correction = None
        return record

    def scan_of(self, ev: ScanEvent) -> Scan:
        """The filter's scan of an input scan: its geometry (the log's, or its own) with the laser's mounting
        yaw added to every bearing, and the self-return range."""
        g = ev.geometry if ev.geometry is not None else self.log.geometry
        yaw = self.cfg.laser_yaw_offset_rad
        if yaw:
            if g is not self.log.geometry:
                g = dataclasses.replace(g, start_angle_rad=g.start_angle_rad + yaw)
            else:  # the log's own geometry: turned once
                if self._turned is None:
                    self._turned = dataclasses.replace(g, start_angle_rad=g.start_angle_rad + yaw)
                g = self._turned
        return Scan(ev.stamp_s, ev.ranges_m, g, self.min_range_m)

    def scans_at(self, indices: list[int]) -> Iterator[Scan]:
        """The filter's scans of the input's scans number `indices` (increasing), read again from the input
        (the run's scans, for the placement of every scan once it is over)."""
        for ev in self.log.scans_at(indices):
            yield self.scan_of(ev)

    def steps(self) -> Iterator[Step]:
        fcfg = self.cfg.filter
        controls: list[list[float]] = []
        last_control: list[float] | None = None
        t_prev = self.t_init_s
        odom_prev: np.ndarray | None = None
        odom_last: np.ndarray | None = None

        reversal = self.reversal_check = ReversalCheck() if self.cfg.odometry_reversal_check else None
        for ev in self.log.events():
            if isinstance(ev, ControlEvent):
                controls.append([ev.t_s, ev.speed_mps, ev.steering_rad])
            elif isinstance(ev, OdomEvent):
                odom_last = ev.pose if reversal is None else reversal.update(ev.pose, ev.tv_mps)
            elif isinstance(ev, GpsEvent):
                self.gps.append((ev.t_s, float(ev.xy[0]), float(ev.xy[1])))
            elif isinstance(ev, ScanEvent):
                predict = None
                if self.vehicle is not None:
                    if t_prev is None or ev.t_s < t_prev:
                        # before initialisation time: keep only the latest control
                        last_control = controls[-1] if controls else last_control
                        controls = []
                        continue
                    rows = ([last_control] if last_control is not None else []) + controls
                    u = np.asarray(rows, dtype=float).reshape(-1, 3)
                    t0, t1 = t_prev, ev.t_s
                    vehicle = self.vehicle

                    def predict(poses, rng, u=u, t0=t0, t1=t1, vehicle=vehicle):
                        return integrate_ackermann(
                            poses,
                            u,
                            t1,
                            t0,
                            vehicle,
                            rng,
                            fcfg.speed_sigma_mps,
                            fcfg.speed_sigma_rel,
                            fcfg.steering_sigma_rad,
                            per_sample=fcfg.control_noise == "per_sample",
                        )

                    if controls:
                        last_control = controls[-1]
                    controls = []
                    t_prev = ev.t_s
                else:
                    if odom_last is None:
                        raise InputError(f"{self.log.path}: scan {ev.index} has no odometry before it")
                    mount = self.mount
                    if odom_prev is None:
                        first = odom_last if self.start is None else self.start
                        self._place_particles(laser_poses(mount, first))
                    else:
                        delta = odometry_delta(odom_prev, odom_last)
                        if mount is None:

                            def predict(poses, rng, delta=delta):
                                return apply_odometry(poses, delta, rng, fcfg.odom_sigma)

                        else:
                            # The odometry (and its noise) moves the base; the particles are laser poses.
                            def predict(poses, rng, delta=delta, mount=mount):
                                base = apply_odometry(mount.base_of(poses), delta, rng, fcfg.odom_sigma)
                                return mount.laser_of(base)

                    odom_prev = odom_last
                scan = self.scan_of(ev)
                t0 = time.perf_counter()
                result = self.filter.step(scan, predict, ev.intensities)
                step_ms = (time.perf_counter() - t0) * 1e3
                if self.live is not None:
                    result = self._onto_live_graph(scan, result)
                laser_pose = result.best_pose
                if self.mount is not None:
                    result = dataclasses.replace(
                        result, poses=self.mount.base_of(result.poses), best_pose=self.mount.base_of(result.best_pose)
                    )
                odom = None if self.vehicle is not None or odom_last is None else np.asarray(odom_last, dtype=float)
                yield Step(ev, result, step_ms, laser_pose, odom)
                if self.cfg.max_scans is not None and ev.index + 1 >= self.cfg.max_scans:
                    break
