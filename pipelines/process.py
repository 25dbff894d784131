"""`gslam process`: stream an input MCAP through the filter, write the result MCAP and Rerun recording."""

from __future__ import annotations

import dataclasses
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gslam import __version__
from gslam.backend import PoseGraphBackEnd
from gslam.scan import transform_points
from pipelines.errors import InputError
from pipelines.outputs.mcap_result import McapResultWriter
from pipelines.outputs.rerun_result import RerunResultWriter
from pipelines.outputs.writer import OccupancyMap, ResultWriter, RunEnd, RunStart
from pipelines.outputs.writer_child import WriterChild, usage
from pipelines.run import interrupts
from pipelines.run.compile_time import COMPILING_NOTE, watching_compiles
from pipelines.run.continuation import PreviousRun, SavedMap, Start, find_start, load_previous, node_returns
from pipelines.run.input_log import InputLog
from pipelines.run.mount import base_poses, laser_poses
from pipelines.run.recorded_input import fingerprint
from pipelines.run.runner import RunConfig, SlamRunner
from pipelines.run.startup import skip_blas_probe


@dataclass
class ProcessSummary:
    steps: int
    scans_in_log: int
    final_map_points: int
    ms_per_step_median: float
    ms_per_step_filter_median: float
    ms_per_step_filter_mean: float
    updates: int
    ms_per_update_mean: float
    """Filter time per updating step (mean): with the travel schedule most steps only predict, so the
    median step is a prediction; this is the cost of the steps that weigh, match and update the maps."""
    ms_per_step_mean: float
    """End-to-end time per step (mean), MCAP and Rerun writing included."""
    wall_s: float
    log_duration_s: float
    interrupted: bool
    output: Path
    rrd: Path | None

    @property
    def real_time_factor(self) -> float:
        return self.log_duration_s / self.wall_s if self.wall_s > 0 else float("nan")

    def describe(self) -> str:
        """One line for the user: steps, updates, map size, time per update and per step, real-time factor."""
        return (
            f"{self.steps} steps of {self.scans_in_log} scans, {self.updates} updates; final map "
            f"{self.final_map_points} points; {self.ms_per_update_mean:.1f} ms per update (filter, mean), "
            f"{self.ms_per_step_mean:.1f} ms per step end to end (mean); "
            f"real-time factor {self.real_time_factor:.1f}"
        )


def peak_rss_mb() -> float:
    """This process's peak resident memory so far (MB), its own (`writer_child.usage`)."""
    return usage()["peak_rss_mb"]


def _occupancy(
    runner: SlamRunner, log: InputLog, scan_indices: list[int], cfg: RunConfig, backend: PoseGraphBackEnd | None
) -> OccupancyMap:
    """The final trinary occupancy grid (scans cast from the final laser poses), for /map/occupancy; in a
    continued run, the earlier runs' graph nodes' returns too (`build_grid`'s `earlier`)."""
    from pipelines.outputs.navigation_map import build_grid, occupancy_probabilities

    flt = runner.filter  # laser poses: where the scans were taken
    times, laser = flt.best_trajectory()
    xy, p = flt.map_points(flt.best_particle())
    p = occupancy_probabilities(p, getattr(cfg.filter, "map_update", "binary"))
    earlier = [] if backend is None else [(backend.estimate[k], backend.points[k]) for k in range(backend.run_start)]
    grid = build_grid(
        log, np.asarray(scan_indices), laser, xy, p, cfg.occupancy_resolution_m, cfg.laser_yaw_offset_rad,
        earlier=earlier,
    )  # fmt: skip
    t_last = float(times[-1]) if len(times) else 0.0
    return OccupancyMap(t_last, grid.state, grid.spec.origin_xy_m, grid.spec.resolution_m)


def _abort(writers: list[ResultWriter]) -> None:
    """The one way a run that cannot be completed ends: every writer drops its file (each one, even when
    another fails to; the first failure is raised after)."""
    failure: BaseException | None = None
    for w in writers:
        try:
            w.abort()
        except BaseException as e:
            failure = failure or e
    if failure is not None:
        raise failure


