"""Ingest: outside log formats to MCAP. One reader module per format, behind one interface
(`ingest.base.LogReader`), chosen by what the input is:

- `ingest.sydney`: the ACFR Car Park and Victoria Park logs (text and MATLAB);
- `ingest.carmen`: CARMEN logs (the Freiburg intel and mit-csail logs);
- `ingest.rosbag`: ROS 1 bags and ROS 2 bags (sqlite3 and MCAP storage).
"""

from __future__ import annotations

import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from mcaplog.tempfiles import file_kind

from .base import LogReader, LogStream, ReadOptions
from .carmen import CarmenReader
from .logdata import LogData, ScanGeometry
from .rosbag import RosbagReader
from .sydney import SydneyReader
from .textlog import IngestError

READERS: tuple[LogReader, ...] = (SydneyReader(), CarmenReader(), RosbagReader())
FORMATS = ("auto", *(f for r in READERS for f in r.formats))

__all__ = [
    "FORMATS",
    "READERS",
    "IngestError",
    "IngestReport",
    "LogData",
    "LogStream",
    "ReadOptions",
    "ScanGeometry",
    "detect_format",
    "ingest",
    "open_log",
    "read_log",
]


def detect_format(source: Path) -> str:
    """The format of `source` (a directory or a file): the first reader that claims it."""
    source = Path(source)
    if not source.exists():
        raise IngestError(f"{source}: no such file or directory")
    for reader in READERS:
        fmt = reader.detect(source)
        if fmt is not None:
            return fmt
    if source.is_file():
        raise IngestError(f"{source}: cannot tell the format from the name (use --format)")
    raise IngestError(
        f"{source}: no known log found (expected DRS.txt, data_set.mat, aa3_dr.mat, one CARMEN .clf/.log, "
        "or a ROS 2 bag's metadata.yaml)"
    )


def _require_file_or_directory(source: Path) -> None:
    """A log is a regular file or a directory: a FIFO or a device (`/dev/zero`) would block or never end."""
    mode = source.stat().st_mode
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise IngestError(f"{source}: {file_kind(mode)}, not a log file or directory")


def _reader_for(fmt: str) -> LogReader:
    for reader in READERS:
        if fmt in reader.formats:
            return reader
    raise IngestError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")


def open_log(source: Path, fmt: str = "auto", options: ReadOptions | None = None) -> LogStream:
    """Open a log of any known format as a `LogStream`, detecting the format when `fmt` is "auto"."""
    source = Path(source)
    options = options or ReadOptions()
    if fmt not in FORMATS:
        raise IngestError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    if not source.exists():
        raise IngestError(f"{source}: no such file or directory")
    _require_file_or_directory(source)
    if fmt == "auto":
        fmt = detect_format(source)
    given = [name for name in ReadOptions.BAG_OPTIONS if getattr(options, name) is not None]
    if given and fmt != "rosbag":
        flags = ", ".join("--" + name.replace("_", "-") for name in given)
        raise IngestError(f"{source}: {flags} apply to ROS bags only; this is a {fmt} log")
    stream = _reader_for(fmt).open(source, fmt, options)
    if options.dataset:
        stream.dataset = options.dataset
    return stream


def read_log(source: Path, fmt: str = "auto", dataset: str | None = None, skip_bad_lines: bool = False) -> LogData:
    """Read a Sydney or CARMEN log into memory (`LogData`). ROS bags stream instead: use `open_log`."""
    stream = open_log(source, fmt, ReadOptions(dataset=dataset, skip_bad_lines=skip_bad_lines))
    load = getattr(stream, "load", None)  # a text log streamed into MCAP, read whole on request
    if load is not None:
        data = load()
        data.dataset = stream.dataset
        return data
    if not isinstance(stream, LogData):
        raise IngestError(f"{source}: a {stream.source_format} log is streamed, not read into memory")
    return stream


@dataclass
class IngestReport:
    log: LogStream
    output: Path
    counts: dict[str, int]


def ingest(
    source: Path,
    output: Path,
    fmt: str = "auto",
    dataset: str | None = None,
    skip_bad_lines: bool = False,
    progress: Callable[[int, int], None] | None = None,
    *,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    base_frame: str | None = None,
) -> IngestReport:
    """Read `source` and write it as an MCAP at `output` (atomically)."""
    from .to_mcap import write_log_mcap

    options = ReadOptions(dataset, skip_bad_lines, scan_topic, odom_topic, base_frame)
    log = open_log(source, fmt, options)
    counts = write_log_mcap(log, Path(output), progress, Path(source))
    return IngestReport(log, Path(output), counts)
