"""Readers for the ACFR (University of Sydney) logs: Car Park and Victoria Park, text and MATLAB forms.

Laser: 361 beams, beam k at k * 0.5 deg with 0 deg = vehicle right, 90 deg = ahead; in the vehicle
frame (x ahead, y left) that is bearing -90 deg + k * 0.5 deg. Ranges at or beyond 80 m carry no return
(the logs write 81.87 to 81.91 m there; Victoria Park's raw file >= 8000 cm) and become +inf.
"""

from __future__ import annotations

import heapq
import math
from array import array
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gslam.vehicle import vehicle_preset

from .base import AckermannRecord, GpsRecord, LandmarksRecord, ReadOptions, Record, ScanRecord, TruthPoseRecord
from .logdata import _PRIORITY, LogData, ScanGeometry
from .textlog import (
    MAX_SPEED_MPS,
    MAX_STEERING_RAD,
    IngestError,
    MonotoneClock,
    NumericCsv,
    check_times,
    odometry_problem,
    parse_numeric_csv,
)

SYDNEY_BEAMS = 361
SYDNEY_GEOMETRY = ScanGeometry(
    beam_count=SYDNEY_BEAMS, start_angle_rad=-math.pi / 2, angle_increment_rad=math.pi / 360, max_range_m=80.0
)
NO_RETURN_M = 80.0
SELF_RETURN_RANGE_M = 1.0
"""The ACFR car's laser sees the car itself: beams 0-7 read 0.84-0.92 m in every Car Park scan."""

CARPARK_MAT = "data_set.mat"
CARPARK_BEACONS_MAT = "beac_juan3.mat"
VICTORIA_DR_MAT = "aa3_dr.mat"
VICTORIA_GPS_MAT = "aa3_gpsx.mat"
VICTORIA_LASER_MAT = "aa3_lsr2.mat"


class SydneyReader:
    """The ACFR logs: a directory (or a file in it) with DRS.txt (text) or the .mat files."""

    formats = ("sydney-text", "sydney-mat")

    def detect(self, source: Path) -> str | None:
        if source.is_file():
            name = source.name.lower()
            return "sydney-mat" if name.endswith(".mat") else "sydney-text" if name.endswith(".txt") else None
        names = {p.name for p in source.iterdir()}
        if CARPARK_MAT in names or VICTORIA_DR_MAT in names:
            return "sydney-mat"
        if "DRS.txt" in names or (source / "text" / "DRS.txt").exists():
            return "sydney-text"
        return None

    def open(self, source: Path, fmt: str, options: ReadOptions) -> SydneyTextStream | LogData:
        directory = source if source.is_dir() else source.parent
        if fmt == "sydney-text" and not (directory / "DRS.txt").exists() and (directory / "text").is_dir():
            directory = directory / "text"
        if source.is_file():
            _check_sydney_file(source, directory, fmt)
        if fmt == "sydney-text":
            return SydneyTextStream(directory, options.skip_bad_lines)
        return read_sydney_mat(directory, options.skip_bad_lines)


def _check_sydney_file(source: Path, directory: Path, fmt: str) -> None:
    """A Sydney log is a directory; a file given instead must be one of the log's own files."""
    if fmt == "sydney-text" and not (directory / "DRS.txt").exists():
        raise IngestError(
            f"{source}: a Sydney text log is a directory holding DRS.txt (with LASER.txt, GPS.txt), and "
            f"{directory} has no DRS.txt; give the log's directory (or --format for another format)"
        )
    if fmt == "sydney-mat" and not ((directory / CARPARK_MAT).exists() or (directory / VICTORIA_DR_MAT).exists()):
        raise IngestError(
            f"{source}: not a known Sydney MATLAB log (expected {CARPARK_MAT}, or {VICTORIA_DR_MAT} with "
            f"{source.name} beside it); give the log's directory (or --format for another format)"
        )


def _dataset_name(directory: Path) -> str:
    d = directory.resolve()
    return d.parent.name if d.name in ("text", "txt", "mat") else d.name


def _check_times(name: str, t: np.ndarray, warnings: list[str]) -> None:
    back = int(np.sum(np.diff(t) < 0))
    if back:
        warnings.append(f"{name}: {back} timestamps go backwards; file order kept")


def _report_dropped(csv: NumericCsv, path: Path, warnings: list[str]) -> None:
    if csv.dropped:
        warnings.append(f"{path}: skipped {csv.dropped} malformed lines (first: {csv.drop_reasons[0]})")


