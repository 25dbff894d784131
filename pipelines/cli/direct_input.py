"""`gslam process` (and `gslam localise`) on a log or a bag: what the input is, and its ingest on the way.

An MCAP written by `gslam ingest` is processed as it is. A log or bag that `gslam ingest` reads (a Sydney
directory, a CARMEN `.clf`/`.log[.gz]`, a ROS 1 `.bag`, a ROS 2 bag directory, `.db3`, or an `.mcap` that
another program wrote) is ingested first into `OUTPUT.input.mcap` beside the result, with ingest's
defaults, so `gslam eval`, `plot` and `export` find the run's input as after an explicit ingest (as
kiss-icp's pipeline reads a dataset directly). The ingest records the source's resolved path and a
fingerprint of its content (`source_fingerprint`: sizes and hashes, never modification times, which a
copied or restored log carries from elsewhere); an earlier ingest at that path is reused only when both
match the source now. An ingest of the same path whose content has changed is replaced; an ingest of
another log, a file that is no ingest, and anything that is not a regular file (a FIFO would block) are
never touched and refused in plain words, saying what was expected.
`gslam localise MAP IN OUT` does the same for IN (into `OUT.input.mcap`); `role` names the argument in the
messages.
"""

from __future__ import annotations

import hashlib
import os
import stat
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcaplog.mcapio import MCAP_MAGIC
from mcaplog.tempfiles import describe_non_regular, file_kind
from pipelines.errors import InputError


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


WHOLE_FILE_BYTES = 32 << 20
"""A source file up to this size is hashed whole; a larger one by its first and last `EDGE_BYTES` (with
its size, which any change of length alters)."""
EDGE_BYTES = 4 << 20
MAX_FILES = 10_000
"""A source directory's fingerprint covers at most this many of its files (sorted by path)."""


def _file_digest(path: Path, h: Any) -> int:
    """Feed `path`'s content (whole, or its two ends) into the hash `h`; returns its size. Reads only a
    regular file: anything else (a FIFO would block) raises OSError."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise OSError(f"{path}: {file_kind(st.st_mode)}, not a regular file")
        size = st.st_size
        h.update(size.to_bytes(8, "little"))
        if size <= WHOLE_FILE_BYTES:
            while chunk := f.read(1 << 20):
                h.update(chunk)
        else:
            h.update(f.read(EDGE_BYTES))
            f.seek(size - EDGE_BYTES)
            h.update(f.read(EDGE_BYTES))
    return size


def source_fingerprint(source: Path) -> dict[str, Any]:
    """What a log's content is, to tell whether an earlier ingest is of this very content: {"size": total
    bytes, "files": count, "sha256": over each file's relative path, size and content (whole up to 32 MiB,
    else its first and last 4 MiB)}. A directory (a Sydney log, a ROS 2 bag) counts its regular files."""
    h = hashlib.sha256()
    if Path(source).is_dir():
        files = sorted(p for p in Path(source).rglob("*") if p.is_file())[:MAX_FILES]
        size = 0
        for p in files:
            h.update(str(p.relative_to(source)).encode("utf-8", "surrogateescape") + b"\0")
            size += _file_digest(p, h)
        return {"size": size, "files": len(files), "sha256": h.hexdigest()}
    return {"size": _file_digest(Path(source), h), "files": 1, "sha256": h.hexdigest()}


def _recorded_source(meta: dict) -> tuple[str | None, Path | None]:
    """The source an ingest's metadata names, as recorded (for messages) and resolved (None: none)."""
    dataset = meta.get("dataset", {})
    raw = dataset.get("source_path") or dataset.get("source")
    if not isinstance(raw, str) or not raw:
        return None, None
    try:
        return raw, Path(raw).resolve()
    except (OSError, RuntimeError):
        return raw, None


def _ingest_of(meta: dict, source: Path) -> str:
    """What an ingest whose metadata is `meta` is to `source`: "this" (the same resolved path and the same
    content fingerprint: used again), "stale" (the same path, but its content changed or was not recorded:
    ingested again over it), or "other" (another log, or none named: never replaced)."""
    _, recorded = _recorded_source(meta)
    if recorded is None or recorded != source.resolve():
        return "other"
    fp = meta.get("dataset", {}).get("source_fingerprint")
    if not isinstance(fp, dict):
        return "stale"
    try:
        return "this" if source_fingerprint(source) == fp else "stale"
    except OSError:
        return "stale"


def prepare(
    source: Path,
    output: Path,
    progress: Callable[[int, int], None] | None = None,
    fmt: str | None = None,
    role: str = "INPUT",
) -> DirectInput:
    """The MCAP `process` (or `localise`) reads for `source`: itself, or `source` ingested into
    `ingested_path(output)`. An earlier ingest of this very source there is reused; one of the same path
    with other content is replaced; anything else there (another log's ingest, a file that is no ingest,
    a FIFO or a device) is never overwritten nor, unless it is a regular file, opened."""
    fmt = fmt or needs_ingest(source, role)
    if fmt is None:
        return DirectInput(source)
    mcap = ingested_path(output)
    if os.path.lexists(mcap):
        odd = describe_non_regular(mcap)  # nothing is opened before this: a FIFO would block
        if odd is not None:
            raise InputError(
                f"{role} {source} is a log: it would be ingested into {mcap}, which is {odd} and is never "
                "replaced; move it, or give another output"
            )
        meta = _ingest_metadata(mcap)
        if meta is None:  # only an earlier ingest is replaced, never another file
            raise InputError(
                f"{role} {source} is a log: it would be ingested into {mcap}, which exists and is not an "
                "input MCAP from gslam ingest; move that file, or run `gslam ingest` yourself"
            )
        verdict = _ingest_of(meta, source)
        if verdict == "this":
            return DirectInput(mcap, source, reused=True)
        if verdict == "other":
            from pipelines.run.recorded_input import shown

            named = _recorded_source(meta)[0]
            of = f"another log, {shown(named)}" if named else "a log it does not name"
            raise InputError(
                f"{role} {source} is a log: it would be ingested into {mcap}, which holds the ingest of {of}; "
                f"give another output, or move {mcap} away"
            )
    from ingest import open_log
    from ingest.to_mcap import write_log_mcap

    log = open_log(source, fmt)  # refuses a FIFO or a device before the fingerprint reads anything
    recorded = {"source_path": str(source.resolve()), "source_fingerprint": source_fingerprint(source)}
    write_log_mcap(log, mcap, progress, source, dataset_extra=recorded)
    return DirectInput(mcap, source)
