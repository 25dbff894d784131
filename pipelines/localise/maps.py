"""Saved maps for `gslam localise`: a `gslam process` result MCAP (its final point map) or a map_server map
(YAML + PGM, from gslam export or any other tool), turned into the core's likelihood field.

A map's files are opened only when they are what they claim to be: regular files (never a FIFO, a device or
a directory, which would block or never end), of a bounded size; the YAML's fields are checked (each refusal
names the field), the PGM's header too, and its width x height against the file's size and the field's cap
(`gslam.localise.field.MAX_FIELD_CELLS`) before any pixel is read. A file that is not a map is refused in one
line naming it, never echoing its bytes."""

from __future__ import annotations

import math
import os
import re
import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from gslam.localise.field import MAX_FIELD_CELLS, LikelihoodField, check_field_size
from mcaplog.tempfiles import file_kind
from pipelines.errors import InputError
from pipelines.run.recorded_input import shown

MAX_YAML_BYTES = 1 << 16
"""A map_server YAML is a few lines (a few hundred bytes); anything over 64 KiB is not one."""
MAX_IMAGE_BYTES = 512 << 20
"""The largest PGM read: the field's cap of 1e8 cells as 16-bit binary pixels (200 MB) or as plain text of
up to 5 characters a pixel, with room."""
MAX_HEADER_BYTES = 1 << 16
"""A PGM's header (magic, width, height, maxval and comments) must end within this."""
MIN_RESOLUTION_M, MAX_RESOLUTION_M = 1e-3, 100.0
"""A map cell of 1 mm to 100 m (map_server maps: 1 to 10 cm)."""
MAX_COORDINATE_M = 1e7
"""A map's origin (and a pose in it) lies within 10 000 km of 0: room for UTM coordinates, and far from
the sizes where float arithmetic on particle poses loses the centimetres."""


@dataclass
class SavedMap:
    field: LikelihoodField
    points: np.ndarray
    """(K, 2) the obstacles, for the viewers."""
    source: str
    """What the map was built from, for the user and the result's metadata."""


def _bytes(n: int) -> str:
    return f"{n} bytes" if n < 1 << 10 else f"{n / 2**10:.0f} KiB" if n < 1 << 20 else f"{n / 2**20:.0f} MiB"


Refuse = Callable[[str], InputError]
"""Makes the one-line error for a file that is not what it should be, from why (e.g. "is a FIFO, not a file")."""


def _open_regular(path: Path, max_bytes: int, refuse: Refuse) -> tuple[BinaryIO, int]:
    """(binary file, size) of `path` when it is a regular file of at most `max_bytes`; else raises
    `refuse(why)`. Checked before it is opened (a device or FIFO is never opened) and again on the open file
    (it may have been swapped meanwhile); opened non-blocking, so that a FIFO swapped in cannot hang."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise refuse("does not exist") from None
    except OSError as e:
        raise refuse(f"cannot be read ({e.strerror})") from None
    if not stat.S_ISREG(mode):
        raise refuse(f"is {file_kind(mode)}, not a file")
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
    except OSError as e:
        raise refuse(f"cannot be read ({e.strerror})") from None
    f = os.fdopen(fd, "rb")
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        f.close()
        raise refuse(f"is {file_kind(st.st_mode)}, not a file")
    if st.st_size > max_bytes:
        f.close()
        raise refuse(f"is {_bytes(st.st_size)}, over the {_bytes(max_bytes)} a map file of its kind may be")
    return f, st.st_size


def _check_map_file(path: Path) -> None:
    """Refuse MAP when it is missing or not a regular file (a FIFO would block the read)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise InputError(f"{path}: no such map file") from None
    except OSError as e:
        raise InputError(f"{path}: cannot read the map ({e.strerror})") from None
    if not stat.S_ISREG(mode):
        raise InputError(f"{path}: is {file_kind(mode)}; a map is a map_server .yaml or a `gslam process` result .mcap")


def _is_yaml(path: Path) -> bool:
    return path.suffix.lower() in (".yaml", ".yml")


def load_map(path: Path) -> SavedMap:
    """The map at `path`: a .yaml map_server map or a result .mcap of `gslam process`."""
    path = Path(path)
    _check_map_file(path)
    if _is_yaml(path):
        return _map_server(path)
    if path.suffix.lower() == ".mcap":
        return _result_map(path)
    raise InputError(f"{path}: a map is a map_server .yaml or a `gslam process` result .mcap")