@dataclass
class _Pass:
    """What the first pass over one file found: its good rows' count, first time and backward steps."""

    path: Path
    csv: NumericCsv
    rows: int = 0
    first_t_s: float = math.nan
    backwards: int = 0


def _drs_problem(values: list[float]) -> str | None:
    """Why a DRS.txt row (t, speed, steering) is not a vehicle's odometry (`odometry_problem`), else None."""
    return odometry_problem(speed_mps=values[1], steering_rad=values[2])


def _first_pass(
    path: Path,
    columns: int,
    skip_bad_lines: bool,
    row_check: Callable[[int, list[float]], bool] | None = None,
    check: Callable[[list[float]], str | None] | None = None,
) -> _Pass:
    """Check every line of one file (`check(values)`, as `NumericCsv`'s, refuses a row as malformed;
    `row_check(lineno, values)` may drop a row by returning False)."""
    found = _Pass(path, NumericCsv(path, columns, skip_bad_lines, time_column=0, check=check))
    last = math.nan
    for lineno, values in found.csv.rows():
        if row_check is not None and not row_check(lineno, values):
            continue
        t = values[0]
        if found.rows == 0:
            found.first_t_s = t
        elif t < last:
            found.backwards += 1
        last = t
        found.rows += 1
    return found


def _log_times(rows: Iterator[tuple[int, list[float]]], priority: int, make) -> Iterator[tuple[int, int, int, object]]:
    """(log time ns, priority, index, record) of one stream; log times keep file order, each at least
    1 ns after the one before (`monotone_log_times_ns`, computed as the rows come)."""
    clock = MonotoneClock()
    for i, (_, values) in enumerate(rows):
        yield clock(int(round(values[0] * 1e9))), priority, i, make(values)


