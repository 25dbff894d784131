"""`gslam process` (and `gslam localise`) on a log or a bag: what the input is, and its ingest on the way.

An MCAP written by `gslam ingest` is processed as it is. A log or bag that `gslam ingest` reads (a Sydney
directory, a CARMEN `.clf`/`.log[.gz]`, a ROS 1 `.bag`, a ROS 2 bag directory, `.db3`, or an `.mcap` that
another program wrote) is ingested first into `OUTPUT.input.mcap` beside the result, with ingest's
defaults, so `gslam eval`, `plot` and `export` find the run's input as after an explicit ingest (as
kiss-icp's pipeline reads a dataset directly). An earlier ingest of the same source at that path is
reused when it is newer than the source. Anything else is refused in plain words, saying what was expected.
`gslam localise MAP IN OUT` does the same for IN (into `OUT.input.mcap`); `role` names the argument in the
messages.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pipelines.errors import InputError

MCAP_MAGIC = b"\x89MCAP0\r\n"


def mcap_library(path: Path) -> str | None:
    """The `library` field of an MCAP's header ("gslam" for gslam's files); None when `path` is not an
    MCAP (or its header cannot be read)."""
    try:
        with open(path, "rb") as f:
            head = f.read(8 + 9 + 8 + 4096)
    except OSError:
        return None
    if not head.startswith(MCAP_MAGIC) or len(head) < 8 + 9 + 4 or head[8] != 0x01:
        return None
    try:
        at = 8 + 9
        (n,) = struct.unpack_from("<I", head, at)
        at += 4 + n  # the profile
        (n,) = struct.unpack_from("<I", head, at)
        return head[at + 4 : at + 4 + n].decode("utf-8", "replace")
    except struct.error:
        return None


def ingested_path(output: Path) -> Path:
    """Where a log given to `process` is ingested: `r.mcap` -> `r.input.mcap`."""
    return output.with_name(output.stem + ".input.mcap")


@dataclass(frozen=True)
class DirectInput:
    mcap: Path
    """The MCAP to process."""
    source: Path | None = None
    """The log or bag it was ingested from (None: the input was an MCAP from gslam ingest)."""
    reused: bool = False
    """An earlier ingest of `source` at `mcap` was used."""


def needs_ingest(source: Path, role: str = "INPUT") -> str | None:
    """The ingest format of `source` when it is a log or bag rather than a gslam input MCAP, else None.
    Raises InputError, in plain words naming the argument `role`, for what is neither."""
    from ingest import IngestError, detect_format

    if source.is_file() and mcap_library(source) == "gslam":
        return None
    if not source.exists():
        raise InputError(f"{role} {source}: no such file or directory")
    try:
        return detect_format(source)
    except IngestError:
        pass
    if source.is_file() and mcap_library(source) is not None:
        raise InputError(
            f"{role} {source}: an MCAP that gslam did not write; give an input MCAP from `gslam ingest` "
            "(a ROS 2 bag in MCAP storage is read when its name ends in .mcap)"
        )
    raise InputError(
        f"{role} {source}: not an MCAP from `gslam ingest` and not a log gslam reads (a Sydney log directory, "
        "a CARMEN .clf/.log[.gz], a ROS 1 .bag or a ROS 2 bag); see `gslam ingest --help`"
    )


def _ingest_metadata(mcap: Path) -> dict | None:
    """The metadata of `mcap` when it is an input MCAP from gslam ingest (not a result), else None."""
    if mcap_library(mcap) != "gslam":
        return None
    from mcaplog.mcapio import McapInput

    try:
        meta = McapInput(mcap).metadata()
    except Exception:  # damaged: not something to keep or reuse
        return None
    return meta if "ingest" in meta and "result" not in meta else None


def _ingest_of(meta: dict, mcap: Path, source: Path) -> bool:
    """An ingest whose metadata is `meta`, at `mcap`, is of `source` and newer than it (then it is used
    again)."""
    recorded = meta.get("dataset", {}).get("source")
    if recorded is None or Path(str(recorded)).resolve() != source.resolve():
        return False
    newest = max((p.stat().st_mtime for p in ([source] if source.is_file() else source.iterdir())), default=0.0)
    return mcap.stat().st_mtime >= newest


def prepare(
    source: Path,
    output: Path,
    progress: Callable[[int, int], None] | None = None,
    fmt: str | None = None,
    role: str = "INPUT",
) -> DirectInput:
    """The MCAP `process` (or `localise`) reads for `source`: itself, or `source` ingested into
    `ingested_path(output)`. A file at that path that is not an earlier gslam ingest is never overwritten."""
    fmt = fmt or needs_ingest(source, role)
    if fmt is None:
        return DirectInput(source)
    mcap = ingested_path(output)
    if mcap.exists():
        meta = _ingest_metadata(mcap)
        if meta is not None and _ingest_of(meta, mcap, source):
            return DirectInput(mcap, source, reused=True)
        if meta is None:  # only an earlier ingest is replaced, never another file
            raise InputError(
                f"{role} {source} is a log: it would be ingested into {mcap}, which exists and is not an "
                "input MCAP from gslam ingest; move that file, or run `gslam ingest` yourself"
            )
    from ingest import ingest

    ingest(source, mcap, fmt, progress=progress)
    return DirectInput(mcap, source)
