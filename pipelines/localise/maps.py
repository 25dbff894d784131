"""Saved maps for `gslam localise`: a `gslam process` result MCAP (its final point map) or a map_server map
(YAML + PGM, from gslam export or any other tool), turned into the core's likelihood field."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gslam.localise.field import LikelihoodField
from pipelines.errors import InputError


@dataclass
class SavedMap:
    field: LikelihoodField
    points: np.ndarray
    """(K, 2) the obstacles, for the viewers."""
    source: str
    """What the map was built from, for the user and the result's metadata."""


def load_map(path: Path) -> SavedMap:
    """The map at `path`: a .yaml map_server map or a result .mcap of `gslam process`."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such map file")
    if path.suffix.lower() in (".yaml", ".yml"):
        return _map_server(path)
    if path.suffix.lower() == ".mcap":
        return _result_map(path)
    raise InputError(f"{path}: a map is a map_server .yaml or a `gslam process` result .mcap")


def _result_map(path: Path) -> SavedMap:
    from pipelines.evaluation.evaluate import read_result
    from pipelines.outputs.navigation_map import grid_from_result
    from pipelines.outputs.occupancy_grid import FREE

    result = read_result(path)
    cfg = result.metadata.get("config", {})
    min_p = float(cfg.get("filter", {}).get("match_min_p", 0.0)) if isinstance(cfg, dict) else 0.0
    keep = result.map_p >= min_p
    xy = result.map_xy[keep]
    if len(xy) == 0:
        raise InputError(f"{path}: the result's final map has no points to localise against")
    try:
        field = LikelihoodField.from_points(xy)
    except ValueError as e:
        raise InputError(f"{path}: {e}") from None
    try:
        grid = grid_from_result(path)
    except (InputError, OSError):
        grid = None  # the run's input is not at hand: free space is taken near the walls
    source = f"{path.name}: {len(xy)} map points"
    if grid is not None:
        rows, cols = np.indices(field.shape)
        x = field.origin_xy_m[0] + (cols + 0.5) * field.cell_m
        y = field.origin_xy_m[1] + (rows + 0.5) * field.cell_m
        spec = grid.spec
        ix = np.floor((x - spec.origin_xy_m[0]) / spec.resolution_m).astype(int)
        iy = np.floor((y - spec.origin_xy_m[1]) / spec.resolution_m).astype(int)
        inside = (ix >= 0) & (ix < spec.width) & (iy >= 0) & (iy < spec.height)
        free = np.zeros(field.shape, dtype=bool)
        free[inside] = grid.state[iy[inside], ix[inside]] == FREE
        if (free & field.free).any():
            field = LikelihoodField(field.origin_xy_m, field.cell_m, field.distance_m, free & field.free,
                                    field.max_distance_m)  # fmt: skip
            source += ", free space from the run's occupancy grid"
    else:
        source += ", free space: within 3 m of the walls (the run's input was not found)"
    return SavedMap(field, xy, source)


def _yaml_values(path: Path) -> dict[str, str]:
    values = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if ":" in line:
            key, value = line.split(":", 1)
            values[key.strip()] = value.strip().strip("'\"")
    return values


def read_pgm(path: Path) -> np.ndarray:
    """A binary (P5) or plain (P2) PGM as (height, width) uint8 or uint16, top row first."""
    data = path.read_bytes()
    tokens: list[bytes] = []
    pos = 0
    while len(tokens) < 4:
        m = re.compile(rb"\s*(#[^\n]*\n\s*)*([^\s#]+)").match(data, pos)
        if m is None:
            raise InputError(f"{path}: not a PGM image (header)")
        tokens.append(m.group(2))
        pos = m.end()
    magic, width, height, maxval = tokens[0], int(tokens[1]), int(tokens[2]), int(tokens[3])
    if magic == b"P5":
        dtype = np.uint8 if maxval < 256 else np.dtype(">u2")
        pixels = np.frombuffer(data, dtype=dtype, count=width * height, offset=pos + 1)
    elif magic == b"P2":
        pixels = np.array(data[pos:].split()[: width * height], dtype=np.int64)
    else:
        raise InputError(f"{path}: not a PGM image (magic {magic!r})")
    if pixels.size != width * height:
        raise InputError(f"{path}: PGM holds {pixels.size} of its {width} x {height} pixels")
    return pixels.reshape(height, width)


def _map_server(path: Path) -> SavedMap:
    v = _yaml_values(path)
    try:
        image = path.parent / v["image"]
        resolution = float(v["resolution"])
        origin = [float(s) for s in v["origin"].strip("[]").split(",")]
        negate = int(v.get("negate", "0"))
        occupied_thresh = float(v.get("occupied_thresh", "0.65"))
        free_thresh = float(v.get("free_thresh", "0.196"))
    except (KeyError, ValueError) as e:
        raise InputError(f"{path}: not a map_server map ({e})") from None
    if not image.exists():
        raise InputError(f"{path}: its image {image} does not exist")
    pixels = read_pgm(image).astype(float)
    top = float(pixels.max()) if pixels.max() > 255 else 255.0
    occupancy = pixels / top if negate else (top - pixels) / top
    occupied = occupancy[::-1] > occupied_thresh  # rows along y: the image's top row is the largest y
    free = occupancy[::-1] < free_thresh
    if abs(origin[2] if len(origin) > 2 else 0.0) > 1e-9:
        raise InputError(f"{path}: a rotated map origin ({math.degrees(origin[2]):.1f} deg) is not supported")
    try:
        field = LikelihoodField.from_grid(occupied, free, np.array(origin[:2]), resolution)
    except ValueError as e:
        raise InputError(f"{path}: {e}") from None
    rows, cols = np.nonzero(occupied)
    points = np.column_stack([origin[0] + (cols + 0.5) * resolution, origin[1] + (rows + 0.5) * resolution])
    return SavedMap(field, points, f"{path.name}: {occupied.sum()} occupied cells of {resolution} m")