class SydneyTextStream:
    """A Sydney text log (DRS.txt speed and steering, GPS.txt, LASER.txt ranges, optional INTENSITY.txt,
    BEACONS.txt, TRUTH.txt) streamed into the MCAP writer (a `LogStream`) in two passes, so memory stays
    flat in the log's length: the first checks every line of every file and finds the counts, the first
    times and which intensity line goes with each scan; the second merges the files by time (odometry
    before GPS before the scan at equal times, as `LogData` orders them) and yields the records.

    Held in memory: the pole list, and one time per scan and per intensity line (16 bytes a scan) to pair
    them."""

    source_format = "sydney-text"

    def __init__(self, directory: Path, skip_bad_lines: bool = False) -> None:
        directory = self.directory = Path(directory)
        self.skip_bad_lines = skip_bad_lines
        self.dataset = _dataset_name(directory)
        warnings: list[str] = []
        self.warnings = warnings
        drs_path = directory / "DRS.txt"
        if not drs_path.exists():
            raise IngestError(f"{drs_path}: file not found (a Sydney text log needs DRS.txt)")
        self.drs = _first_pass(drs_path, 3, skip_bad_lines, check=_drs_problem)
        self._report(self.drs)
        gps_path = directory / "GPS.txt"
        self.gps: _Pass | None = None
        if gps_path.exists():
            self.gps = _first_pass(gps_path, 3, skip_bad_lines)
            self._report(self.gps)
        else:
            warnings.append(f"{gps_path}: not present; no GPS channel")
        self.laser: _Pass | None = None
        self.negative = 0
        self.intensity_rows: np.ndarray | None = None  # per scan: its row among INTENSITY.txt's good rows
        laser_path = directory / "LASER.txt"
        if laser_path.exists():
            scan_t = array("d")

            def keep_scan(lineno: int, values: list[float]) -> bool:
                ranges = values[1:]
                if min(ranges) < 0:
                    if not skip_bad_lines:
                        beam = next(k for k, r in enumerate(ranges) if r < 0)
                        raise IngestError(f"{laser_path}:{lineno}: negative range {ranges[beam]} m at beam {beam}")
                    self.negative += 1
                    return False
                scan_t.append(values[0])
                return True

            self.laser = _first_pass(laser_path, 1 + SYDNEY_BEAMS, skip_bad_lines, keep_scan)
            _report_dropped(self.laser.csv, laser_path, warnings)
            if self.negative:
                warnings.append(f"{laser_path}: dropped {self.negative} scans with negative ranges")
            if self.laser.backwards:
                warnings.append(f"{laser_path}: {self.laser.backwards} timestamps go backwards; file order kept")
            intensity_path = directory / "INTENSITY.txt"
            if intensity_path.exists():
                self.intensity_rows = self._pair_intensities(intensity_path, np.frombuffer(scan_t))
        else:
            warnings.append(f"{laser_path}: not present; this log has odometry and GPS only, no laser")
        beacons_path = directory / "BEACONS.txt"
        self.landmarks = parse_numeric_csv(beacons_path, 2, skip_bad_lines).rows if beacons_path.exists() else None
        truth_path = directory / "TRUTH.txt"  # simulated logs: t, x, y, phi of the laser
        self.truth = _first_pass(truth_path, 4, skip_bad_lines) if truth_path.exists() else None

    def _report(self, found: _Pass) -> None:
        _report_dropped(found.csv, found.path, self.warnings)
        if found.backwards:
            self.warnings.append(f"{found.path}: {found.backwards} timestamps go backwards; file order kept")

    def _pair_intensities(self, path: Path, scan_t: np.ndarray) -> np.ndarray | None:
        """Each scan's intensity line, found by its time (the last line with that time); None, with a
        warning, when a scan has none."""
        csv = NumericCsv(path, 1 + SYDNEY_BEAMS, self.skip_bad_lines, time_column=0)
        by_time = {values[0]: i for i, (_, values) in enumerate(csv.rows())}
        _report_dropped(csv, path, self.warnings)
        rows = [by_time.get(t) for t in scan_t.tolist()]
        missing = sum(i is None for i in rows)
        if missing:
            self.warnings.append(f"{path}: {missing} scans have no intensity line; intensities left out")
            return None
        return np.asarray(rows, dtype=np.int64)

    # -- LogStream ---------------------------------------------------------------------------------
    def counts(self) -> dict[str, int]:
        return {
            "scans": 0 if self.laser is None else self.laser.rows,
            "ackermann": self.drs.rows,
            "odom_pose": 0,
            "gps": 0 if self.gps is None else self.gps.rows,
            "landmarks": 0 if self.landmarks is None else len(self.landmarks),
            "relations": 0,
        }

    @property
    def expected_records(self) -> int:
        return sum(self.counts().values()) + (0 if self.truth is None else self.truth.rows)

    def metadata(self) -> dict[str, dict[str, Any]]:
        preset = vehicle_preset("carpark")
        meta: dict[str, dict[str, Any]] = {
            "dataset": {
                "name": self.dataset,
                "source_format": self.source_format,
                "source": str(self.directory),
                "counts": self.counts(),
            },
            "vehicle": {"motion_model": "ackermann", "preset": preset.name, **preset.as_dict()},
        }
        if self.laser is not None:
            meta["sensor"] = {"frame": "laser", **SYDNEY_GEOMETRY.as_dict(), "self_return_range_m": SELF_RETURN_RANGE_M}
        return meta

    def _rows(self, found: _Pass) -> Iterator[tuple[int, list[float]]]:
        """The good rows of a file the first pass checked (with the same checks, so the same rows)."""
        return NumericCsv(
            found.path, found.csv.columns, self.skip_bad_lines, time_column=0, check=found.csv.check
        ).rows()

    def _scans(self) -> Iterator[tuple[int, list[float]]]:
        """LASER.txt's kept rows (no negative range)."""
        return ((lineno, v) for lineno, v in self._rows(self.laser) if min(v[1:]) >= 0)

    def _intensities(self) -> Iterator[np.ndarray]:
        """Each scan's intensity codes, in scan order: INTENSITY.txt read alongside when its lines come in
        scan order (the logs' case), else its good rows read whole."""
        path = self.directory / "INTENSITY.txt"
        csv = NumericCsv(path, 1 + SYDNEY_BEAMS, self.skip_bad_lines, time_column=0)
        wanted = self.intensity_rows
        if len(wanted) and (np.diff(wanted) < 0).any():
            table = np.asarray([v for _, v in csv.rows()], dtype=float)
            for i in wanted.tolist():
                yield table[i, 1:]
            return
        rows = csv.rows()
        at, row = -1, None
        for i in wanted.tolist():
            while at < i:
                _, row = next(rows)
                at += 1
            yield np.asarray(row[1:], dtype=float)

    def records(self) -> Iterator[tuple[int, Record]]:
        """(log time, record): the poles first, then the three streams merged by time (ties: odometry, GPS,
        scan), then the simulated truth; log times at least 1 ns apart."""
        streams = [_log_times(self._rows(self.drs), _PRIORITY["ackermann"], lambda v: AckermannRecord(*v))]
        firsts = [self.drs.first_t_s]
        if self.gps is not None:
            streams.append(_log_times(self._rows(self.gps), _PRIORITY["gps"], lambda v: GpsRecord(*v)))
            firsts.append(self.gps.first_t_s)
        if self.laser is not None and self.laser.rows:
            g = SYDNEY_GEOMETRY
            intensities = None if self.intensity_rows is None else self._intensities()

            def scan(values: list[float]) -> ScanRecord:
                ranges = np.asarray(values[1:], dtype=float)
                ranges[ranges >= NO_RETURN_M] = np.inf
                inten = None if intensities is None else next(intensities)
                return ScanRecord(float(values[0]), ranges, g.start_angle_rad, g.end_angle_rad, inten)

            streams.append(_log_times(self._scans(), _PRIORITY["scan"], scan))
            firsts.append(self.laser.first_t_s)
        if self.landmarks is not None:
            yield min(int(round(t * 1e9)) for t in firsts), LandmarksRecord(self.landmarks)
        clock = MonotoneClock()  # ties between streams keep the order above
        for ns, _, _, record in heapq.merge(*streams, key=lambda e: e[:3]):
            yield clock(ns), record
        if self.truth is not None:
            # Written after the stream: MCAP indexes keep log-time order for readers.
            for ns, _, _, record in _log_times(self._rows(self.truth), 0, lambda v: TruthPoseRecord(*v)):
                yield ns, record

    def load(self) -> LogData:
        """The whole log in memory (`ingest.read_log`)."""
        scan_t, scans, inten, ack, gps, truth = [], [], [], [], [], []
        for _, rec in self.records():
            if isinstance(rec, ScanRecord):
                scan_t.append(rec.t_s)
                scans.append(rec.ranges_m)
                if rec.intensities is not None:
                    inten.append(rec.intensities)
            elif isinstance(rec, AckermannRecord):
                ack.append((rec.t_s, rec.speed_mps, rec.steering_rad))
            elif isinstance(rec, GpsRecord):
                gps.append((rec.t_s, rec.x_m, rec.y_m))
            elif isinstance(rec, TruthPoseRecord):
                truth.append((rec.t_s, rec.x_m, rec.y_m, rec.theta_rad))
        log = LogData(
            dataset=self.dataset,
            source_format=self.source_format,
            source=str(self.directory),
            motion_model="ackermann",
            vehicle_preset="carpark",
            ackermann=np.asarray(ack, dtype=float).reshape(-1, 3),
            warnings=list(self.warnings),
        )
        if self.gps is not None:
            log.gps = np.asarray(gps, dtype=float).reshape(-1, 3)
        if self.laser is not None:
            log.geometry = SYDNEY_GEOMETRY
            log.self_return_range_m = SELF_RETURN_RANGE_M
            log.scan_t_s = np.asarray(scan_t, dtype=float)
            log.scan_ranges_m = np.vstack(scans) if scans else np.zeros((0, SYDNEY_BEAMS))
            if self.intensity_rows is not None:
                log.scan_intensities = np.vstack(inten) if inten else np.zeros((0, SYDNEY_BEAMS))
        log.landmarks = self.landmarks
        if self.truth is not None:
            log.truth_pose = np.asarray(truth, dtype=float).reshape(-1, 4)
        return log