@dataclass(frozen=True)
class Continuation:
    """`gslam process --continue PREVIOUS`: the result to go on from, and where the new run starts in its map
    (the base's pose; None: found by searching the map, `pipelines.run.continuation.find_start`)."""

    previous: Path
    initial_pose: tuple[float, float, float] | None = None
    if_lost: str = "stop"
    """When the run cannot find itself in the map: "stop" (an error, nothing written), or "new": map it as a
    new trajectory in its own frame, the earlier map and trajectories kept in the result apart from it."""


@dataclass
class _OpenRun:
    """A run whose outputs are open: the input, the runner over it and the writers it feeds."""

    log: InputLog
    runner: SlamRunner
    writers: list[ResultWriter]
    cfg: RunConfig
    output_path: Path
    rrd_path: Path | None
    previous: PreviousRun | None = None
    """The run this one continues (`--continue`)."""
    connected: bool = True
    """Whether this run found itself in the previous run's map and mapped on in it (else a new trajectory)."""

    @property
    def written(self) -> str:
        """The outputs, for the notes that say what was kept."""
        return " and ".join(str(p) for p in (self.output_path, self.rrd_path) if p is not None)


@dataclass
class _StepTimes:
    """What the steps took, and how the loop over them ended."""

    step_ms: list[float] = dataclasses.field(default_factory=list)
    """End to end, writers included, compile time left out."""
    filter_ms: list[float] = dataclasses.field(default_factory=list)
    update_ms: list[float] = dataclasses.field(default_factory=list)
    scan_indices: list[int] = dataclasses.field(default_factory=list)
    first_t: float | None = None
    last_t: float | None = None
    wall_s: float = 0.0
    compile_s: float = 0.0
    interrupted: bool = False
    error: BaseException | None = None
    """Why the steps stopped before the end (a signal or an error), re-raised once the outputs are finished."""
    after_last_scan: KeyboardInterrupt | None = None
    """A signal that came once every scan was processed: the run is whole; raised after the finish."""


def process(
    input_path: Path,
    output_path: Path,
    rrd_path: Path | None,
    cfg: RunConfig,
    progress: Callable[[int, int, float], None] | None = None,
    command: str | None = None,
    rrd_writer: WriterChild | None = None,
    notice: Callable[[str], None] | None = None,
    continuation: Continuation | None = None,
) -> ProcessSummary:
    """Run the filter over `input_path` into the result MCAP `output_path` and the Rerun recording
    `rrd_path` (None: none). Ctrl-C or an error mid-run still finishes the outputs with the steps done so
    far (the error is re-raised after). `rrd_writer`: the recording's child writer, started beforehand by
    `writer_child.start_rerun_writer` (aborted here if the run cannot start). `notice(text)` tells the
    user why the run waits (the kernels' first compile, the occupancy grid); compile time is left out of
    the recorded step times and recorded as `compile_s`. `continuation`: go on from an earlier result's map
    and graph (`pipelines.run.continuation`)."""
    run = _open(input_path, output_path, rrd_path, cfg, command, rrd_writer, continuation, notice)
    try:
        times = _run_steps(run, progress, notice)
    except BaseException:  # a signal before its loop could catch it: the outputs are dropped, not orphaned
        _abort(run.writers)
        run.runner.stop_live()
        raise
    summary = _finish(run, times, notice)
    if times.after_last_scan is not None:
        times.after_last_scan.add_note(f"wrote {run.written}: every scan was processed before the signal")
        raise times.after_last_scan
    if times.error is not None:
        times.error.add_note(f"wrote {run.written} with the {summary.steps} steps done, marked interrupted")
        raise times.error
    return summary


