"""MCAP reading and writing shared by ingest and the pipelines.

`AtomicMcapWriter` writes protobuf (Foxglove schemas) and JSON channels into a temporary file beside
the target and renames it into place only when `finish()` succeeds, so no half-written output is left.
`abort()` removes the temporary file; `finish()` called from an interruption handler leaves a valid,
finished file holding what was written so far.
"""

from __future__ import annotations

import json
import os
import re
import stat
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import get_chunk_data_stream
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap_protobuf.decoder import DecoderFactory
from mcap_protobuf.schema import register_schema

from .tempfiles import create_temporary, file_kind
from .tempfiles import replace as replace_temporary
from .writer import McapWriter

NS = 1_000_000_000


def to_ns(t_s: float) -> int:
    """Seconds on the dataset clock to integer nanoseconds (MCAP log time)."""
    return int(round(t_s * NS))


class AtomicMcapWriter:
    """An MCAP writer with protobuf and JSON channels, written atomically (temp file + rename)."""

    def __init__(self, path: str | os.PathLike, profile: str = "", chunk_size: int = 1 << 20) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, self.tmp_path = create_temporary(self.path)
        self._file: BinaryIO | None = None
        try:
            self._file = os.fdopen(fd, "wb")
            self._writer = McapWriter(self._file, chunk_size=chunk_size)
            self._writer.start(profile=profile, library="gslam")
        except BaseException:  # an error or a signal while it starts: no temporary left behind
            try:
                if self._file is not None:
                    self._file.close()
                else:
                    os.close(fd)
            except OSError:
                pass
            self.tmp_path.unlink(missing_ok=True)
            raise
        self._channels: dict[str, int] = {}
        self._json_schemas: dict[str, int] = {}
        self._proto_schemas: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self.closed = False

    # -- channels ---------------------------------------------------------------------------
    def _json_channel(self, topic: str, schema_name: str, schema: dict[str, Any]) -> int:
        if topic not in self._channels:
            if schema_name not in self._json_schemas:
                self._json_schemas[schema_name] = self._writer.register_schema(
                    name=schema_name, encoding=SchemaEncoding.JSONSchema, data=json.dumps(schema).encode()
                )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding=MessageEncoding.JSON, schema_id=self._json_schemas[schema_name]
            )
        return self._channels[topic]

    def _proto_channel(self, topic: str, message_type: type) -> int:
        if topic not in self._channels:
            name = message_type.DESCRIPTOR.full_name  # one schema per message type, shared by its channels
            if name not in self._proto_schemas:
                self._proto_schemas[name] = register_schema(self._writer, message_type)
            schema_id = self._proto_schemas[name]
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding=MessageEncoding.Protobuf, schema_id=schema_id
            )
        return self._channels[topic]

    def _add(self, channel_id: int, topic: str, log_time_ns: int, data: bytes) -> None:
        seq = self._sequence.get(topic, 0)
        self._sequence[topic] = seq + 1
        try:
            self._writer.add_message(
                channel_id=channel_id, log_time=log_time_ns, publish_time=log_time_ns, data=data, sequence=seq
            )
        except OSError as e:  # disk full, I/O error: say which output
            raise OSError(e.errno, e.strerror, str(self.path)) from None

    def write_proto(self, topic: str, message: Any, log_time_ns: int) -> None:
        """Write a protobuf message (a Foxglove schema) on `topic` at `log_time_ns`."""
        self._add(self._proto_channel(topic, type(message)), topic, log_time_ns, message.SerializeToString())

    def write_proto_bytes(self, topic: str, message_type: type, data: bytes, log_time_ns: int) -> None:
        """Write an already serialised protobuf message of `message_type` on `topic`."""
        self._add(self._proto_channel(topic, message_type), topic, log_time_ns, data)

    def write_json(
        self, topic: str, schema_name: str, schema: dict[str, Any], obj: dict[str, Any], log_time_ns: int
    ) -> None:
        """Write a JSON message with a JSON schema of the project's own."""
        self.write_json_bytes(topic, schema_name, schema, json.dumps(obj, separators=(",", ":")).encode(), log_time_ns)

    def write_json_bytes(
        self, topic: str, schema_name: str, schema: dict[str, Any], data: bytes, log_time_ns: int
    ) -> None:
        """Write an already encoded JSON message (`write_json`'s bytes) with a JSON schema of the project's own."""
        self._add(self._json_channel(topic, schema_name, schema), topic, log_time_ns, data)

    def add_metadata(self, name: str, data: dict[str, Any]) -> None:
        """MCAP metadata record; values that are not strings are stored as JSON."""
        self._writer.add_metadata(name, {k: v if isinstance(v, str) else json.dumps(v) for k, v in data.items()})

    # -- ending -----------------------------------------------------------------------------
    def finish(self) -> Path:
        """Finish the MCAP (index, footer) and move it into place. Safe to call twice."""
        if not self.closed:
            try:
                self._writer.finish()
                self._file.close()
                replace_temporary(self.tmp_path, self.path)
            except OSError as e:  # disk full, I/O error: nothing at the final path, the error names it
                self.abort()
                raise OSError(e.errno, e.strerror, str(self.path)) from None
            self.closed = True
        return self.path

    def abort(self) -> None:
        """Drop the temporary file: nothing is left at the target path."""
        if not self.closed:
            try:
                self._file.close()
            except OSError:
                pass  # the data is dropped anyway
            finally:
                self.tmp_path.unlink(missing_ok=True)
                self.closed = True

    def __enter__(self) -> AtomicMcapWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.finish()
        else:
            self.abort()


