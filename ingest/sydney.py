"""Readers for the ACFR (University of Sydney) logs: Car Park and Victoria Park, text and MATLAB forms.

Laser: 361 beams, beam k at k * 0.5 deg with 0 deg = vehicle right, 90 deg = ahead; in the vehicle
frame (x ahead, y left) that is bearing -90 deg + k * 0.5 deg. Ranges at or beyond 80 m carry no return
(the logs write 81.87 to 81.91 m there; Victoria Park's raw file >= 8000 cm) and become +inf.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .base import ReadOptions
from .logdata import LogData, ScanGeometry
from .textlog import IngestError, Table, check_times, parse_numeric_csv

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

    def open(self, source: Path, fmt: str, options: ReadOptions) -> LogData:
        directory = source if source.is_dir() else source.parent
        if fmt == "sydney-text" and not (directory / "DRS.txt").exists() and (directory / "text").is_dir():
            directory = directory / "text"
        if source.is_file():
            _check_sydney_file(source, directory, fmt)
        reader = read_sydney_text if fmt == "sydney-text" else read_sydney_mat
        return reader(directory, options.skip_bad_lines)


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


def _ranges(table: Table, path: Path, skip_bad_lines: bool, warnings: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Check ranges (no negatives) and map no-return values to +inf. Returns (kept rows mask, ranges)."""
    ranges = table.rows[:, 1:]
    negative = (ranges < 0).any(axis=1)
    if negative.any():
        first = int(np.argmax(negative))
        if not skip_bad_lines:
            beam = int(np.argmax(ranges[first] < 0))
            raise IngestError(
                f"{path}:{table.line_numbers[first]}: negative range {ranges[first, beam]} m at beam {beam}"
            )
        warnings.append(f"{path}: dropped {int(negative.sum())} scans with negative ranges")
    keep = ~negative
    out = ranges[keep].copy()
    out[out >= NO_RETURN_M] = np.inf
    return keep, out


def _check_times(name: str, t: np.ndarray, warnings: list[str]) -> None:
    back = int(np.sum(np.diff(t) < 0))
    if back:
        warnings.append(f"{name}: {back} timestamps go backwards; file order kept")


def _report_dropped(table: Table, path: Path, warnings: list[str]) -> None:
    if table.dropped:
        warnings.append(f"{path}: skipped {table.dropped} malformed lines (first: {table.drop_reasons[0]})")


def read_sydney_text(directory: Path, skip_bad_lines: bool = False) -> LogData:
    """DRS.txt (t,speed,steering), GPS.txt (t,x,y), LASER.txt (t + 361 ranges), optional
    INTENSITY.txt (t + 361 codes) and BEACONS.txt (x,y)."""
    directory = Path(directory)
    warnings: list[str] = []
    drs_path = directory / "DRS.txt"
    if not drs_path.exists():
        raise IngestError(f"{drs_path}: file not found (a Sydney text log needs DRS.txt)")
    drs = parse_numeric_csv(drs_path, 3, skip_bad_lines, time_column=0)
    _report_dropped(drs, drs_path, warnings)
    _check_times(str(drs_path), drs.rows[:, 0], warnings)
    log = LogData(
        dataset=_dataset_name(directory),
        source_format="sydney-text",
        source=str(directory),
        motion_model="ackermann",
        vehicle_preset="carpark",
        ackermann=drs.rows,
    )
    gps_path = directory / "GPS.txt"
    if gps_path.exists():
        gps = parse_numeric_csv(gps_path, 3, skip_bad_lines, time_column=0)
        _report_dropped(gps, gps_path, warnings)
        _check_times(str(gps_path), gps.rows[:, 0], warnings)
        log.gps = gps.rows
    else:
        warnings.append(f"{gps_path}: not present; no GPS channel")
    laser_path = directory / "LASER.txt"
    if laser_path.exists():
        laser = parse_numeric_csv(laser_path, 1 + SYDNEY_BEAMS, skip_bad_lines, time_column=0)
        _report_dropped(laser, laser_path, warnings)
        keep, ranges = _ranges(laser, laser_path, skip_bad_lines, warnings)
        log.geometry = SYDNEY_GEOMETRY
        log.self_return_range_m = SELF_RETURN_RANGE_M
        log.scan_t_s = laser.rows[keep, 0]
        log.scan_ranges_m = ranges
        _check_times(str(laser_path), log.scan_t_s, warnings)
        intensity_path = directory / "INTENSITY.txt"
        if intensity_path.exists():
            inten = parse_numeric_csv(intensity_path, 1 + SYDNEY_BEAMS, skip_bad_lines, time_column=0)
            _report_dropped(inten, intensity_path, warnings)
            by_time = dict(zip(inten.rows[:, 0].tolist(), range(len(inten.rows)), strict=True))
            idx = [by_time.get(t) for t in log.scan_t_s.tolist()]
            if any(i is None for i in idx):
                missing = sum(i is None for i in idx)
                warnings.append(f"{intensity_path}: {missing} scans have no intensity line; intensities left out")
            else:
                log.scan_intensities = inten.rows[idx, 1:]
    else:
        warnings.append(f"{laser_path}: not present; this log has odometry and GPS only, no laser")
    beacons_path = directory / "BEACONS.txt"
    if beacons_path.exists():
        log.landmarks = parse_numeric_csv(beacons_path, 2, skip_bad_lines).rows
    truth_path = directory / "TRUTH.txt"  # simulated logs: t, x, y, phi of the laser
    if truth_path.exists():
        log.truth_pose = parse_numeric_csv(truth_path, 4, skip_bad_lines, time_column=0).rows
    log.warnings = warnings
    return log


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
