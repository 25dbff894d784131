"""Reader for CARMEN logs (`.clf`/`.log`, plain or gzip): FLASER scans and ODOM odometry.

    FLASER n r_1..r_n x y theta odom_x odom_y odom_theta ipc_timestamp hostname logger_timestamp
    ODOM x y theta tv rv accel ipc_timestamp hostname logger_timestamp

Beams start at -90 deg (right) and go counter-clockwise: 180 beams = 1 deg steps, 360 = 0.5 deg
(-90..+89.5), 361 = 0.5 deg (-90..+90), 181 = 1 deg (-90..+90). Ranges >= 81.9 m carry no return.
The odometry pose stored in each FLASER line and every ODOM line go to one odometry stream, in file
order (they share the odometry frame), so the filter has the odometry exactly at each scan.
"""

from __future__ import annotations

import gzip
import math
import zlib
from pathlib import Path

import numpy as np

from .base import ReadOptions
from .logdata import LogData, ScanGeometry
from .textlog import IngestError, time_problem

CARMEN_NO_RETURN_M = 81.9
"""Readings at or beyond this are no return (the SICK LMS reports 81.91 m or so when nothing is hit)."""
SATURATION_MIN_REPEATS = 100
"""A log's largest reading that recurs on at least this many beams is its laser's no-return value."""

CARMEN_SUFFIXES = (".clf", ".clf.gz", ".log", ".log.gz")


class CarmenReader:
    """A CARMEN log file (.clf/.log, plain or gzip), or a directory holding exactly one."""

    formats = ("carmen",)

    def detect(self, source: Path) -> str | None:
        if source.is_file():
            return "carmen" if source.name.lower().endswith((*CARMEN_SUFFIXES, ".gz")) else None
        return "carmen" if len(_logs_in(source)) == 1 else None

    def open(self, source: Path, fmt: str, options: ReadOptions) -> LogData:
        if source.is_dir():
            logs = _logs_in(source)
            if len(logs) != 1:
                raise IngestError(f"{source}: expected one CARMEN log in the directory, found {len(logs)}")
            source = logs[0]
        return read_carmen(source, options.skip_bad_lines)


def _logs_in(directory: Path) -> list[Path]:
    return sorted(p for p in directory.iterdir() if p.name.endswith(CARMEN_SUFFIXES))


def no_return_range_m(ranges_m: np.ndarray) -> float:
    """The range from which readings carry no return. CARMEN logs do not record it; the SICK lasers write
    a fixed saturation value when nothing is hit (81.91 m on mit-csail, 81.83 m on intel). The log's
    largest reading is that value when it recurs on many beams (a real far return is not repeated to the
    centimetre): then it and everything above it is no return, as GMapping's ROS wrapper does with
    `range_max - 0.01`. Otherwise the fixed CARMEN bound applies."""
    finite = ranges_m[np.isfinite(ranges_m)]
    if finite.size == 0:
        return CARMEN_NO_RETURN_M
    top = float(finite.max())
    if top < CARMEN_NO_RETURN_M and int(np.count_nonzero(finite == top)) >= SATURATION_MIN_REPEATS:
        return top
    return CARMEN_NO_RETURN_M


def carmen_geometry(beam_count: int, max_range_m: float = CARMEN_NO_RETURN_M) -> ScanGeometry:
    """Beam geometry from the beam count (see module docstring)."""
    if beam_count in (180, 360):
        step = math.pi / beam_count
    else:
        step = math.pi / max(beam_count - 1, 1)
    return ScanGeometry(beam_count, -math.pi / 2, step, max_range_m)


