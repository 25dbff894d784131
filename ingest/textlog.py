"""Validating parser for numeric CSV text logs (the Sydney `*.txt` layout)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


class IngestError(Exception):
    """Bad input: the message names the file and, where there is one, the line."""


MAX_TIME_S = 9.2e9
"""Latest time an MCAP log time holds (unsigned 64-bit nanoseconds, kept below 2^63); times are >= 0."""


def time_problem(t_s: float) -> str | None:
    """Why `t_s` cannot be a log time, or None when it can."""
    if not 0.0 <= t_s <= MAX_TIME_S:
        return f"time {t_s:g} s outside 0 to {MAX_TIME_S:g} s (MCAP log times)"
    return None


MAX_ODOM_POSITION_M = 1e6
"""The largest odometry coordinate taken (1000 km from the odometry's origin): beyond it a pose is a corrupt
value (1e300), not a drive, and its differences would lose the centimetres the filter works in."""
MAX_HEADING_RAD = 1e6
"""The largest odometry heading taken (about 160 000 turns, for odometry that does not wrap its angle)."""
MAX_SPEED_MPS = 1e3
"""The largest odometry speed taken (3600 km/h)."""
MAX_TURN_RATE_RADPS = 1e3
"""The largest odometry turn rate taken (about 160 turns a second)."""
MAX_STEERING_RAD = math.pi / 2
"""The largest steering angle taken: an Ackermann vehicle's wheels turn less than 90 degrees either way (a
larger value is most likely in degrees, or corrupt)."""


def odometry_problem(
    x_m: float = 0.0,
    y_m: float = 0.0,
    theta_rad: float = 0.0,
    speed_mps: float = 0.0,
    turn_rate_radps: float = 0.0,
    steering_rad: float = 0.0,
) -> str | None:
    """Why these odometry values cannot be a vehicle's (non-finite, or an absurd magnitude: see the MAX_
    bounds above), or None when they can. The filter would integrate such a value into every particle's
    pose without complaint, so readers refuse it naming file and line."""
    values = {
        "x": (x_m, MAX_ODOM_POSITION_M, "m"),
        "y": (y_m, MAX_ODOM_POSITION_M, "m"),
        "theta": (theta_rad, MAX_HEADING_RAD, "rad"),
        "speed": (speed_mps, MAX_SPEED_MPS, "m/s"),
        "turn rate": (turn_rate_radps, MAX_TURN_RATE_RADPS, "rad/s"),
        "steering": (steering_rad, MAX_STEERING_RAD, "rad"),
    }
    for name, (v, bound, unit) in values.items():
        if not math.isfinite(v):
            return f"odometry {name} is {v} (not a finite number)"
        if abs(v) > bound:
            return f"odometry {name} {v:g} {unit} is beyond +-{bound:g} {unit} (not a vehicle's odometry)"
    return None


def check_times(path: Path, name: str, t_s: np.ndarray) -> None:
    """Refuse an array of times (a MATLAB variable) with a time no MCAP log time can hold."""
    bad = ~((t_s >= 0) & (t_s <= MAX_TIME_S))
    if bad.any():
        i = int(np.argmax(bad))
        raise IngestError(f"{path}: variable {name!r} index {i}: {time_problem(float(t_s[i]))}")


@dataclass
class Table:
    """Parsed rows, the 1-based source line of each row, and how many lines were dropped."""

    rows: np.ndarray
    line_numbers: np.ndarray
    dropped: int = 0
    drop_reasons: list[str] = field(default_factory=list)


UTF8_BOM = b"\xef\xbb\xbf"
"""The byte order mark some editors (Windows Notepad, Excel's "CSV UTF-8") write at the start of a text file."""

MAX_LINE_BYTES = 1 << 20
"""The longest line a text log may have (1 MiB; a Sydney LASER.txt line of 361 ranges is about 3 kB, a
CARMEN FLASER line of 1 081 beams about 10 kB): a file without line breaks is refused, not read whole."""


def text_lines(
    path: Path, kind: str = "text log", gzip_ok: bool = False, latin1_fallback: bool = False
) -> Iterator[tuple[int, str]]:
    """(line number, text) of a text log read a line at a time, so memory stays flat in its length. Lines
    are numbered as `str.splitlines` splits them (as `Path.read_text().splitlines()` does). `gzip_ok`:
    a gzip file is read through; `latin1_fallback`: a line that is not UTF-8 is read as Latin-1 (else it
    is refused); `kind` names the format in the refusal of an overlong line. A UTF-8 byte order mark at the
    start of the file is dropped: it is not part of the first line (read as text, it would make the first
    line's first field unreadable, and that line, a scan, dropped)."""
    import gzip
    import zlib

    try:
        f = open(path, "rb")
    except FileNotFoundError:
        raise IngestError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise IngestError(f"{path}: a directory, not a text file") from None
    with f:
        packed = gzip_ok and f.read(2) == b"\x1f\x8b"
        f.seek(0)
        stream = gzip.GzipFile(fileobj=f, mode="rb") if packed else f
        offset = lineno = 0
        while True:
            try:
                raw = stream.readline(MAX_LINE_BYTES + 1)
            except (OSError, EOFError, zlib.error) as e:
                raise IngestError(f"{path}: corrupt gzip data ({e})") from None
            if not raw:
                return
            if offset == 0 and raw.startswith(UTF8_BOM):
                raw, offset = raw[len(UTF8_BOM) :], len(UTF8_BOM)
            if len(raw) > MAX_LINE_BYTES:
                raise IngestError(f"{path}:{lineno + 1}: a line longer than {MAX_LINE_BYTES >> 20} MiB: not a {kind}")
            try:
                text = raw.decode("utf-8")
            except UnicodeDecodeError as e:
                if not latin1_fallback:
                    raise IngestError(f"{path}: not a text file ({e.reason} at byte {offset + e.start})") from None
                text = raw.decode("latin-1")
            offset += len(raw)
            for line in text.splitlines():
                lineno += 1
                yield lineno, line


class NumericCsv:
    """A comma-separated numeric log, checked and read a row at a time (`rows()`).

    Every non-empty line must have `columns` finite numbers (when `columns` is None, the first data
    line sets the count), with a time a log time can hold in `time_column` (when given), and passing
    `check(values)` (when given: None, or why the row is bad, e.g. `odometry_problem`). A malformed
    line raises `IngestError("file:line: why")`, or with `skip_bad_lines` is dropped and counted
    (`dropped`, `drop_reasons`). A file with no data line raises `IngestError`. `text` parses a string
    instead of the file.
    """

    def __init__(
        self,
        path: Path,
        columns: int | None,
        skip_bad_lines: bool = False,
        time_column: int | None = None,
        text: str | None = None,
        check: Callable[[list[float]], str | None] | None = None,
    ) -> None:
        self.path, self.columns, self.skip_bad_lines = path, columns, skip_bad_lines
        self.time_column, self.text, self.check = time_column, text, check
        self.dropped = 0
        self.drop_reasons: list[str] = []

    def rows(self) -> Iterator[tuple[int, list[float]]]:
        """(1-based line number, values) of every good data line, in file order."""
        path, columns = self.path, self.columns
        self.dropped, self.drop_reasons = 0, []
        if self.text is None:
            lines = text_lines(path)
        else:
            lines = enumerate(self.text.removeprefix("\ufeff").splitlines(), start=1)
        found = False
        for lineno, raw in lines:
            line = raw.strip()
            if not line or line.startswith("#"):
                continue
            parts = line.split(",")
            why = None
            if columns is not None and len(parts) != columns:
                why = f"expected {columns} comma-separated columns, found {len(parts)}"
            else:
                try:
                    values = [float(p) for p in parts]
                except ValueError:
                    bad = next(p for p in parts if not _is_float(p))
                    why = f"not a number: {bad.strip()[:30]!r}"
                else:
                    if not all(math.isfinite(v) for v in values):
                        why = "non-finite value (NaN or infinity)"
                    else:
                        if self.time_column is not None:
                            why = time_problem(values[self.time_column])
                        if why is None and self.check is not None:
                            why = self.check(values)
            if why is not None:
                if not self.skip_bad_lines:
                    raise IngestError(f"{path}:{lineno}: {why}")
                self.dropped += 1
                if len(self.drop_reasons) < 5:
                    self.drop_reasons.append(f"{path}:{lineno}: {why}")
                continue
            if columns is None:
                columns = self.columns = len(values)
            found = True
            yield lineno, values
        if not found:
            raise IngestError(f"{path}: no data lines (empty log)")


def parse_numeric_csv(
    path: Path,
    columns: int | None,
    skip_bad_lines: bool = False,
    text: str | None = None,
    time_column: int | None = None,
) -> Table:
    """A comma-separated numeric log read whole into a `Table` (the checks of `NumericCsv`)."""
    csv = NumericCsv(path, columns, skip_bad_lines, time_column, text)
    rows: list[list[float]] = []
    lines: list[int] = []
    for lineno, values in csv.rows():
        rows.append(values)
        lines.append(lineno)
    return Table(np.asarray(rows, dtype=float), np.asarray(lines), csv.dropped, csv.drop_reasons)


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


class MonotoneClock:
    """`monotone_log_times_ns` one time at a time, for logs streamed: each log time at least 1 ns after
    the one before (`clock(ns)` returns the time to write)."""

    def __init__(self) -> None:
        self.last_ns: int | None = None

    def __call__(self, ns: int) -> int:
        self.last_ns = ns if self.last_ns is None or ns > self.last_ns else self.last_ns + 1
        return self.last_ns


def monotone_log_times_ns(t_s: np.ndarray) -> tuple[np.ndarray, int]:
    """MCAP log times [ns] that keep file order: each at least 1 ns after the one before.

    Returns the int64 log times and how many samples had a time that did not increase (their
    original time stays in the message itself).
    """
    t_ns = np.round(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)
    if len(t_ns) < 2:
        return t_ns, 0
    backwards = int(np.sum(np.diff(t_ns) <= 0))
    i = np.arange(len(t_ns), dtype=np.int64)
    return np.maximum.accumulate(t_ns - i) + i, backwards