def _open(
    input_path: Path,
    output_path: Path,
    rrd_path: Path | None,
    cfg: RunConfig,
    command: str | None,
    rrd_writer: WriterChild | None,
    continuation: Continuation | None = None,
    notice: Callable[[str], None] | None = None,
) -> _OpenRun:
    """Open the input (and the result it continues, finding the run in its map), build the runner and start
    every writer with the run's metadata; on any failure every writer drops its file."""
    # The result MCAP first: the writers finish in reverse order, so that its record holds the figures
    # the others add to it.
    writers: list[ResultWriter] = [McapResultWriter(output_path, cfg.map_snapshot_every)]
    if rrd_path is not None:
        writers.append(RerunResultWriter(rrd_path, cfg.map_snapshot_every, writer=rrd_writer, live_url=cfg.live_url))
    elif rrd_writer is not None:
        rrd_writer.abort()  # started for a recording this run does not write
    runner: SlamRunner | None = None
    try:
        log = InputLog(input_path)
        skip_blas_probe()
        previous, start = (None, None) if continuation is None else _continue(continuation, log, cfg, notice)
        connected = start is None or start.pose is not None
        runner = SlamRunner(
            log, cfg, None if start is None else start.pose,
            (0, 0) if start is None else (start.sigma_xy_m, start.sigma_phi_rad),
        )  # fmt: skip
        if previous is not None and connected:
            runner.filter.seed_map(previous.map_xy, previous.map_p)
        metadata = _run_metadata(input_path, log, runner, cfg, command)
        if previous is not None:
            metadata["continuation"] = {
                "previous": str(previous.path.resolve()),
                "earlier_runs": len(previous.sessions),
                "maps": len(previous.maps),
                "graph_nodes": 0 if previous.maps[0].graph is None else len(previous.maps[0].graph.poses),
                "start": start.record(),
                "connected": connected,
            }
        for w in writers:
            w.start(RunStart(log, metadata))
        rrd = Path(rrd_path) if rrd_path else None
        return _OpenRun(log, runner, writers, cfg, Path(output_path), rrd, previous, connected)
    except BaseException:
        _abort(writers)
        if runner is not None:
            runner.stop_live()  # its worker thread ends with the run that could not start
        raise


def _continue(
    continuation: Continuation, log: InputLog, cfg: RunConfig, notice: Callable[[str], None] | None
) -> tuple[PreviousRun, Start]:
    """The result to go on from and where the new run starts in its map; InputError when it cannot be found."""
    if cfg.method != "gslam":
        raise InputError(f"--continue maps on with G-SLAM's point map; --method {cfg.method} cannot continue one")
    previous = load_previous(continuation.previous)
    maps = len(previous.maps)
    others = f" and its {maps - 1} earlier map{'s' if maps > 2 else ''}" if maps > 1 else ""
    if continuation.initial_pose is None and notice is not None:
        notice(
            f"finding the run in {continuation.previous}'s map{others} (its first scans searched for over the "
            "whole map)"
        )
    pose = None if continuation.initial_pose is None else np.asarray(continuation.initial_pose, dtype=float)
    workers = max(1, cfg.threads or os.cpu_count() or 1)
    start = find_start(previous, log, pose, workers, log.vehicle(cfg.vehicle), cfg.laser_yaw_offset_rad)
    if start.pose is not None and start.map:
        if notice is not None:
            notice(f"found the run in earlier map {start.map} of {continuation.previous}: mapping on in that map")
        previous = previous.with_map_first(start.map)  # the map it continues becomes the result's own
    if start.pose is None:
        lost = (
            f"{log.path}: could not find itself in the map of {continuation.previous}{others} over its first "
            f"{start.travel_m:.1f} m of travel ({start.scans_searched} scans searched)"
        )
        if continuation.if_lost != "new":
            raise InputError(
                f"{lost}; give --initial-pose X Y YAW (where its first scan stands in that map), or --if-lost new "
                "to map it as a new trajectory beside the earlier map"
            )
        if notice is not None:
            notice(f"{lost}: mapping it as a new trajectory in its own frame; the earlier map is kept beside it")
    return previous, start


def _run_metadata(input_path: Path, log: InputLog, runner: SlamRunner, cfg: RunConfig, command: str | None) -> dict:
    """What a result records of its run: the software, the command, the configuration, the input, the start."""
    return {
        "gslam": {"version": __version__, "command": command or " ".join(sys.argv), "method": cfg.method},
        "config": cfg.as_dict(),
        "input": {
            "path": str(Path(input_path).resolve()),
            "fingerprint": fingerprint(Path(input_path)),
            "dataset": log.meta.get("dataset", {}).get("name", ""),
            "sensor": log.meta.get("sensor", {}),
            "vehicle": log.meta.get("vehicle", {}),
        },
        "initialisation": {
            "pose": None if runner.initial_pose is None else runner.initial_pose.tolist(),
            "t_s": runner.t_init_s,
            "heading_window_s": cfg.init_heading_window_s,
            "from_gps": runner.initialised_from_gps,
        },
    }