def _open_text(path: Path) -> str:
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise IngestError(f"{path}: file not found") from None
    if raw[:2] == b"\x1f\x8b":
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError, zlib.error) as e:
            raise IngestError(f"{path}: corrupt gzip data ({e})") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def relations_path_for(path: Path) -> Path:
    name = path.name
    for suffix in (".gz", ".clf", ".log"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
    return path.with_name(name + ".relations")


def read_relations(path: Path) -> np.ndarray:
    """`t1 t2 dx dy dz droll dpitch dyaw` lines -> (R, 5): t1_s, t2_s, dx_m, dy_m, dyaw_rad."""
    rows = []
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        if len(parts) != 8:
            raise IngestError(
                f"{path}:{lineno}: expected 8 columns (t1 t2 dx dy dz droll dpitch dyaw), found {len(parts)}"
            )
        try:
            v = [float(p) for p in parts]
        except ValueError:
            raise IngestError(f"{path}:{lineno}: not a number") from None
        if not all(math.isfinite(x) for x in v):
            raise IngestError(f"{path}:{lineno}: non-finite value (NaN or infinity)")
        rows.append([v[0], v[1], v[2], v[3], v[7]])
    if not rows:
        raise IngestError(f"{path}: no relations")
    return np.asarray(rows)


def read_carmen(path: Path, skip_bad_lines: bool = False) -> LogData:
    path = Path(path)
    text = _open_text(path)
    warnings: list[str] = []
    scan_t: list[float] = []
    scans: list[np.ndarray] = []
    odom: list[tuple[float, float, float, float, float, float]] = []
    odom_source: list[str] = []
    beam_count: int | None = None
    dropped = 0
    first_drop = ""
    other: dict[str, int] = {}

    def bad(lineno: int, why: str) -> None:
        nonlocal dropped, first_drop
        if not skip_bad_lines:
            raise IngestError(f"{path}:{lineno}: {why}")
        dropped += 1
        first_drop = first_drop or f"{path}:{lineno}: {why}"

    for lineno, line in enumerate(text.splitlines(), start=1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        kind = parts[0]
        if kind == "FLASER":
            try:
                n = int(parts[1])
            except (IndexError, ValueError):
                bad(lineno, "FLASER without a beam count")
                continue
            if len(parts) < n + 9:
                bad(
                    lineno,
                    f"FLASER with {n} beams needs {n + 9} fields (up to ipc_timestamp and "
                    f"hostname), found {len(parts)}",
                )
                continue
            if beam_count is not None and n != beam_count:
                bad(lineno, f"FLASER with {n} beams after scans with {beam_count}")
                continue
            try:
                ranges = np.array(parts[2 : 2 + n], dtype=float)
                ox, oy, oth = (float(p) for p in parts[2 + n + 3 : 2 + n + 6])
                t = float(parts[2 + n + 6])
            except ValueError:
                bad(lineno, "FLASER field is not a number")
                continue
            if not np.isfinite(ranges).all():
                bad(lineno, "FLASER has a non-finite range")
                continue
            if not all(math.isfinite(v) for v in (ox, oy, oth)) or time_problem(t):
                bad(lineno, time_problem(t) or "FLASER has a non-finite odometry pose")
                continue
            if (ranges < 0).any():
                bad(lineno, f"negative range {ranges[ranges < 0][0]} m at beam {int(np.argmax(ranges < 0))}")
                continue
            beam_count = n
            scan_t.append(t)
            scans.append(ranges)
            odom.append((t, ox, oy, oth, math.nan, math.nan))
            odom_source.append("FLASER")
        elif kind == "ODOM":
            if len(parts) < 8:
                bad(
                    lineno,
                    f"ODOM needs at least 8 fields (ODOM x y theta tv rv accel ipc_timestamp), found {len(parts)}",
                )
                continue
            try:
                x, y, th, tv, rv = (float(p) for p in parts[1:6])
                t = float(parts[7])
            except ValueError:
                bad(lineno, "ODOM field is not a number")
                continue
            if not all(math.isfinite(v) for v in (x, y, th)) or time_problem(t):
                bad(lineno, time_problem(t) or "ODOM has a non-finite pose")
                continue
            odom.append((t, x, y, th, tv, rv))
            odom_source.append("ODOM")
        else:
            other[kind] = other.get(kind, 0) + 1
    if not scans:
        raise IngestError(f"{path}: no FLASER scans (empty or not a CARMEN log)")
    if dropped:
        warnings.append(f"{path}: skipped {dropped} malformed lines (first: {first_drop})")
    if other:
        listed = ", ".join(f"{k} x{v}" for k, v in sorted(other.items()))
        warnings.append(f"{path}: ignored lines of other types: {listed}")
    scan_t_s = np.asarray(scan_t)
    back = int(np.sum(np.diff(scan_t_s) <= 0))
    if back:
        warnings.append(f"{path}: {back} scans have non-increasing timestamps; file order kept")
    ranges_m = np.vstack(scans)
    no_return_m = no_return_range_m(ranges_m)
    ranges_m[ranges_m >= no_return_m] = np.inf
    name = path.name.split(".")[0]
    log = LogData(
        dataset=name,
        source_format="carmen",
        source=str(path),
        motion_model="odometry",
        geometry=carmen_geometry(int(beam_count), no_return_m),
        scan_t_s=scan_t_s,
        scan_ranges_m=ranges_m,
        odom_pose=np.asarray(odom),
        odom_source=odom_source,
        warnings=warnings,
    )
    rel = relations_path_for(path)
    if rel.exists():
        log.relations = read_relations(rel)
    else:
        warnings.append(f"{rel}: no relations file beside the log; relations metric unavailable")
    return log
