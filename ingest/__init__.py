"""Ingest: outside log formats (Sydney text and MATLAB logs, CARMEN logs) to MCAP."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .carmen import read_carmen
from .logdata import LogData, ScanGeometry
from .sydney import CARPARK_MAT, VICTORIA_DR_MAT, read_sydney_mat, read_sydney_text
from .textlog import IngestError

FORMATS = ("auto", "sydney-text", "sydney-mat", "carmen")

__all__ = ["FORMATS", "IngestError", "IngestReport", "LogData", "ScanGeometry", "detect_format", "ingest", "read_log"]


def detect_format(source: Path) -> str:
    """The format of `source` (a directory or a file), from the names it holds."""
    source = Path(source)
    if not source.exists():
        raise IngestError(f"{source}: no such file or directory")
    if source.is_file():
        name = source.name.lower()
        if name.endswith((".clf", ".log", ".clf.gz", ".log.gz", ".gz")):
            return "carmen"
        if name.endswith(".mat"):
            return "sydney-mat"
        if name.endswith(".txt"):
            return "sydney-text"
        raise IngestError(f"{source}: cannot tell the format from the name (use --format)")
    names = {p.name for p in source.iterdir()}
    if CARPARK_MAT in names or VICTORIA_DR_MAT in names:
        return "sydney-mat"
    if "DRS.txt" in names:
        return "sydney-text"
    if "text" in names and (source / "text" / "DRS.txt").exists():
        return "sydney-text"
    logs = [n for n in names if n.endswith((".clf", ".clf.gz", ".log", ".log.gz"))]
    if len(logs) == 1:
        return "carmen"
    raise IngestError(
        f"{source}: no known log found (expected DRS.txt, {CARPARK_MAT}, {VICTORIA_DR_MAT} or one CARMEN .clf/.log)"
    )


def read_log(source: Path, fmt: str = "auto", dataset: str | None = None, skip_bad_lines: bool = False) -> LogData:
    """Read a log into memory (`LogData`), detecting the format when `fmt` is "auto"."""
    source = Path(source)
    if fmt not in FORMATS:
        raise IngestError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    if fmt == "auto":
        fmt = detect_format(source)
    if fmt == "carmen":
        if source.is_dir():
            logs = sorted(p for p in source.iterdir() if p.name.endswith((".clf", ".clf.gz", ".log", ".log.gz")))
            if len(logs) != 1:
                raise IngestError(f"{source}: expected one CARMEN log in the directory, found {len(logs)}")
            source = logs[0]
        log = read_carmen(source, skip_bad_lines)
    else:
        directory = source if source.is_dir() else source.parent
        if fmt == "sydney-text" and not (directory / "DRS.txt").exists() and (directory / "text").is_dir():
            directory = directory / "text"
        if source.is_file():
            _check_sydney_file(source, directory, fmt)
        reader = read_sydney_text if fmt == "sydney-text" else read_sydney_mat
        log = reader(directory, skip_bad_lines)
    if dataset:
        log.dataset = dataset
    return log


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


@dataclass
class IngestReport:
    log: LogData
    output: Path
    counts: dict[str, int]


def ingest(
    source: Path,
    output: Path,
    fmt: str = "auto",
    dataset: str | None = None,
    skip_bad_lines: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> IngestReport:
    """Read `source` and write it as an MCAP at `output` (atomically)."""
    from .to_mcap import write_log_mcap

    log = read_log(source, fmt, dataset, skip_bad_lines)
    counts = write_log_mcap(log, Path(output), progress)
    return IngestReport(log, Path(output), counts)
