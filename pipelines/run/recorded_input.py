"""The input a result names: `gslam process` records the input MCAP's path and fingerprint, and the
commands that read it back (`eval`, `plot`, `export --occupancy`) use it only when it is still that
file: a regular file (never a FIFO or a device, which would block) with the recorded fingerprint
(another log put at the same path is refused, not used silently). Messages show the recorded path
escaped (printable characters only), never the file's content."""

from __future__ import annotations

import hashlib
import os
import stat
from pathlib import Path
from typing import Any

from pipelines.errors import InputError

TAIL_BYTES = 1 << 16
"""The fingerprint hashes the file's last 64 KiB: an MCAP's summary and footer (its chunk index with
offsets, sizes and times, and the summary's CRC) change with any change to its messages."""


def process_result_metadata(src: Any, path: Path, needs: str = "this needs") -> dict[str, Any]:
    """The metadata of the MCAP `src` (an `McapInput` of `path`) when it is a `gslam process` result; else
    InputError naming the file, `needs` saying what wanted one ("--continue takes")."""
    from mcaplog.mcapio import read_error

    try:
        meta = src.metadata()
    except Exception as e:
        raise InputError(f"{path}: not a readable MCAP file ({read_error(e)})") from None
    if "localise" in meta:
        raise InputError(f"{path}: a result of `gslam localise`; {needs} a result of `gslam process`")
    if "result" not in meta or "config" not in meta:
        raise InputError(f"{path}: no 'result'/'config' metadata; {needs} a result of `gslam process`")
    return meta


def fingerprint(path: Path) -> dict[str, Any]:
    """{"size": bytes, "tail_sha256": hex digest of the last `TAIL_BYTES`} of a regular file."""
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        f.seek(max(0, size - TAIL_BYTES))
        tail = f.read(TAIL_BYTES)
    return {"size": size, "tail_sha256": hashlib.sha256(tail).hexdigest()}


def shown(path: object) -> str:
    """A recorded path as a message may show it: printable characters only, at most 200."""
    text = "".join(c if c.isprintable() else "?" for c in str(path))
    return text if len(text) <= 200 else text[:197] + "..."


def recorded_input(result: Path, metadata: dict[str, Any], option: str) -> Path:
    """The input MCAP `result` (whose metadata is `metadata`) was computed from, checked; InputError
    naming `option` (the flag that gives the input instead) when it cannot be used."""
    entry = metadata.get("input", {})
    raw = entry.get("path") if isinstance(entry, dict) else None
    if not isinstance(raw, str) or not raw:
        raise InputError(f"{result}: it names no input MCAP; give it with {option} INPUT.mcap")
    path = Path(raw)
    try:
        mode = os.stat(path).st_mode
    except OSError:
        raise InputError(f"{result}: its input {shown(raw)} is not there; give it with {option} INPUT.mcap") from None
    if not stat.S_ISREG(mode):
        raise InputError(
            f"{result}: its recorded input {shown(raw)} is not a regular file; give the input with {option} INPUT.mcap"
        )
    recorded = entry.get("fingerprint")
    if isinstance(recorded, dict):
        try:
            now = fingerprint(path)
        except OSError as e:
            raise InputError(f"{result}: cannot read its input {shown(raw)} ({e.strerror})") from None
        if now != recorded:
            raise InputError(
                f"{result}: the file at its recorded input {shown(raw)} is not the one the run read (its size "
                f"or content differ); give the input with {option} INPUT.mcap"
            )
    return path
