"""`gslam export`: the final best trajectory in TUM format, the final map as CSV, and the occupancy grid
as a map_server map (PGM + YAML); for a localisation result, its trajectory (the estimate at every scan)
in TUM format.

The slow parts (reading a long result, casting the input's scans into a new occupancy grid) report their
progress through `phase` (the command line shows it as the other commands do)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mcaplog.tempfiles import write_atomic
from pipelines.errors import InputError
from pipelines.evaluation.evaluate import ResultData, read_result
from pipelines.evaluation.localisation import is_localisation, read_localisation, result_metadata

if TYPE_CHECKING:
    from pipelines.outputs.occupancy_grid import OccupancyGrid

TRAJECTORY_HEADER = "gslam final best path: the base's if the laser is mounted off it"
LOCALISATION_HEADER = "gslam localise: the base's estimate at every scan, tracking or lost (see /localise/state)"

Report = Callable[[int, int], None]
"""`report(done, total)`."""
Phase = Callable[[str, str], AbstractContextManager[Report]]
"""`phase(what, unit)`: a context giving the `report` of one slow part of the export (`what` it does,
counted in `unit`)."""


@contextmanager
def quiet(what: str, unit: str) -> Iterator[Report]:
    """The `Phase` that reports nothing."""
    yield lambda done, total: None


def tum_text(stamp_s: np.ndarray, poses: np.ndarray, what: str = TRAJECTORY_HEADER) -> str:
    """TUM trajectory lines `t x y z qx qy qz qw` (evo's `evo_traj tum`, `evo_ape tum` read them), under a
    comment saying `what` they are."""
    half = poses[:, 2] / 2
    rows = np.column_stack(
        [
            stamp_s,
            poses[:, 0],
            poses[:, 1],
            np.zeros(len(poses)),
            np.zeros(len(poses)),
            np.zeros(len(poses)),
            np.sin(half),
            np.cos(half),
        ]
    )
    lines = [f"# timestamp tx ty tz qx qy qz qw ({what})"]
    lines += [" ".join(f"{v:.9f}" if i == 0 else f"{v:.6f}" for i, v in enumerate(r)) for r in rows]
    return "\n".join(lines) + "\n"


def tum_stamps(stamp_s: np.ndarray) -> np.ndarray:
    """Strictly increasing stamps for TUM readers (logs whose stamps go backwards keep file order)."""
    stamps = np.asarray(stamp_s, dtype=float).copy()
    for i in range(1, len(stamps)):  # over steps, once
        if stamps[i] <= stamps[i - 1]:
            stamps[i] = stamps[i - 1] + 1e-6
    return stamps


def reference_tum(res, result: Path, input_path: Path | None = None) -> str:
    """The input's reference trajectory as TUM lines at the result's scan stamps (the stamps of `--tum`),
    so that evo pairs every pose with its reference: the simulator's true pose where the input has one,
    else GPS (position only: the orientation is written as identity). Interpolated linearly at each
    step's log time; steps outside the reference's span are left out."""
    from mcaplog import channels as ch
    from mcaplog.mcapio import McapInput
    from pipelines.evaluation.evaluate import reference_truth
    from pipelines.evaluation.localisation import checked_input
    from pipelines.evaluation.metrics import interpolate_positions
    from pipelines.run.recorded_input import recorded_input

    if input_path is not None:
        path = Path(input_path)
    elif is_localisation(res.metadata):
        path = checked_input(result, res.metadata, "--input")
    else:
        path = recorded_input(result, res.metadata, "--input")
    truth = []
    for m in McapInput(path).messages([ch.TRAJECTORY_TRUTH]):
        p = m.value.pose
        truth.append([m.t_s, p.position.x, p.position.y, 2 * np.arctan2(p.orientation.z, p.orientation.w)])
    topic = ch.TRAJECTORY_TRUTH
    ref = np.asarray(truth, dtype=float).reshape(-1, 4)
    if len(ref) < 2:  # GPS, read as `gslam eval` reads it
        gps, _, _ = reference_truth(McapInput(path))
        topic, ref = ch.GPS, np.zeros((0, 4)) if gps is None else np.column_stack([gps, np.zeros(len(gps))])
    if len(ref) < 2:
        raise InputError(
            f"{path}: no GPS or true trajectory to export (this log's reference, if any, is relations: "
            "`gslam eval` scores them)"
        )
    inside, xy = interpolate_positions(ref[:, 0], ref[:, 1:3], res.t_s)
    poses = np.zeros((int(inside.sum()), 3))
    poses[:, :2] = xy
    if topic == ch.TRAJECTORY_TRUTH:
        poses[:, 2] = np.interp(res.t_s[inside], ref[:, 0], np.unwrap(ref[:, 3]))
    what = "true pose" if topic == ch.TRAJECTORY_TRUTH else "GPS (position only; orientation identity)"
    return tum_text(tum_stamps(res.stamp_s)[inside], poses, f"reference: {what}, at the scan stamps")


def map_csv_text(xy: np.ndarray, p: np.ndarray) -> str:
    lines = ["x_m,y_m,probability"] + [f"{x:.4f},{y:.4f},{q:.6g}" for (x, y), q in zip(xy, p, strict=True)]
    return "\n".join(lines) + "\n"


def export_result(
    result: Path,
    tum: Path | None = None,
    map_csv: Path | None = None,
    occupancy_yaml: Path | None = None,
    input_path: Path | None = None,
    resolution_m: float | None = None,
    reference: Path | None = None,
    phase: Phase = quiet,
) -> list[Path]:
    """Write what is asked; the occupancy grid is the result's own when it holds one at `resolution_m`
    (None: whatever it holds), else built from the input's scans (`navigation_map.grid_from_result`). A
    localisation result gives its trajectory and reference; it has no map of its own to export."""
    meta = result_metadata(result)
    if is_localisation(meta):
        if map_csv is not None or occupancy_yaml is not None:
            raise InputError(
                f"{result} is a localisation result: it has no map of its own (--map and --occupancy export a "
                f"`gslam process` result; it localised in {meta['localise'].get('map')})"
            )
        with phase("reading the localisation", "scans") as report:
            loc = read_localisation(result, report)
        written = []
        if tum is not None:
            written.append(write_atomic(tum, tum_text(tum_stamps(loc.stamp_s), loc.poses, LOCALISATION_HEADER)))
        if reference is not None:
            written.append(write_atomic(reference, reference_tum(loc, result, input_path)))
        return written
    written = []
    res = None
    if tum is not None or reference is not None or map_csv is not None:
        with phase("reading the result", "steps") as report:
            res = read_result(result, report)
        if tum is not None:
            written.append(write_atomic(tum, tum_text(tum_stamps(res.stamp_s), res.trajectory)))
        if reference is not None:
            written.append(write_atomic(reference, reference_tum(res, result, input_path)))
        if map_csv is not None:
            written.append(write_atomic(map_csv, map_csv_text(res.map_xy, res.map_p)))
    if occupancy_yaml is not None:
        from pipelines.outputs.navigation_map import write_map_server

        written += write_map_server(occupancy_grid(result, input_path, resolution_m, phase, res), occupancy_yaml)
    return written


def occupancy_grid(
    result: Path,
    input_path: Path | None,
    resolution_m: float | None,
    phase: Phase = quiet,
    res: ResultData | None = None,
) -> OccupancyGrid:
    """`navigation_map.grid_from_result`, with progress: the grid the result holds when it has one at
    `resolution_m` (None: whatever it holds); else built again from the input's scans (seconds per thousand
    scans), reading the result (unless `res` is it, read already) and casting the scans each reported
    through `phase`."""
    from pipelines.outputs.navigation_map import grid_from_result, stored_grid

    stored = stored_grid(result)
    if stored is not None and (resolution_m is None or abs(stored.spec.resolution_m - resolution_m) < 1e-9):
        return stored
    if res is None:
        with phase("reading the result", "steps") as report:
            res = read_result(result, report)
    with phase("occupancy grid from the input's scans", "scans") as report:
        return grid_from_result(result, input_path, resolution_m, res=res, progress=report)