def map_reads(path: Path) -> dict[str, Path]:
    """The files localising in the map at `path` reads, labelled for the output checks: MAP itself, a YAML's
    image, a result's recorded input MCAP (read for its free space). Checked as `load_map` checks them
    (InputError for a map that is not one), without reading pixels or points: run before any work, so that
    no output is written over them."""
    path = Path(path)
    _check_map_file(path)
    reads = {"MAP": path}
    if _is_yaml(path):
        reads[f"MAP {path}'s image"] = map_server_yaml(path).image
    elif path.suffix.lower() == ".mcap":
        from pipelines.evaluation.localisation import result_metadata

        entry = result_metadata(path).get("input", {})
        recorded = entry.get("path") if isinstance(entry, dict) else None
        if isinstance(recorded, str) and recorded:
            reads[f"MAP {path}'s recorded input"] = Path(recorded)
    return reads


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
        field = LikelihoodField.from_points(xy)  # its size is checked before it is allocated
    except ValueError as e:
        raise InputError(f"{path}: {e}") from None
    try:
        grid = grid_from_result(path)
    except (InputError, OSError, ValueError):
        grid = None  # the run's input is not at hand (or its grid is too large): free space near the walls
    source = f"{path.name}: {len(xy)} map points"
    if grid is not None:
        # The grid's cell under each field cell's centre, by column and by row (the two grids are aligned
        # with the axes): index vectors, not arrays of the field's size.
        spec = grid.spec
        ny, nx = field.shape
        x = field.origin_xy_m[0] + (np.arange(nx) + 0.5) * field.cell_m
        y = field.origin_xy_m[1] + (np.arange(ny) + 0.5) * field.cell_m
        ix = np.floor((x - spec.origin_xy_m[0]) / spec.resolution_m).astype(int)
        iy = np.floor((y - spec.origin_xy_m[1]) / spec.resolution_m).astype(int)
        in_x, in_y = (ix >= 0) & (ix < spec.width), (iy >= 0) & (iy < spec.height)
        free = np.zeros(field.shape, dtype=bool)
        free[np.ix_(in_y, in_x)] = grid.state[np.ix_(iy[in_y], ix[in_x])] == FREE
        if (free & field.free).any():
            field = LikelihoodField(field.origin_xy_m, field.cell_m, field.distance_m, free & field.free,
                                    field.max_distance_m)  # fmt: skip
            source += ", free space from the run's occupancy grid"
    else:
        source += ", free space: within 3 m of the walls (the run's input was not found)"
    return SavedMap(field, xy, source)


@dataclass
class MapServerYaml:
    """The fields of a map_server YAML, checked."""

    image: Path
    resolution: float
    origin: tuple[float, float, float]
    negate: int
    occupied_thresh: float
    free_thresh: float


def _yaml_values(path: Path) -> dict[str, str]:
    """The `key: value` lines of a map_server YAML (a flat mapping; quotes and comments removed)."""

    def refuse(why: str) -> InputError:
        return InputError(f"{path}: {why}; a map_server map is a .yaml file beside its image")

    f, _ = _open_regular(path, MAX_YAML_BYTES, refuse)
    with f:
        data = f.read(MAX_YAML_BYTES + 1)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a map_server YAML (not UTF-8 text)") from None
    values = {}
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if ":" in line:
            key, value = line.split(":", 1)
            values[key.strip()] = value.strip().strip("'\"")
    return values