def _run_steps(
    run: _OpenRun, progress: Callable[[int, int, float], None] | None, notice: Callable[[str], None] | None
) -> _StepTimes:
    """Every scan through the filter and to the writers. A signal or an error ends the loop and is kept in
    the times (not raised), so that the outputs are finished with the steps done."""
    cfg, log = run.cfg, run.log
    total = log.scan_count if cfg.max_scans is None else min(cfg.max_scans, log.scan_count)
    times = _StepTimes()
    t_start = time.perf_counter()
    t_prev = t_start

    def compiling() -> None:
        if notice is not None:
            notice(COMPILING_NOTE)

    compile_watch = None
    try:
        with watching_compiles(compiling) as compile_watch:
            compiled_ms = 0.0  # numba compile time so far, taken out of the step it fell in
            for st in run.runner.steps():
                interrupts.check()  # a signal whose exception was swallowed on its way (interrupts.check)
                spent_ms = compile_watch.total_s * 1e3 - compiled_ms
                if spent_ms > 0:
                    compiled_ms += spent_ms
                    st = dataclasses.replace(st, step_ms=max(0.0, st.step_ms - spent_ms))
                with interrupts.whole_step:  # a signal waits: the step is written and counted whole
                    for w in run.writers:
                        w.step(st, run.runner.output_filter)
                    now = time.perf_counter()
                    times.step_ms.append(max(0.0, (now - t_prev) * 1e3 - max(spent_ms, 0.0)))
                    t_prev = now
                    times.filter_ms.append(st.step_ms)
                    times.scan_indices.append(st.event.index)
                    if st.result.updated:
                        times.update_ms.append(st.step_ms)
                    times.first_t = st.event.t_s if times.first_t is None else times.first_t
                    times.last_t = st.event.t_s
                if progress is not None:
                    progress(st.event.index + 1, total, st.step_ms)
            interrupts.hold()  # from here a signal waits for the outputs (a signal before it is caught below)
    except (KeyboardInterrupt, Exception) as e:  # SIGINT, SIGTERM (interrupts.Stopped) or an error
        interrupts.hold()
        interrupts.acknowledge()
        e = interrupts.as_stop(e)
        if isinstance(e, KeyboardInterrupt) and len(times.filter_ms) >= total:
            times.after_last_scan = e  # every scan was processed: the run is whole, finish it, then stop
        else:
            times.interrupted = True
            times.error = e
    times.wall_s = time.perf_counter() - t_start
    times.compile_s = 0.0 if compile_watch is None else round(compile_watch.total_s, 3)
    return times


def _summary(run: _OpenRun, times: _StepTimes) -> ProcessSummary:
    flt = run.runner.output_filter

    def median(values: list[float]) -> float:
        return float(np.median(values)) if values else float("nan")

    def mean(values: list[float]) -> float:
        return float(np.mean(values)) if values else float("nan")

    return ProcessSummary(
        steps=len(times.filter_ms),
        scans_in_log=run.log.scan_count,
        final_map_points=len(flt.map_points(flt.best_particle())[1]),
        ms_per_step_median=median(times.step_ms),
        ms_per_step_filter_median=median(times.filter_ms),
        ms_per_step_filter_mean=mean(times.filter_ms),
        updates=len(times.update_ms),
        ms_per_update_mean=mean(times.update_ms),
        ms_per_step_mean=mean(times.step_ms),
        wall_s=times.wall_s,
        log_duration_s=(times.last_t - times.first_t) if times.first_t is not None else 0.0,
        interrupted=times.interrupted,
        output=run.output_path,
        rrd=run.rrd_path,
    )