def read_sydney_text(directory: Path, skip_bad_lines: bool = False) -> LogData:
    """A Sydney text log read into memory (`SydneyTextStream.load`)."""
    return SydneyTextStream(directory, skip_bad_lines).load()


def _loadmat_here(path: Path) -> dict:
    from scipy.io import loadmat

    try:
        return loadmat(path)
    except FileNotFoundError:
        raise IngestError(f"{path}: file not found") from None
    except Exception as e:  # scipy raises several types for corrupt files
        raise IngestError(f"{path}: not a readable MATLAB file ({e})") from None


def _loadmat_child(path: Path, conn) -> None:
    import faulthandler

    faulthandler.disable()  # a crash here is reported by the parent, in one line
    try:
        conn.send((True, _loadmat_here(path)))
    except IngestError as e:
        conn.send((False, str(e)))
    conn.close()


def _loadmat(path: Path) -> dict:
    """The variables of a MATLAB file, read in a forked child: scipy's reader can crash the process
    (segmentation fault) on some damaged files, and a crash must be one line, not the end of gslam."""
    import multiprocessing

    if "fork" not in multiprocessing.get_all_start_methods():
        return _loadmat_here(path)
    ctx = multiprocessing.get_context("fork")
    receive, send = ctx.Pipe(duplex=False)
    child = ctx.Process(target=_loadmat_child, args=(path, send), daemon=True)
    child.start()
    send.close()
    try:
        ok, payload = receive.recv()
    except EOFError:  # the child died without an answer
        child.join()
        raise IngestError(
            f"{path}: not a readable MATLAB file (the MATLAB reader crashed on it, exit {child.exitcode})"
        ) from None
    finally:
        receive.close()
    child.join()
    if not ok:
        raise IngestError(payload)
    return payload


