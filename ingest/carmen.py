"""Reader for CARMEN logs (`.clf`/`.log`, plain or gzip): FLASER scans and ODOM odometry.

    FLASER n r_1..r_n x y theta odom_x odom_y odom_theta ipc_timestamp hostname logger_timestamp
    ODOM x y theta tv rv accel ipc_timestamp hostname logger_timestamp

Beams start at -90 deg (right) and go counter-clockwise: 180 beams = 1 deg steps, 360 = 0.5 deg
(-90..+89.5), 361 = 0.5 deg (-90..+90), 181 = 1 deg (-90..+90). Ranges >= 81.9 m carry no return.
The odometry pose stored in each FLASER line and every ODOM line go to one odometry stream, in file
order (they share the odometry frame), so the filter has the odometry exactly at each scan.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .base import OdomRecord, ReadOptions, Record, RelationsRecord, ScanRecord
from .logdata import LogData, ScanGeometry
from .textlog import IngestError, MonotoneClock, odometry_problem, text_lines, time_problem

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

    def open(self, source: Path, fmt: str, options: ReadOptions) -> CarmenStream:
        if source.is_dir():
            logs = _logs_in(source)
            if len(logs) != 1:
                raise IngestError(f"{source}: expected one CARMEN log in the directory, found {len(logs)}")
            source = logs[0]
        return CarmenStream(source, options.skip_bad_lines)


def _logs_in(directory: Path) -> list[Path]:
    return sorted(p for p in directory.iterdir() if p.name.endswith(CARMEN_SUFFIXES))


def no_return_range_m(top_m: float, repeats: int) -> float:
    """The range from which readings carry no return. CARMEN logs do not record it; the SICK lasers write
    a fixed saturation value when nothing is hit (81.91 m on mit-csail, 81.83 m on intel). The log's
    largest reading (`top_m`, read by `repeats` beams) is that value when it recurs on many beams (a real
    far return is not repeated to the centimetre): then it and everything above it is no return, as
    GMapping's ROS wrapper does with `range_max - 0.01`. Otherwise the fixed CARMEN bound applies."""
    if top_m < CARMEN_NO_RETURN_M and repeats >= SATURATION_MIN_REPEATS:
        return top_m
    return CARMEN_NO_RETURN_M


def carmen_geometry(beam_count: int, max_range_m: float = CARMEN_NO_RETURN_M) -> ScanGeometry:
    """Beam geometry from the beam count (see module docstring)."""
    if beam_count in (180, 360):
        step = math.pi / beam_count
    else:
        step = math.pi / max(beam_count - 1, 1)
    return ScanGeometry(beam_count, -math.pi / 2, step, max_range_m)


MAX_BEAMS = 100_000
"""The most beams a scan may have (what `gslam process` accepts)."""


def _lines(path: Path) -> Iterator[tuple[int, str]]:
    """(line number, text) of a CARMEN log, plain or gzip, a line at a time; bytes that are not UTF-8 are
    read as Latin-1."""
    return text_lines(path, "CARMEN log", gzip_ok=True, latin1_fallback=True)