def _result_metadata(run: _OpenRun, times: _StepTimes, summary: ProcessSummary) -> dict:
    """What a result records of how its run went (the `result` metadata record)."""
    cfg = run.cfg
    return {
        "steps": summary.steps,
        "scans_in_log": run.log.scan_count,
        "max_scans": cfg.max_scans,
        "interrupted": times.interrupted,
        "error": None if times.error is None else repr(times.error),
        "ms_per_step_median": summary.ms_per_step_median,
        "ms_per_step_filter_median": summary.ms_per_step_filter_median,
        "ms_per_step_filter_mean": summary.ms_per_step_filter_mean,
        "updates": summary.updates,
        "rechecked_updates": getattr(run.runner.filter, "rechecked_updates", None),
        "ms_per_update_mean": summary.ms_per_update_mean,
        "ms_per_step_mean": summary.ms_per_step_mean,
        "wall_s": times.wall_s,
        "log_duration_s": summary.log_duration_s,
        "real_time_factor": summary.real_time_factor,
        "final_map_points": summary.final_map_points,
        "peak_rss_mb": peak_rss_mb(),
        "compile_s": times.compile_s,
        "particles": cfg.filter.particles,
        "points_per_observation": cfg.filter.points_per_observation,
    }


def placement_workers(threads: int | None) -> int:
    """Threads for the placement of every scan: the run's (every core by default); one where numba's
    threading layer cannot take two compiled calls at once (its "workqueue" layer aborts the process)."""
    import numba

    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel function has run yet
        return 1
    return max(1, threads or os.cpu_count() or 1) if layer in ("omp", "tbb") else 1


def _place_every_scan(run: _OpenRun, times: _StepTimes, notice: Callable[[str], None] | None) -> dict | None:
    """Every scan of the final trajectory matched against the final map (`GSlamFilter.place_every_scan`,
    `place_every_scan` on): how many were matched, placed between matched neighbours, or had no returns,
    and the seconds it took. None when off, for other methods, and for a run cut short (its trajectory is
    kept as recorded)."""
    flt = run.runner.filter
    if times.interrupted or not times.scan_indices or not run.cfg.filter.place_every_scan:
        return None
    if not hasattr(flt, "place_every_scan"):
        return None
    if notice is not None:
        notice(f"placing every scan in the final map ({len(times.scan_indices)} scans)")
    t0 = time.perf_counter()
    indices = times.scan_indices
    workers = placement_workers(run.cfg.threads)
    counts = flt.place_every_scan(lambda a, b: run.runner.scans_at(indices[a:b]), workers).counts()
    counts["workers"] = workers
    counts["seconds"] = round(time.perf_counter() - t0, 3)
    return counts


def _close_loops(
    run: _OpenRun, times: _StepTimes, notice: Callable[[str], None] | None
) -> tuple[dict | None, dict | None, PoseGraphBackEnd | None]:
    """The pose graph under the final trajectory (`GSlamFilter.close_loops`, `loop_closure` on), with the
    graph of the run it continues: (its record for the result, the graph for the outputs in their frame, the
    back end); (None, None, None) when off, for other methods, and for a run cut short."""
    flt = run.runner.filter
    if times.interrupted or not times.scan_indices or not getattr(run.cfg.filter, "loop_closure", False):
        return None, None, None
    if not hasattr(flt, "close_loops"):
        return None, None, None
    if notice is not None:
        notice("closing loops: a pose graph under the trajectory, each node's scan searched in earlier submaps")
    t0 = time.perf_counter()
    indices = times.scan_indices
    mount = run.runner.mount
    previous = None if run.previous is None or not run.connected else run.previous.graph(mount)
    first = 0 if run.previous is None else len(run.previous.sessions)  # this run's number, after the earlier ones
    backend = flt.close_loops(lambda steps: run.runner.scans_at([indices[k] for k in steps]), None, previous, first)
    record = backend.summary()
    record["seconds"] = round(time.perf_counter() - t0, 3)
    graph = backend.graph()
    if mount is not None and graph["x_m"]:  # the outputs are the base's poses
        base = mount.base_of(np.column_stack([graph["x_m"], graph["y_m"], graph["yaw_rad"]]))
        graph["x_m"], graph["y_m"], graph["yaw_rad"] = base[:, 0].tolist(), base[:, 1].tolist(), base[:, 2].tolist()
    return record, graph, backend


