"""Navigation maps of a run: the trinary occupancy grid (`occupancy_grid`), built from the final map and
the input's scans cast along the final trajectory, written as a map_server map (PGM + YAML) or as the
foxglove.Grid of /map/occupancy.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mcaplog import channels as ch
from mcaplog.mcapio import McapInput
from pipelines.errors import InputError
from pipelines.outputs.occupancy_grid import FREE, OCCUPIED, GridSpec, OccupancyGrid, ScanCaster, occupied_cells
from pipelines.run.input_log import InputLog

if TYPE_CHECKING:
    from pipelines.evaluation.evaluate import ResultData

DEFAULT_RESOLUTION_M = 0.05
OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196
"""map_server's thresholds (as map_saver writes them): with negate 0 a pixel's occupancy is
(255 - value) / 255, so 0 is occupied, 254 free and 205 (0.196...) neither: unknown."""
PGM_OCCUPIED, PGM_FREE, PGM_UNKNOWN = 0, 254, 205
SUPPORT_M = 0.15
"""A return marks its cell occupied when a probable map point lies this close (pipelines.outputs.occupancy_grid)."""


def build_grid(
    log: InputLog,
    scan_indices: np.ndarray,
    laser_poses: np.ndarray,
    map_xy: np.ndarray,
    map_p: np.ndarray,
    resolution_m: float = DEFAULT_RESOLUTION_M,
    bearing_offset_rad: float = 0.0,
    support_m: float = SUPPORT_M,
    progress: Callable[[int, int], None] | None = None,
    earlier: Sequence[tuple[np.ndarray, np.ndarray]] = (),
) -> OccupancyGrid:
    """The grid of a run: `laser_poses[j]` is where the input's scan number `scan_indices[j]` (increasing)
    was taken; `map_p` are occupancy probabilities of the map points `map_xy`. `progress(done, total)`
    counts the input's scans read (a long log takes seconds per thousand scans). `earlier`: the scans of
    the earlier runs a continued result holds (`pipelines.run.continuation.earlier_node_scans`), each a
    laser pose (3,) and its returns (K, 2) in that laser's frame, cast as the input's are: the free space
    of places only an earlier run saw."""
    scan_indices = np.asarray(scan_indices, dtype=np.int64)
    origins = np.vstack([laser_poses[:, :2], *(np.asarray(pose)[None, :2] for pose, _ in earlier)])
    spec = GridSpec.around(np.vstack([np.asarray(map_xy).reshape(-1, 2), origins]), resolution_m)
    casts = ScanCaster(spec)
    for pose, returns in earlier:
        returns = np.asarray(returns, dtype=float).reshape(-1, 2)
        casts.add_scan(np.asarray(pose, dtype=float), np.hypot(returns[:, 0], returns[:, 1]),
                       np.arctan2(returns[:, 1], returns[:, 0]))  # fmt: skip
    g = log.geometry
    bearings = g.bearings_rad + bearing_offset_rad
    for j, ev in enumerate(log.scans_at(scan_indices, progress)):
        r = ev.ranges_m
        returns = np.isfinite(r) & (r < g.max_range_m) & (r > log.self_return_range_m)
        beams = bearings if ev.geometry is g else ev.geometry.bearings_rad + bearing_offset_rad
        casts.add_scan(laser_poses[j], np.where(returns, r, np.nan), beams)
    occupied = occupied_cells(spec, map_xy, map_p, OCCUPIED_THRESH, casts.hit, support_m)
    return OccupancyGrid.combine(spec, occupied, casts.free)


def occupancy_probabilities(p: np.ndarray, map_update: str) -> np.ndarray:
    """Map point probabilities as occupancy probabilities: the "binary" update's p already is one; the
    other updates spread a mass over the map, scaled here to its maximum."""
    p = np.asarray(p, dtype=float)
    if map_update == "binary" or len(p) == 0:
        return p
    return p / max(float(p.max()), 1e-300)


def stored_grid(result: Path) -> OccupancyGrid | None:
    """The grid a result holds on /map/occupancy (`gslam process --occupancy`), or None."""
    last = None
    for m in McapInput(result).messages([ch.MAP_OCCUPANCY]):
        last = m.value
    if last is None:
        return None
    width = int(last.column_count)
    cells = np.frombuffer(last.data, dtype=np.int8)
    if width < 1 or len(cells) % width or not last.cell_size.x > 0:
        raise InputError(f"{result}: {ch.MAP_OCCUPANCY} is malformed ({len(cells)} cells in rows of {width})")
    spec = GridSpec(
        (float(last.pose.position.x), float(last.pose.position.y)), float(last.cell_size.x), width, len(cells) // width
    )
    return OccupancyGrid(spec, cells.reshape(spec.height, width).copy())


def grid_from_result(
    result: Path,
    input_path: Path | None = None,
    resolution_m: float | None = None,
    res: ResultData | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> OccupancyGrid:
    """The grid of a result MCAP: the one it holds (`process --occupancy`) when `resolution_m` is None or
    that grid's own, else built again from the input's scans (`input_path`, default the path in the
    result's metadata) at `resolution_m` (default `DEFAULT_RESOLUTION_M`). `res`: the result, when read
    already; `progress`: as `build_grid`'s."""
    stored = stored_grid(result)
    if stored is not None and (resolution_m is None or abs(stored.spec.resolution_m - resolution_m) < 1e-9):
        return stored
    resolution_m = DEFAULT_RESOLUTION_M if resolution_m is None else resolution_m
    if res is None:
        from pipelines.evaluation.evaluate import read_result

        res = read_result(result)
    meta = res.metadata
    if input_path is None:
        from pipelines.run.recorded_input import recorded_input

        input_path = recorded_input(result, meta, "--input")
    log = InputLog(Path(input_path))
    scan_indices = [m.value["scan_index"] for m in McapInput(result).messages([ch.SLAM_STATS])]
    if len(scan_indices) != len(res.trajectory):
        raise InputError(f"{result}: {len(scan_indices)} step records for {len(res.trajectory)} poses")
    laser = res.trajectory if log.mount is None else log.mount.laser_of(res.trajectory)
    config = meta.get("config", {})
    p = occupancy_probabilities(res.map_p, config.get("filter", {}).get("map_update", "binary"))
    offset = float(config.get("laser_yaw_offset_rad", 0))
    from pipelines.run.continuation import earlier_node_scans

    earlier = earlier_node_scans(result, log.mount)
    return build_grid(
        log, np.asarray(scan_indices), laser, res.map_xy, p, resolution_m, offset, progress=progress, earlier=earlier
    )


def pgm_bytes(grid: OccupancyGrid, comment: str = "gslam occupancy grid") -> bytes:
    """Binary PGM (P5): the top row is the largest y, as map_server reads it."""
    state = grid.state[::-1]
    pix = np.full(state.shape, PGM_UNKNOWN, dtype=np.uint8)
    pix[state == FREE] = PGM_FREE
    pix[state == OCCUPIED] = PGM_OCCUPIED
    header = f"P5\n# {comment}\n{grid.spec.width} {grid.spec.height}\n255\n".encode()
    return header + pix.tobytes()


def map_yaml_text(grid: OccupancyGrid, image_name: str) -> str:
    x, y = grid.spec.origin_xy_m
    return (
        f"image: {image_name}\n"
        f"mode: trinary\n"
        f"resolution: {grid.spec.resolution_m:g}\n"
        f"origin: [{x:.6f}, {y:.6f}, 0.0]\n"
        f"negate: 0\n"
        f"occupied_thresh: {OCCUPIED_THRESH}\n"
        f"free_thresh: {FREE_THRESH}\n"
    )


def write_map_server(grid: OccupancyGrid, yaml_path: Path) -> list[Path]:
    """`yaml_path` and the PGM beside it (same name, .pgm), each written atomically."""
    from mcaplog.tempfiles import write_atomic

    yaml_path = Path(yaml_path)
    pgm_path = yaml_path.with_suffix(".pgm")
    cells = grid.spec.width * grid.spec.height
    pgm = write_atomic(pgm_path, pgm_bytes(grid, f"gslam occupancy grid, {grid.spec.resolution_m:g} m, {cells} cells"))
    return [pgm, write_atomic(yaml_path, map_yaml_text(grid, pgm_path.name))]
