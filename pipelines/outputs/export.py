"""`gslam export`: the final best trajectory in TUM format, the final map as CSV, and the occupancy grid
as a map_server map (PGM + YAML)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mcaplog.tempfiles import write_atomic
from pipelines.evaluation.evaluate import read_result


def tum_text(stamp_s: np.ndarray, poses: np.ndarray) -> str:
    """TUM trajectory lines `t x y z qx qy qz qw` (evo's `evo_traj tum`, `evo_ape tum` read them)."""
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
    lines = ["# timestamp tx ty tz qx qy qz qw (gslam final best path: the base's if the laser is mounted off it)"]
    lines += [" ".join(f"{v:.9f}" if i == 0 else f"{v:.6f}" for i, v in enumerate(r)) for r in rows]
    return "\n".join(lines) + "\n"


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
) -> list[Path]:
    """Write what is asked; the occupancy grid is the result's own when it holds one at `resolution_m`
    (None: whatever it holds), else built from the input's scans (`navigation_map.grid_from_result`)."""
    res = read_result(result)
    written = []
    if tum is not None:
        # Strictly increasing stamps for TUM readers: logs whose stamps go backwards keep file order.
        stamps = res.stamp_s.copy()
        for i in range(1, len(stamps)):  # over steps, once
            if stamps[i] <= stamps[i - 1]:
                stamps[i] = stamps[i - 1] + 1e-6
        written.append(write_atomic(tum, tum_text(stamps, res.trajectory)))
    if map_csv is not None:
        written.append(write_atomic(map_csv, map_csv_text(res.map_xy, res.map_p)))
    if occupancy_yaml is not None:
        from pipelines.outputs.navigation_map import grid_from_result, write_map_server

        written += write_map_server(grid_from_result(result, input_path, resolution_m), occupancy_yaml)
    return written
