"""`gslam demo`: simulate a Car Park-like log, ingest, process, evaluate against the truth, plot."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gslam.config import FilterConfig
from gslam.vehicle import vehicle_preset
from mcaplog.tempfiles import create_temporary
from mcaplog.tempfiles import replace as replace_temporary
from pipelines.demo.world import SimConfig, SydneyLog, distance_to_obstacles, simulate_sydney_log
from pipelines.evaluation.evaluate import evaluate_result, read_result
from pipelines.evaluation.plot import plot_result
from pipelines.process import process
from pipelines.run.runner import RunConfig


def write_sydney_text(log: SydneyLog, directory: Path) -> Path:
    """The Sydney text-log layout (DRS, GPS, LASER, INTENSITY, BEACONS) plus TRUTH.txt (t, x, y, phi)
    and WALLS.txt (x0, y0, x1, y1), each written atomically."""
    directory.mkdir(parents=True, exist_ok=True)
    files = {
        "DRS.txt": (log.drs, "%.3f,%.7f,%.8f"),
        "GPS.txt": (log.gps, "%.3f,%.6f,%.6f"),
        "LASER.txt": (log.laser, "%.2f"),
        "INTENSITY.txt": (log.intensity, "%d"),
        "BEACONS.txt": (log.beacons, "%.6f"),
        "TRUTH.txt": (log.truth, "%.6f"),
        "WALLS.txt": (log.world.walls, "%.4f"),
    }
    for name, (arr, fmt) in files.items():
        fd, tmp = create_temporary(directory / name)
        if name == "LASER.txt":
            fmt = ["%.3f"] + ["%.2f"] * (arr.shape[1] - 1)
        elif name == "INTENSITY.txt":
            fmt = ["%.3f"] + ["%d"] * (arr.shape[1] - 1)
        try:
            with os.fdopen(fd, "wb") as f:
                np.savetxt(f, arr, fmt=fmt, delimiter=",")
            replace_temporary(tmp, directory / name)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
    return directory


@dataclass
class DemoReport:
    log_dir: Path
    input_mcap: Path
    result_mcap: Path
    rrd: Path
    figure: Path
    metrics: dict
    truth_error_m: float
    dead_reckoning_error_m: float
    map_within_05m: float
    free_space_fraction: float


def run_demo(
    out: Path,
    seed: int,
    particles: int,
    points: int,
    say: Callable[[str], None] = print,
    filter_cfg: FilterConfig | None = None,
    progress: Callable[[int, int, float], None] | None = None,
) -> DemoReport:
    from ingest import ingest

    out = Path(out)
    vehicle = vehicle_preset("carpark")
    t0 = time.perf_counter()
    say(f"[1/5] simulating a Car Park-like log (seed {seed}) ...")
    sim = simulate_sydney_log(SimConfig(seed=seed), vehicle)
    log_dir = write_sydney_text(sim, out / "log")
    say(f"      {len(sim.laser)} scans, {len(sim.drs)} odometry samples, {len(sim.gps)} GPS fixes -> {log_dir}")
    say("[2/5] ingesting ...")
    input_mcap = out / "demo.mcap"
    ingest(log_dir, input_mcap, dataset="demo")
    say(f"[3/5] G-SLAM, N {particles}, M {points} ...")
    base = (filter_cfg or FilterConfig()).as_dict()
    cfg = RunConfig(
        filter=FilterConfig.from_dict(dict(base, particles=particles, points_per_observation=points, seed=seed))
    )
    result = out / "demo_result.mcap"
    rrd = out / "demo_result.rrd"
    summary = process(
        input_mcap,
        result,
        rrd,
        cfg,
        progress,
        command=f"gslam demo --out {out} --seed {seed} --particles {particles} --points {points}",
        notice=lambda text: say(f"      {text}"),
    )
    say(
        f"      {summary.steps} steps, {summary.updates} updates, {summary.ms_per_update_mean:.1f} ms per update "
        f"(mean), map {summary.final_map_points} points"
    )
    say("[4/5] evaluating against the known truth ...")
    metrics = evaluate_result(result, input_mcap)
    res = read_result(result)
    truth = sim.truth
    err = float(np.mean(np.hypot(*(res.trajectory[:, :2] - truth[: len(res.trajectory), 1:3]).T)))
    # Dead reckoning from the filter's own start (recorded in the result) over the same odometry.
    from gslam.initialisation import dead_reckoning

    start = np.asarray(res.metadata["initialisation"]["pose"], dtype=float)
    dr = dead_reckoning(sim.drs, start, float(sim.gps[0, 0]), truth[:, 0], vehicle)
    dr_err = float(np.mean(np.hypot(*(dr[:, :2] - truth[:, 1:3]).T)))
    d = distance_to_obstacles(sim.world, res.map_xy)
    within = float(np.mean(d < 0.5)) if len(d) else float("nan")
    free = float(np.mean(d > 1.5)) if len(d) else float("nan")
    say(
        f"      trajectory vs truth {err:.2f} m (dead reckoning {dr_err:.2f} m); GPS error "
        f"{metrics['gps_mean_error_m']:.2f} m; {within:.0%} of map points within 0.5 m of an obstacle, "
        f"{free:.1%} in free space"
    )
    say("[5/5] plotting ...")
    figure = plot_result(result, out / "demo.png", input_mcap)
    say(f"      wrote {figure}")
    from pipelines.outputs.rerun_viewer import open_command

    say(f"done in {time.perf_counter() - t0:.0f} s. Open the recording with:  {open_command(rrd)}")
    return DemoReport(log_dir, input_mcap, result, rrd, figure, metrics, err, dr_err, within, free)
