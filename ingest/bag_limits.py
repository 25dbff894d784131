"""Bounds on what a ROS bag may decompress.

rosbags (0.11) decompresses each chunk (ROS 1 bags: bz2 or lz4; ROS 2 bags in MCAP storage: lz4 or zstd)
and each message (ROS 2 message compression: zstd) whole and without a limit, so a small bag holding a
chunk that expands to gigabytes would take that much memory. `install` replaces the decompressors in
rosbags' own tables with ones that stop at `MAX_CHUNK_BYTES` (the bound `mcaplog.mcapio` puts on MCAP
chunks) and refuse what would expand further: real bags' chunks are far smaller (ROS 1 records 768 KiB
chunks, ROS 2's MCAP storage 1 MiB to 4 MiB). A ROS 2 bag compressed as a whole file (`compression_mode:
file`) is unpacked by rosbags into a temporary directory, on disk, not in memory; it is not bounded here.
"""

from __future__ import annotations

import bz2
import types
from collections.abc import Callable
from typing import Any

from mcaplog.mcapio import MAX_CHUNK_BYTES


class ExpandsTooFar(ValueError):
    """Compressed data that would expand beyond the bound."""


STEP_BYTES = 16 << 20
"""Output is produced in pieces of at most this size, so the bound is checked before more is allocated."""


def bounded(new_decompressor: Callable[[], Any], data: bytes, limit: int | None = None) -> bytes:
    """`data` decompressed (one or more concatenated streams), refusing output beyond `limit` bytes
    (default `MAX_CHUNK_BYTES`): it is produced `STEP_BYTES` at a time, so no more than the bound and one
    step or two is ever held."""
    limit = MAX_CHUNK_BYTES if limit is None else limit
    out: list[bytes] = []
    total = 0
    rest = bytes(data)
    while True:
        d = new_decompressor()
        pending = rest
        while not d.eof:
            if d.needs_input and not pending:
                raise ValueError("compressed data ended before the end of its stream")
            part = d.decompress(pending, STEP_BYTES)
            pending = b""
            total += len(part)
            if total > limit:
                raise ExpandsTooFar(f"compressed data expands beyond {limit >> 20} MiB")
            out.append(part)
        rest = d.unused_data
        if not rest:
            return b"".join(out)


def _bz2(data: bytes) -> bytes:
    return bounded(bz2.BZ2Decompressor, data)


def _lz4(data: bytes) -> bytes:
    from lz4.frame import LZ4FrameDecompressor

    return bounded(LZ4FrameDecompressor, data)


def _zstd_module():
    try:
        from compression import zstd  # Python 3.14
    except ImportError:
        from backports import zstd
    return zstd


def _zstd(data: bytes) -> bytes:
    return bounded(_zstd_module().ZstdDecompressor, data)


def _claimed(decompress: Callable[[bytes], bytes]) -> Callable[[bytes, int], bytes]:
    """A ROS 2 MCAP chunk decompressor: the chunk's stated size is checked before anything is read."""

    def chunk(data: bytes, size: int) -> bytes:
        if size > MAX_CHUNK_BYTES:
            raise ExpandsTooFar(f"a chunk claims {size} bytes, more than the {MAX_CHUNK_BYTES >> 20} MiB allowed")
        return decompress(data)

    return chunk


_installed = False


def install() -> None:
    """Put the bounded decompressors into rosbags' tables (once; before a bag is opened)."""
    global _installed
    if _installed:
        return
    from rosbags.rosbag1 import reader as rosbag1_reader
    from rosbags.rosbag2 import reader as rosbag2_reader
    from rosbags.rosbag2 import storage_mcap

    rosbag1_reader.decompressors.update({"bz2": _bz2, "lz4": _lz4})
    storage_mcap.DECOMPRESSORS.update({"lz4": _claimed(_lz4), "zstd": _claimed(_zstd)})
    zstd = _zstd_module()
    rosbag2_reader.zstd = types.SimpleNamespace(decompress=_zstd, open=zstd.open)  # message compression
    _installed = True