def _var(mat: dict, path: Path, name: str) -> np.ndarray:
    """A numeric variable of a MATLAB file; missing or not numbers: one line naming file and variable."""
    if name not in mat:
        raise IngestError(f"{path}: variable {name!r} missing")
    a = np.asarray(mat[name])
    if a.dtype.kind not in "biuf":
        raise IngestError(f"{path}: variable {name!r} holds {a.dtype} values, expected numbers")
    return a


def _columns(path: Path, **named: np.ndarray) -> np.ndarray:
    """Equal-length vectors side by side (K, n) as floats; unequal lengths name the variables."""
    vectors = {k: v.ravel().astype(float) for k, v in named.items()}
    lengths = {k: len(v) for k, v in vectors.items()}
    if len(set(lengths.values())) > 1:
        listed = ", ".join(f"{k} {n}" for k, n in lengths.items())
        raise IngestError(f"{path}: variables of one stream differ in length ({listed})")
    return np.column_stack(list(vectors.values()))


def _finite(path: Path, name: str, a: np.ndarray) -> np.ndarray:
    bad = ~np.isfinite(a)
    if bad.any():
        raise IngestError(
            f"{path}: variable {name!r} has {int(bad.sum())} non-finite values "
            f"(first at index {int(np.argmax(bad.ravel()))})"
        )
    return a


def _check_odometry(path: Path, names: tuple[str, str], ack: np.ndarray) -> None:
    """Refuse speed and steering (columns 1 and 2 of `ack`, MATLAB variables `names`) that are not a
    vehicle's (`odometry_problem`), naming the variable and the first bad index."""
    with np.errstate(invalid="ignore"):
        bad = ~(np.abs(ack[:, 1]) <= MAX_SPEED_MPS) | ~(np.abs(ack[:, 2]) <= MAX_STEERING_RAD)
    if not bad.any():
        return
    i = int(np.argmax(bad))
    speed, steering = float(ack[i, 1]), float(ack[i, 2])
    for name, why in (
        (names[0], odometry_problem(speed_mps=speed)),
        (names[1], odometry_problem(steering_rad=steering)),
    ):
        if why is not None:
            raise IngestError(f"{path}: variable {name!r} index {i}: {why}")


def read_sydney_mat(directory: Path, skip_bad_lines: bool = False) -> LogData:
    """Car Park `data_set.mat` (+ `beac_juan3.mat`), or Victoria Park `aa3_dr.mat`, `aa3_gpsx.mat` and,
    when present, `aa3_lsr2.mat`."""
    directory = Path(directory)
    if (directory / CARPARK_MAT).exists():
        return _read_carpark_mat(directory)
    if (directory / VICTORIA_DR_MAT).exists():
        return _read_victoria_mat(directory, skip_bad_lines)
    raise IngestError(f"{directory}: no {CARPARK_MAT} or {VICTORIA_DR_MAT} found")


