"""Validating parser for numeric CSV text logs (the Sydney `*.txt` layout)."""

from __future__ import annotations

import math
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


def parse_numeric_csv(
    path: Path,
    columns: int | None,
    skip_bad_lines: bool = False,
    text: str | None = None,
    time_column: int | None = None,
) -> Table:
    """Parse a comma-separated numeric log.

    Every non-empty line must have `columns` finite numbers (when `columns` is None, the first data
    line sets the count), with a time a log time can hold in `time_column` (when given). A malformed
    line raises `IngestError("file:line: why")`, or with `skip_bad_lines` is dropped and counted. A
    file with no data line raises `IngestError`.
    """
    if text is None:
        try:
            text = Path(path).read_text()
        except FileNotFoundError:
            raise IngestError(f"{path}: file not found") from None
        except UnicodeDecodeError as e:
            raise IngestError(f"{path}: not a text file ({e.reason} at byte {e.start})") from None
    rows: list[list[float]] = []
    lines: list[int] = []
    dropped = 0
    reasons: list[str] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
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
                elif time_column is not None:
                    why = time_problem(values[time_column])
        if why is not None:
            if not skip_bad_lines:
                raise IngestError(f"{path}:{lineno}: {why}")
            dropped += 1
            if len(reasons) < 5:
                reasons.append(f"{path}:{lineno}: {why}")
            continue
        if columns is None:
            columns = len(values)
        rows.append(values)
        lines.append(lineno)
    if not rows:
        raise IngestError(f"{path}: no data lines (empty log)")
    return Table(np.asarray(rows, dtype=float), np.asarray(lines), dropped, reasons)


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


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