def _number(path: Path, field: str, text: str, low: float, high: float, what: str) -> float:
    """The YAML's `field` as a finite number within [low, high]; InputError naming the field otherwise."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and low <= value <= high):
        raise InputError(f"{path}: {field} {shown(text)[:40]!r} is not {what}")
    return value


def map_server_yaml(path: Path) -> MapServerYaml:
    """The checked fields of the map_server YAML at `path`: `image` a name beside it (or a path) to a
    regular file ending .pgm (checked when it is read), `resolution` in [1 mm, 100 m], `origin` x, y within
    `MAX_COORDINATE_M` and an optional yaw, `negate` 0 or 1, `occupied_thresh` and `free_thresh` in [0, 1]."""
    v = _yaml_values(path)
    for key in ("image", "resolution", "origin"):
        if key not in v:
            raise InputError(f"{path}: not a map_server map (no `{key}:`)")
    if not v["image"]:
        raise InputError(f"{path}: its `image:` is empty")
    image = path.parent / v["image"]
    resolution = _number(
        path, "resolution", v["resolution"], MIN_RESOLUTION_M, MAX_RESOLUTION_M,
        f"a cell size between {MIN_RESOLUTION_M:g} and {MAX_RESOLUTION_M:g} m",
    )  # fmt: skip
    parts = [s.strip() for s in v["origin"].strip().strip("[]").split(",")]
    if len(parts) not in (2, 3):
        raise InputError(f"{path}: origin {shown(v['origin'])[:60]!r} is not [x, y, yaw]")
    within = f"a finite number of metres within {MAX_COORDINATE_M:g} m of 0"
    x = _number(path, "origin x", parts[0], -MAX_COORDINATE_M, MAX_COORDINATE_M, within)
    y = _number(path, "origin y", parts[1], -MAX_COORDINATE_M, MAX_COORDINATE_M, within)
    yaw = _number(path, "origin yaw", parts[2], -1e3, 1e3, "a finite angle (rad)") if len(parts) > 2 else 0.0
    negate_text = v.get("negate", "0")
    if negate_text not in ("0", "1"):
        raise InputError(f"{path}: negate {shown(negate_text)[:40]!r} is not 0 or 1")
    thresholds = {}
    for key, default in (("occupied_thresh", "0.65"), ("free_thresh", "0.196")):
        thresholds[key] = _number(path, key, v.get(key, default), 0.0, 1.0, "a number between 0 and 1")
    return MapServerYaml(image, resolution, (x, y, yaw), int(negate_text), **thresholds)


_TOKEN = re.compile(rb"(?:\s|#[^\n]*(?:\n|$))*([^\s#]+)")
_NUMBER = re.compile(rb"[0-9]{1,10}")
_P2_CHUNK = 1 << 20


def read_pgm(
    path: Path, refuse: Refuse | None = None, check_shape: Callable[[int, int], None] | None = None
) -> np.ndarray:
    """A binary (P5) or plain (P2) PGM as (height, width) uint8 or uint16, top row first. A regular file of
    at most `MAX_IMAGE_BYTES`; its header checked, and width x height against the file's size and
    `check_shape(width, height)` (default: at most `MAX_FIELD_CELLS` pixels), before the pixels are read.
    `refuse(why)` makes the InputError (default: naming the file)."""
    path = Path(path)
    if refuse is None:

        def refuse(why: str) -> InputError:
            return InputError(f"{path}: {why}")

    f, size = _open_regular(path, MAX_IMAGE_BYTES, refuse)
    with f:
        head = f.read(MAX_HEADER_BYTES)
        tokens: list[bytes] = []
        pos = 0
        while len(tokens) < 4:
            m = _TOKEN.match(head, pos)
            if m is None:
                break
            tokens.append(m.group(1))
            pos = m.end()
        if not tokens or tokens[0] not in (b"P5", b"P2"):
            raise refuse("is not a PGM image (it does not start with P5 or P2)")
        if len(tokens) < 4 or not all(_NUMBER.fullmatch(t) for t in tokens[1:]) or pos >= len(head):
            raise refuse("is not a PGM image (its header is not: magic, width, height, maxval)")
        width, height, maxval = int(tokens[1]), int(tokens[2]), int(tokens[3])
        if width < 1 or height < 1 or not 1 <= maxval <= 65535:
            raise refuse(f"is not a PGM image (width {width}, height {height}, maxval {maxval})")
        if not head[pos : pos + 1].isspace():
            raise refuse("is not a PGM image (no whitespace after its maxval)")
        pixels_at = pos + 1  # one whitespace character ends the header
        count = width * height
        if check_shape is not None:
            check_shape(width, height)
        elif count > MAX_FIELD_CELLS:
            raise refuse(f"is {width} x {height} pixels = {count:.3g}, over the {MAX_FIELD_CELLS:.0e} a map may have")
        if tokens[0] == b"P5":
            dtype = np.dtype(np.uint8) if maxval < 256 else np.dtype(">u2")
            if size - pixels_at < count * dtype.itemsize:
                raise refuse(
                    f"holds {size - pixels_at} bytes of pixels; its {width} x {height} need {count * dtype.itemsize}"
                )
            f.seek(pixels_at)
            pixels = np.frombuffer(f.read(count * dtype.itemsize), dtype=dtype)
        else:
            if size - pixels_at < 2 * count - 1:  # a digit and a separator a pixel at the least
                raise refuse(f"holds {size - pixels_at} bytes of text; its {width} x {height} pixels need more")
            f.seek(pixels_at)
            pixels = _plain_pixels(f, count, refuse)
    if int(pixels.max()) > maxval:
        raise refuse(f"has pixels over its maxval {maxval}")
    return pixels.reshape(height, width)


def _plain_pixels(f: BinaryIO, count: int, refuse: Refuse) -> np.ndarray:
    """The first `count` whitespace-separated decimal pixels of a plain PGM's raster, as uint16, read in
    chunks (never the whole text as Python objects)."""
    out = np.empty(count, dtype=np.uint16)
    done = 0
    carry = b""
    while done < count:
        chunk = f.read(_P2_CHUNK)
        text = carry + chunk
        if chunk:  # the last token may continue in the next chunk
            cut = max(text.rfind(b" "), text.rfind(b"\n"), text.rfind(b"\t"), text.rfind(b"\r"))
            text, carry = (text[: cut + 1], text[cut + 1 :]) if cut >= 0 else (b"", text)
        else:
            carry = b""
        if len(carry) > 16:  # no pixel is that long: not a raster of numbers (and no carry grows unbounded)
            raise refuse("is not a PGM image (its plain raster holds something other than decimal pixels)")
        words = text.split()
        if words:
            if not all(_NUMBER.fullmatch(w) for w in words):
                raise refuse("is not a PGM image (its plain raster holds something other than decimal pixels)")
            values = np.array(words[: count - done], dtype=np.int64)
            if values.size and int(values.max()) > 65535:
                raise refuse("is not a PGM image (a pixel over 65535)")
            out[done : done + values.size] = values
            done += values.size
        if not chunk and not words:
            break
    if done < count:
        raise refuse(f"holds {done} of its {count} pixels")
    return out


def _map_server(path: Path) -> SavedMap:
    y = map_server_yaml(path)

    def refuse(why: str) -> InputError:
        return InputError(f"{path}: its image {shown(y.image)} {why}")

    if abs(y.origin[2]) > 1e-9:
        raise InputError(f"{path}: a rotated map origin ({math.degrees(y.origin[2]):.1f} deg) is not supported")
    if y.image.suffix.lower() != ".pgm":
        raise refuse("is not a .pgm file; gslam reads map images in PGM (P5 or P2)")

    def check_shape(width: int, height: int) -> None:
        """The field's cap, before the pixels are read, with the map's extent."""
        extent = (
            f"its image {shown(y.image)} is {width} x {height} pixels of {y.resolution:g} m, "
            f"{width * y.resolution:.6g} m x {height * y.resolution:.6g} m"
        )
        try:
            check_field_size(width, height, y.resolution, extent)
        except ValueError as e:
            raise InputError(f"{path}: {e}") from None

    pixels = read_pgm(y.image, refuse, check_shape)
    top = int(pixels.max()) if int(pixels.max()) > 255 else 255
    # The occupancy of each grey level, as map_server computes it, looked up: no float array of the image's size.
    grey = np.arange(top + 1, dtype=float)
    occupancy = grey / top if y.negate else (top - grey) / top
    occupied = (occupancy > y.occupied_thresh)[pixels[::-1]]  # rows along y: the image's top row is the largest y
    free = (occupancy < y.free_thresh)[pixels[::-1]]
    origin = np.array(y.origin[:2])
    try:
        field = LikelihoodField.from_grid(occupied, free, origin, y.resolution)
    except ValueError as e:
        raise InputError(f"{path}: {e}") from None
    rows, cols = np.nonzero(occupied)
    points = np.column_stack([origin[0] + (cols + 0.5) * y.resolution, origin[1] + (rows + 0.5) * y.resolution])
    return SavedMap(field, points, f"{path.name}: {occupied.sum()} occupied cells of {y.resolution} m")