def relations_path_for(path: Path) -> Path:
    name = path.name
    for suffix in (".gz", ".clf", ".log"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
    return path.with_name(name + ".relations")


def read_relations(path: Path) -> np.ndarray:
    """`t1 t2 dx dy dz droll dpitch dyaw` lines -> (R, 5): t1_s, t2_s, dx_m, dy_m, dyaw_rad."""
    rows = []
    for lineno, line in text_lines(path, "CARMEN relations file"):
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


@dataclass
class _Event:
    kind: str  # "scan" (a FLASER line: its odometry pose, then its scan) or "odom"
    t_s: float
    pose: tuple[float, float, float, float, float]  # x, y, theta, tv, rv (NaN unknown)
    ranges_m: np.ndarray | None = None


class _Parser:
    """The FLASER and ODOM lines of a log, checked: every bad line is refused naming file and line (or,
    with `skip_bad_lines`, dropped and counted)."""

    def __init__(self, path: Path, skip_bad_lines: bool) -> None:
        self.path, self.skip_bad_lines = path, skip_bad_lines
        self.beam_count: int | None = None
        self.dropped = 0
        self.first_drop = ""
        self.other: dict[str, int] = {}

    def bad(self, lineno: int, why: str) -> None:
        if not self.skip_bad_lines:
            raise IngestError(f"{self.path}:{lineno}: {why}")
        self.dropped += 1
        self.first_drop = self.first_drop or f"{self.path}:{lineno}: {why}"

    def events(self) -> Iterator[_Event]:
        for lineno, line in _lines(self.path):
            parts = line.split()
            if not parts or parts[0].startswith("#"):
                continue
            kind = parts[0]
            if kind == "FLASER":
                event = self._flaser(lineno, parts)
            elif kind == "ODOM":
                event = self._odom(lineno, parts)
            else:
                self.other[kind] = self.other.get(kind, 0) + 1
                continue
            if event is not None:
                yield event

    def _flaser(self, lineno: int, parts: list[str]) -> _Event | None:
        try:
            n = int(parts[1])
        except (IndexError, ValueError):
            return self.bad(lineno, "FLASER without a beam count")
        if not 1 <= n <= MAX_BEAMS:
            return self.bad(lineno, f"FLASER with {n} beams (a scan has 1 to {MAX_BEAMS} beams)")
        if len(parts) < n + 9:
            return self.bad(
                lineno,
                f"FLASER with {n} beams needs {n + 9} fields (up to ipc_timestamp and hostname), found {len(parts)}",
            )
        if self.beam_count is not None and n != self.beam_count:
            return self.bad(lineno, f"FLASER with {n} beams after scans with {self.beam_count}")
        try:
            ranges = np.array(parts[2 : 2 + n], dtype=float)
            ox, oy, oth = (float(p) for p in parts[2 + n + 3 : 2 + n + 6])
            t = float(parts[2 + n + 6])
        except ValueError:
            return self.bad(lineno, "FLASER field is not a number")
        if not np.isfinite(ranges).all():
            return self.bad(lineno, "FLASER has a non-finite range")
        why = time_problem(t) or odometry_problem(ox, oy, oth)
        if why is not None:
            return self.bad(lineno, f"FLASER {why}")
        if (ranges < 0).any():
            return self.bad(lineno, f"negative range {ranges[ranges < 0][0]} m at beam {int(np.argmax(ranges < 0))}")
        self.beam_count = n
        return _Event("scan", t, (ox, oy, oth, math.nan, math.nan), ranges)

    def _odom(self, lineno: int, parts: list[str]) -> _Event | None:
        if len(parts) < 8:
            return self.bad(
                lineno, f"ODOM needs at least 8 fields (ODOM x y theta tv rv accel ipc_timestamp), found {len(parts)}"
            )
        try:
            x, y, th, tv, rv = (float(p) for p in parts[1:6])
            t = float(parts[7])
        except ValueError:
            return self.bad(lineno, "ODOM field is not a number")
        why = time_problem(t) or odometry_problem(x, y, th, speed_mps=tv, turn_rate_radps=rv)
        if why is not None:
            return self.bad(lineno, f"ODOM {why}")
        return _Event("odom", t, (x, y, th, tv, rv))


class CarmenStream:
    """A CARMEN log streamed into the MCAP writer (a `LogStream`), in two passes over the file, so memory
    stays flat in the log's length: the first checks every line and finds what the records need (the
    beam count, the no-return range `no_return_range_m`, the first time, the counts); the second yields
    the records in file order (each FLASER's odometry pose just before its scan)."""

    source_format = "carmen"

    def __init__(self, path: Path, skip_bad_lines: bool = False) -> None:
        self.path = Path(path)
        self.skip_bad_lines = skip_bad_lines
        self.dataset = self.path.name.split(".")[0]
        self.warnings: list[str] = []
        parser = _Parser(self.path, skip_bad_lines)
        scans = odoms = back = top_count = 0
        top = -math.inf
        first_t = last_scan_t = None
        for ev in parser.events():
            first_t = ev.t_s if first_t is None else first_t
            odoms += 1
            if ev.kind == "scan":
                scans += 1
                if last_scan_t is not None and ev.t_s <= last_scan_t:
                    back += 1
                last_scan_t = ev.t_s
                m = float(ev.ranges_m.max()) if len(ev.ranges_m) else -math.inf
                if m > top:
                    top, top_count = m, int(np.count_nonzero(ev.ranges_m == m))
                elif m == top:
                    top_count += int(np.count_nonzero(ev.ranges_m == m))
        if not scans:
            raise IngestError(f"{self.path}: no FLASER scans (empty or not a CARMEN log)")
        if parser.dropped:
            self.warnings.append(f"{self.path}: skipped {parser.dropped} malformed lines (first: {parser.first_drop})")
        if parser.other:
            listed = ", ".join(f"{k} x{v}" for k, v in sorted(parser.other.items()))
            self.warnings.append(f"{self.path}: ignored lines of other types: {listed}")
        if back:
            self.warnings.append(f"{self.path}: {back} scans have non-increasing timestamps; file order kept")
        self.no_return_m = no_return_range_m(top, top_count)
        self.geometry = carmen_geometry(int(parser.beam_count), self.no_return_m)
        self.first_t_s = float(first_t)
        self.scan_count, self.odom_count = scans, odoms
        rel = relations_path_for(self.path)
        self.relations = read_relations(rel) if rel.exists() else None
        if self.relations is None:
            self.warnings.append(f"{rel}: no relations file beside the log; relations metric unavailable")

    def counts(self) -> dict[str, int]:
        n_rel = 0 if self.relations is None else len(self.relations)
        return {
            "scans": self.scan_count,
            "ackermann": 0,
            "odom_pose": self.odom_count,
            "gps": 0,
            "landmarks": 0,
            "relations": n_rel,
        }

    @property
    def expected_records(self) -> int:
        return sum(self.counts().values())

    def records(self) -> Iterator[tuple[int, Record]]:
        """(log time, record) in file order; log times at least 1 ns apart (`monotone_log_times_ns`)."""
        g = self.geometry
        clock = MonotoneClock()

        def log_time(t_s: float) -> int:
            return clock(int(round(t_s * 1e9)))

        if self.relations is not None:
            yield int(round(self.first_t_s * 1e9)), RelationsRecord(self.relations)
        for ev in _Parser(self.path, self.skip_bad_lines).events():
            yield log_time(ev.t_s), OdomRecord(ev.t_s, *ev.pose, source="FLASER" if ev.kind == "scan" else "ODOM")
            if ev.kind == "scan":
                ranges = ev.ranges_m
                ranges[ranges >= self.no_return_m] = np.inf
                yield log_time(ev.t_s), ScanRecord(ev.t_s, ranges, g.start_angle_rad, g.end_angle_rad)

    def metadata(self) -> dict[str, dict[str, Any]]:
        return {
            "dataset": {
                "name": self.dataset,
                "source_format": "carmen",
                "source": str(self.path),
                "counts": self.counts(),
            },
            "vehicle": {"motion_model": "odometry", "preset": "odometry"},
            "sensor": {"frame": "laser", **self.geometry.as_dict(), "self_return_range_m": 0.0},
        }

    def load(self) -> LogData:
        """The whole log in memory (`ingest.read_log`)."""
        scan_t, scans, odom, sources = [], [], [], []
        for _, rec in self.records():
            if isinstance(rec, ScanRecord):
                scan_t.append(rec.t_s)
                scans.append(rec.ranges_m)
            elif isinstance(rec, OdomRecord):
                odom.append((rec.t_s, rec.x_m, rec.y_m, rec.theta_rad, rec.tv_mps, rec.rv_radps))
                sources.append(rec.source)
        log = LogData(
            dataset=self.dataset,
            source_format="carmen",
            source=str(self.path),
            motion_model="odometry",
            geometry=self.geometry,
            scan_t_s=np.asarray(scan_t),
            scan_ranges_m=np.vstack(scans),
            odom_pose=np.asarray(odom),
            odom_source=sources,
            warnings=list(self.warnings),
        )
        log.relations = self.relations
        return log


def read_carmen(path: Path, skip_bad_lines: bool = False) -> LogData:
    """A CARMEN log read into memory (`CarmenStream.load`)."""
    return CarmenStream(path, skip_bad_lines).load()