@dataclass
class Message:
    """One decoded message: topic, log time [s], and the decoded object (protobuf or dict)."""

    topic: str
    t_s: float
    log_time_ns: int
    value: Any


class McapInput:
    """Reads an MCAP written by gslam: metadata, summary, and messages decoded in log-time order."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: no such file")
        require_regular_file(self.path, "an MCAP file")

    def _reader(self, f):
        check_finished(f)
        return make_reader(f, decoder_factories=[DecoderFactory()])

    def metadata(self) -> dict[str, dict[str, Any]]:
        """All metadata records, values parsed from JSON where they are JSON."""
        out: dict[str, dict[str, Any]] = {}
        with open(self.path, "rb") as f:
            for record in self._reader(f).iter_metadata():
                parsed = {}
                for k, v in record.metadata.items():
                    try:
                        parsed[k] = json.loads(v)
                    except (json.JSONDecodeError, TypeError):
                        parsed[k] = v
                out[record.name] = parsed
        return out

    def summary(self):
        with open(self.path, "rb") as f:
            return self._reader(f).get_summary()

    def messages(
        self, topics: list[str] | None = None, select: Callable[[int], bool] | None = None
    ) -> Iterator[Message]:
        """Messages of `topics` (all when None) in log-time order, decoded. `select(n)`: whether the n-th of
        them (from 0, in that order) is decoded and yielded; the others are passed over undecoded, which
        costs a fraction of decoding them (a run's end reads back some of its input's scans: `InputLog.scans_at`).

        The order is the mcap library's (log time, then position in the file). When the file's chunks
        follow one another in time, as every chunk of a file written in time order does, each chunk is
        read and ordered on its own (`_chunk_messages`), which is several times faster than the
        library's merge of all chunks; otherwise the library's reader does the merge."""
        with open(self.path, "rb") as f:
            reader = self._reader(f)
            summary = reader.get_summary()
            wanted = None
            if summary is not None:
                wanted = {cid for cid, c in summary.channels.items() if topics is None or c.topic in topics}
            for c in summary.chunk_indexes if summary is not None else ():
                check_chunk_size(c.uncompressed_size, c.chunk_start_offset)  # before any is decompressed
            chunks = _sequential_chunks(summary, wanted)
            if chunks is None:
                records = (
                    (schema, channel, m.log_time, m.data)
                    for schema, channel, m in reader.iter_messages(topics=topics, log_time_order=True)
                )
            else:
                records = (
                    (summary.schemas.get(summary.channels[cid].schema_id), summary.channels[cid], log_time, data)
                    for chunk in chunks
                    for log_time, cid, data in _chunk_messages(f, chunk, wanted)
                )
            for n, (schema, channel, log_time, data) in enumerate(records):
                if select is not None and not select(n):
                    continue
                if channel.message_encoding == MessageEncoding.JSON:
                    value: Any = json.loads(data)
                else:
                    value = _decode_proto(schema, data)
                yield Message(channel.topic, log_time / NS, log_time, value)


MCAP_MAGIC = b"\x89MCAP0\r\n"
"""The 8 bytes an MCAP begins and ends with."""
MIN_FINISHED_BYTES = 2 * len(MCAP_MAGIC) + 9 + 20
"""The smallest finished MCAP: the magic, a footer record (opcode, length, 20 bytes) and the magic again."""


class TruncatedMcap(ValueError):
    """An MCAP that begins as one but does not end with its footer and closing magic: cut short, as the
    temporary of a writer killed mid-write (`.NAME.PID-START-RANDOM.tmp`) or a partial copy is. Its
    message says so in words (the mcap library would say "RecordLengthLimitExceeded", reading garbage as
    the footer)."""


def check_finished(f: Any) -> None:
    """Raise `TruncatedMcap` when the open file `f` begins with the MCAP magic (or a part of it) but does not
    end as a finished MCAP; a file that does not begin so is left to the library (`read_error` words it)."""
    size = f.seek(0, os.SEEK_END)
    f.seek(0)
    head = f.read(len(MCAP_MAGIC))
    f.seek(0)
    if head != MCAP_MAGIC[: len(head)]:
        return
    if size == 0:
        raise TruncatedMcap("it is empty (0 bytes), not a finished MCAP")
    tail = b""
    if size >= MIN_FINISHED_BYTES:
        f.seek(size - len(MCAP_MAGIC))
        tail = f.read(len(MCAP_MAGIC))
        f.seek(0)
    if tail != MCAP_MAGIC:
        raise TruncatedMcap(
            f"truncated after {size} bytes: no MCAP footer at its end, so not a finished MCAP; a run killed "
            f"while writing it leaves such a file"
        )


def read_error(e: BaseException) -> str:
    """What went wrong reading an MCAP, for a one-line message: never the file's bytes (the mcap library
    puts the first bytes of a file that is not an MCAP in its message), nor the library's names for a file
    cut short (`TruncatedMcap`), printable, at most 160 characters."""
    from mcap.exceptions import EndOfFile, InvalidMagic, RecordLengthLimitExceeded

    if isinstance(e, InvalidMagic):
        return "it does not begin with the MCAP magic bytes"
    if isinstance(e, TruncatedMcap):
        return str(e)
    if isinstance(e, (EndOfFile, RecordLengthLimitExceeded)):
        return "a record runs past the end of the file or claims an impossible length: it is truncated or damaged"
    text = f"{type(e).__name__}: {e}".splitlines()[0] if str(e) else type(e).__name__
    text = re.sub(r"b'[^']*'|b\"[^\"]*\"", "<bytes>", text)  # byte strings of the file's content
    text = "".join(c if c.isprintable() else "?" for c in text)
    return text if len(text) <= 160 else text[:157] + "..."


MAX_CHUNK_BYTES = 256 << 20
"""The largest decompressed chunk read (256 MiB): gslam writes 1 MiB chunks, ROS 2 bags about 1 MiB; a
chunk claiming more is refused before it is decompressed, so a small file cannot take gigabytes."""


def check_chunk_size(uncompressed_size: int, offset: int) -> None:
    """Refuse a chunk that would decompress to more than `MAX_CHUNK_BYTES`."""
    if uncompressed_size > MAX_CHUNK_BYTES:
        raise ValueError(
            f"the chunk at byte {offset} would decompress to {uncompressed_size} bytes, more than "
            f"{MAX_CHUNK_BYTES >> 20} MiB: not an MCAP gslam reads"
        )


def require_regular_file(path: Path, what: str) -> None:
    """Refuse anything but a regular file (a FIFO or a device would block or never end)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return  # reported by whoever opens it
    if not stat.S_ISREG(mode):
        raise ValueError(f"{path}: {file_kind(mode)}, not a regular file; give {what}")