def _read_carpark_mat(directory: Path) -> LogData:
    path = directory / CARPARK_MAT
    m = _loadmat(path)
    warnings: list[str] = []
    ack = _columns(
        path, Time_VS=_var(m, path, "Time_VS"), Velocity=_var(m, path, "Velocity"), Steering=_var(m, path, "Steering")
    )
    _finite(path, "Time_VS/Velocity/Steering", ack)
    _check_odometry(path, ("Velocity", "Steering"), ack)
    t_vs = ack[:, 0]
    gps = _columns(
        path, TimeGPS=_var(m, path, "TimeGPS"), GPSLon=_var(m, path, "GPSLon"), GPSLat=_var(m, path, "GPSLat")
    )
    _finite(path, "TimeGPS/GPSLon/GPSLat", gps)
    laser = _finite(path, "Laser", _var(m, path, "Laser").astype(float))
    if laser.ndim != 2 or laser.shape[1] != SYDNEY_BEAMS:
        raise IngestError(f"{path}: 'Laser' has shape {laser.shape}, expected (K, {SYDNEY_BEAMS})")
    if (laser < 0).any():
        k = int(np.argmax((laser < 0).any(axis=1)))
        raise IngestError(f"{path}: 'Laser' scan {k} has a negative range")
    ranges = laser.copy()
    ranges[ranges >= NO_RETURN_M] = np.inf
    t_laser = _var(m, path, "TimeLaser").ravel().astype(float)
    if len(t_laser) != len(laser):
        raise IngestError(f"{path}: {len(t_laser)} laser times for {len(laser)} scans")
    for name, t in (("Time_VS", t_vs), ("TimeGPS", gps[:, 0]), ("TimeLaser", t_laser)):
        check_times(path, name, t)
        _check_times(f"{path}:{name}", t, warnings)
    log = LogData(
        dataset=_dataset_name(directory),
        source_format="sydney-mat",
        source=str(directory),
        motion_model="ackermann",
        vehicle_preset="carpark",
        geometry=SYDNEY_GEOMETRY,
        self_return_range_m=SELF_RETURN_RANGE_M,
        scan_t_s=t_laser,
        scan_ranges_m=ranges,
        ackermann=ack,
        gps=gps,
        warnings=warnings,
    )
    if "Intensity" in m:
        log.scan_intensities = np.asarray(m["Intensity"], dtype=float)
    beac = directory / CARPARK_BEACONS_MAT
    if beac.exists():
        log.landmarks = _var(_loadmat(beac), beac, "estbeac").astype(float).reshape(-1, 2)
    return log


def _read_victoria_mat(directory: Path, skip_bad_lines: bool) -> LogData:
    warnings: list[str] = []
    dr_path = directory / VICTORIA_DR_MAT
    dr = _loadmat(dr_path)
    ack = _columns(
        dr_path,
        time=_var(dr, dr_path, "time"),
        speed=_var(dr, dr_path, "speed"),
        steering=_var(dr, dr_path, "steering"),
    )
    ack[:, 0] /= 1000.0
    check_times(dr_path, "time", ack[:, 0])
    _finite(dr_path, "time/speed/steering", ack)
    _check_odometry(dr_path, ("speed", "steering"), ack)
    _check_times(str(dr_path), ack[:, 0], warnings)
    log = LogData(
        dataset=_dataset_name(directory),
        source_format="sydney-mat",
        source=str(directory),
        motion_model="ackermann",
        vehicle_preset="carpark",
        ackermann=ack,
        warnings=warnings,
    )
    gps_path = directory / VICTORIA_GPS_MAT
    if gps_path.exists():
        g = _loadmat(gps_path)
        log.gps = _columns(
            gps_path,
            timeGps=_var(g, gps_path, "timeGps"),
            Lo_m=_var(g, gps_path, "Lo_m"),
            La_m=_var(g, gps_path, "La_m"),
        )
        log.gps[:, 0] /= 1000.0
        check_times(gps_path, "timeGps", log.gps[:, 0])
        _finite(gps_path, "timeGps/Lo_m/La_m", log.gps)
    laser_path = directory / VICTORIA_LASER_MAT
    if laser_path.exists():
        lm = _loadmat(laser_path)
        raw = _var(lm, laser_path, "LASER").astype(np.uint16)
        if raw.ndim != 2 or raw.shape[1] != SYDNEY_BEAMS:
            raise IngestError(f"{laser_path}: 'LASER' has shape {raw.shape}, expected (K, {SYDNEY_BEAMS})")
        cm = (raw & 0x1FFF).astype(float)
        ranges = cm / 100.0
        ranges[cm >= NO_RETURN_M * 100] = np.inf
        log.geometry = SYDNEY_GEOMETRY
        log.self_return_range_m = SELF_RETURN_RANGE_M
        log.scan_t_s = _var(lm, laser_path, "TLsr").ravel().astype(float) / 1000.0
        check_times(laser_path, "TLsr", log.scan_t_s)
        if len(log.scan_t_s) != len(raw):
            raise IngestError(f"{laser_path}: {len(log.scan_t_s)} laser times for {len(raw)} scans")
        log.scan_ranges_m = ranges
        log.scan_intensities = (raw >> 13).astype(float)
    else:
        warnings.append(f"{laser_path}: not present; this log has odometry and GPS only, no laser")
    return log