def _graph_scans(backend: PoseGraphBackEnd) -> tuple[np.ndarray, np.ndarray]:
    """Each node's returns in the map frame, at its final pose, and the node each belongs to."""
    return node_returns([transform_points(backend.estimate[k], pts) for k, pts in enumerate(backend.points)])


def _sessions(run: _OpenRun, backend: PoseGraphBackEnd | None) -> tuple[list[dict] | None, list[SavedMap] | None]:
    """The earlier runs' final trajectories for the result (`/slam/sessions`), moved with the graph where it
    corrects them, and the maps apart from this run's, each with its graph (`/slam/earlier_maps`,
    `/slam/earlier_graphs`): the previous result's earlier ones, and its own map too when this run could not
    find itself in any."""
    prev = run.previous
    if prev is None:
        return None, None
    mount = run.runner.mount
    shift = 0 if run.connected else 1  # the previous map becomes the first of the earlier ones
    out = []
    for s in prev.sessions:
        poses = s.poses
        if run.connected and s.connected and backend is not None and backend.applied and len(poses):
            moved = backend.correct_trajectory(laser_poses(mount, poses), session=s.index)
            poses = base_poses(mount, moved)
        at = s.map + shift
        out.append({
            "session": s.index, "input": s.input, "map": at, "connected": at == 0, "t_s": s.t_s.tolist(),
            "x_m": poses[:, 0].tolist(), "y_m": poses[:, 1].tolist(), "yaw_rad": poses[:, 2].tolist(),
        })  # fmt: skip
    earlier = prev.earlier_maps if run.connected else prev.maps  # lost: the previous result's own map too
    return out, earlier


def _finish(run: _OpenRun, times: _StepTimes, notice: Callable[[str], None] | None) -> ProcessSummary:
    """Finish every output with the steps done (the result MCAP last, so that it records the others'
    figures); a signal meanwhile waits for it. An output that cannot be finished is dropped, the others
    kept, and its error raised."""
    errors: list[Exception] = []
    finished = False
    try:
        # A signal from here on waits for the outputs to be finished (a second one aborts them).
        with interrupts.deferred():
            live = run.runner.stop_live()  # the live back end's record (`loop_closure_live`), or None
            if run.previous is not None and run.connected:  # the map it was seeded with: saved at its own p
                run.runner.filter.restore_saved_p()
            placement = _place_every_scan(run, times, notice)
            closure, graph, backend = _close_loops(run, times, notice)
            if closure is not None:
                closure["live"] = live
            summary = _summary(run, times)
            result_meta = _result_metadata(run, times, summary)
            result_meta["placement"] = placement
            result_meta["loop_closure"] = closure
            occupancy = None
            if run.cfg.occupancy and not times.interrupted and times.scan_indices:
                if notice is not None:
                    notice("building the occupancy grid (every scan ray-cast at the final poses)")
                occupancy = _occupancy(run.runner, run.log, times.scan_indices, run.cfg, backend)
            scans = None if backend is None else _graph_scans(backend)
            sessions, earlier = _sessions(run, backend)
            end = RunEnd(run.runner.output_filter, result_meta, occupancy, graph, scans, sessions)
            if earlier is not None:
                end.earlier_maps = [(m.xy, m.p) for m in earlier]
                end.earlier_graphs = [
                    None if m.graph is None else (m.graph.record(k), m.graph.returns())
                    for k, m in enumerate(earlier, start=1)
                ]
            for w in reversed(run.writers):
                try:
                    w.finish(end)
                except Exception as e:  # this output is lost, not the others: finish them, then say so
                    w.abort()
                    errors.append(e)
            finished = True
    except KeyboardInterrupt as stop:
        if finished and times.error is None and not errors:  # the signal waited for the finish
            stop.add_note(f"wrote {run.written}: every scan was processed before the signal")
        else:
            _abort(run.writers)
        raise
    except BaseException:
        _abort(run.writers)
        raise
    if errors:
        raise errors[0]
    return summary