def _sequential_chunks(summary: Any, channel_ids: set[int] | None) -> list[Any] | None:
    """The chunk indexes holding messages of `channel_ids`, in time order, when each chunk's messages all
    come at or before the next chunk's (ties going to the chunk earlier in the file, as in the library's
    order); None when the file has no chunk index or its chunks overlap in time."""
    if summary is None or not summary.chunk_indexes:
        return None
    chunks = [
        c for c in summary.chunk_indexes if not c.message_index_offsets or channel_ids & set(c.message_index_offsets)
    ]
    chunks.sort(key=lambda c: (c.message_start_time, c.chunk_start_offset))
    for a, b in zip(chunks, chunks[1:], strict=False):
        if a.message_end_time > b.message_start_time or (
            a.message_end_time == b.message_start_time and a.chunk_start_offset > b.chunk_start_offset
        ):
            return None
    return chunks


_RECORD_HEAD = struct.Struct("<BQ")
_MESSAGE_HEAD = struct.Struct("<HIQQ")
_OP_MESSAGE = 0x05


def _chunk_messages(f: Any, chunk_index: Any, channel_ids: set[int]) -> list[tuple[int, int, bytes]]:
    """(log time, channel id, data) of the messages of `channel_ids` in one chunk, in log-time order
    (ties in file order). A damaged chunk raises (the library's errors, or ValueError for its records);
    the pipelines (`pipelines.run.input_log.converted`) report any of them as a damaged file."""
    f.seek(chunk_index.chunk_start_offset + 9)  # past the record's opcode and length
    chunk = Chunk.read(ReadDataStream(f))
    check_chunk_size(chunk.uncompressed_size, chunk_index.chunk_start_offset)
    stream, size = get_chunk_data_stream(chunk)  # decompressed by the library
    payload = stream.read(size)
    out = []
    o, end = 0, len(payload)
    while o < end:
        opcode, length = _RECORD_HEAD.unpack_from(payload, o)
        start = o + _RECORD_HEAD.size
        o = start + length
        if o > end:
            raise ValueError("record runs past the end of its chunk")
        if opcode == _OP_MESSAGE:
            if length < _MESSAGE_HEAD.size:
                raise ValueError("message record too short")
            cid, _, log_time, _ = _MESSAGE_HEAD.unpack_from(payload, start)
            if cid in channel_ids:
                out.append((log_time, cid, payload[start + _MESSAGE_HEAD.size : o]))
    out.sort(key=lambda m: m[0])  # stable: equal times keep their order in the file
    return out


_PROTO_DECODERS: dict[tuple[str, bytes], Any] = {}
_SCHEMA_DECODERS: dict[int, tuple[Any, Any]] = {}  # id(schema) -> (schema, its decoder): one lookup a message


def _decode_proto(schema, data: bytes):
    known = _SCHEMA_DECODERS.get(id(schema))
    if known is not None and known[0] is schema:
        return known[1](data)
    key = (schema.name, bytes(schema.data))
    dec = _PROTO_DECODERS.get(key)
    if dec is None:
        dec = DecoderFactory().decoder_for(MessageEncoding.Protobuf, schema)
        _PROTO_DECODERS[key] = dec
    if len(_SCHEMA_DECODERS) > 256:  # files read one after another (a benchmark's): forget the old ones
        _SCHEMA_DECODERS.clear()
    _SCHEMA_DECODERS[id(schema)] = (schema, dec)  # the schema kept alive, so its id is not reused
    return dec(data)
