"""A lean MCAP writer for files of many small messages (the MCAP format, https://mcap.dev/spec).

The `mcap` library's `Writer` builds every message record field by field in Python (a record object,
five `struct` calls and two seeks) and every chunk's message indexes entry by entry: on intel's result
(70 067 messages) 1.3 s in `add_message` and 0.65 s finishing chunks, 0.4 s of which is zstd. Here a message
record is one `struct.pack` appended to the chunk, and a chunk's message index, read from its records when
the chunk is written, is packed in one call per channel. Every other record (header, schema, channel,
chunk, chunk index, statistics, metadata, summary offsets, footer) is written by the `mcap` library's own
record classes, in the layout its `Writer` uses: schemas and channels in the chunk where they are
registered and repeated in the summary, zstd chunks with the CRC of their records, metadata between
chunks, one summary offset per group.

A file finished after an interruption (Ctrl-C raises KeyboardInterrupt at any bytecode; `gslam process`
then finishes its outputs) holds every message whose `add_message` returned, none twice, and reads
whole: see `McapWriter` for how.
"""

from __future__ import annotations

import struct
import zlib
from typing import BinaryIO, NamedTuple

import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.writer import MCAP0_MAGIC

_MESSAGE = struct.Struct("<BQHIQQ")
"""A message record's opcode, length, channel id, sequence, log time and publish time (the data follows)."""
_MESSAGE_FIELDS = 2 + 4 + 8 + 8
_MESSAGE_HEAD = struct.Struct("<BQHIQ")
"""A message record's opcode, length, channel id, sequence and log time: what its index needs."""
_RECORD_HEAD = struct.Struct("<BQ")
_INDEX_HEAD = struct.Struct("<BQHI")
"""A message index record's opcode, length, channel id and the byte length of its (time, offset) pairs."""
_OP_MESSAGE = int(Opcode.MESSAGE)


def _record(record: McapRecord) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    return builder.end()


def _message_index(records: bytes) -> dict[int, list[int]]:
    """channel id -> log time, offset, log time, offset, ... of the message records among `records` (a
    chunk's: schemas, channels and messages), in their order."""
    index: dict[int, list[int]] = {}
    head, record_head = _MESSAGE_HEAD.unpack_from, _RECORD_HEAD.unpack_from
    o, end = 0, len(records)
    while o < end:
        if records[o] == _OP_MESSAGE:
            _, length, channel_id, _, log_time = head(records, o)
            pairs = index.get(channel_id)
            if pairs is None:
                pairs = index[channel_id] = []
            pairs += (log_time, o)
        else:
            length = record_head(records, o)[1]
        o += 9 + length
    return index


class _State(NamedTuple):
    """What the writer has written and holds, replaced whole (one assignment) at every change but a message
    or a registration appended to `chunk`: an interruption leaves either the state before a change or the
    state after it, never a mixture."""

    chunk: bytearray
    """The records of the chunk being filled (schemas, channels, messages): a message is in the file once its
    record is in here (one in-place extend)."""
    chunk_indexes: tuple[ChunkIndex, ...]
    metadata_indexes: tuple[MetadataIndex, ...]
    message_counts: dict[int, int]
    """Messages per channel in the chunks written (never changed in place: replaced with the state)."""
    time_span: tuple[int, int] | None
    """The first and last log time of the messages in the chunks written."""
    unwritten: tuple[int, bytes] | None
    """Bytes that belong at this offset of the stream (a chunk and its message indexes, a metadata record,
    the summary) and may not all be there yet: the state already counts them. `_settle` writes what of
    them the stream lacks (judged by its position) before anything else is written."""
    finished: bool


class McapWriter:
    """Writes an MCAP file to `stream` (opened for binary writing; not closed here): `start`, then
    `register_schema`, `register_channel`, `add_message` and `add_metadata` in any order, then `finish`.
    Messages go into zstd chunks of about `chunk_size` uncompressed bytes.

    An interruption (an exception at any bytecode, as Ctrl-C raises KeyboardInterrupt) loses nothing:
    after it the writer can go on and be finished, and the file then holds every message whose
    `add_message` returned, the interrupted call's own message if the interruption came once its record
    was in the chunk, none twice, and indexes that agree with them. For this a message is a single
    in-place extend of the pending chunk (its index is built from the chunk's records when the chunk is
    written); every other change builds a new `_State` and publishes it in one assignment, bytes still
    to be written included (`_State.unwritten`); and those bytes are written by `_settle`, from the
    stream's position (so an interruption after the write and before its state is noted, or within the
    write, neither loses nor repeats them). A schema or channel registered again (identical, as a caller
    does whose registration was interrupted before it returned the id) keeps its id."""

    def __init__(self, stream: BinaryIO, chunk_size: int = 1 << 20) -> None:
        self._stream = stream
        self._chunk_size = chunk_size
        self._compressor = zstandard.ZstdCompressor()
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._state = _State(bytearray(), (), (), {}, None, None, False)

    def start(self, profile: str = "", library: str = "") -> None:
        self._stream.write(MCAP0_MAGIC + _record(Header(profile=profile, library=library)))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """A new schema's id (from 1); an identical schema registered again keeps its id."""
        schema = next((s for s in self._schemas if (s.name, s.encoding, s.data) == (name, encoding, data)), None)
        if schema is None:
            schema = Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
            self._schemas.append(schema)  # its id taken before a record holds it: never given to two schemas
        self._state.chunk.extend(_record(schema))  # again when registered again: an identical record may repeat
        return schema.id

    def register_channel(
        self, topic: str, message_encoding: str, schema_id: int, metadata: dict[str, str] | None = None
    ) -> int:
        """A new channel's id (from 1); an identical channel registered again keeps its id."""
        metadata = dict(metadata or {})
        key = (topic, message_encoding, schema_id, metadata)
        channel = next(
            (c for c in self._channels if (c.topic, c.message_encoding, c.schema_id, c.metadata) == key), None
        )
        if channel is None:
            channel = Channel(
                id=len(self._channels) + 1,
                topic=topic,
                message_encoding=message_encoding,
                schema_id=schema_id,
                metadata=metadata,
            )
            self._channels.append(channel)
        self._state.chunk.extend(_record(channel))
        return channel.id

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0) -> None:
        record = _MESSAGE.pack(_OP_MESSAGE, _MESSAGE_FIELDS + len(data), channel_id, sequence, log_time, publish_time)
        chunk = self._state.chunk
        chunk += record + data  # the message is in: one extend, nothing else to note
        if len(chunk) > self._chunk_size:
            self._finish_chunk()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record (written at once, between chunks) and its index."""
        self._settle()
        record = _record(Metadata(name=name, metadata=data))
        state = self._state
        offset = self._stream.tell()
        index = MetadataIndex(offset=offset, length=len(record), name=name)
        self._state = state._replace(metadata_indexes=(*state.metadata_indexes, index), unwritten=(offset, record))
        self._settle()

    def _settle(self) -> None:
        """Write what the stream lacks of the state's unwritten bytes (all of them, the rest of them after a
        write cut short, or none when they were written and the interruption came before this was noted)."""
        state = self._state
        if state.unwritten is None:
            return
        offset, data = state.unwritten
        done = self._stream.tell() - offset
        if not 0 <= done <= len(data):
            raise RuntimeError(f"the MCAP stream is at byte {offset + done}; its writer expected {offset}")
        if done < len(data):
            self._stream.write(memoryview(data)[done:])
        self._state = state._replace(unwritten=None)

    def _finish_chunk(self) -> None:
        """Hand over the chunk (if it holds any message): its record, message indexes, chunk index, counts
        and a new chunk, built aside and published in one state, then written (`_settle`)."""
        self._settle()
        state = self._state
        records = bytes(state.chunk)
        index = _message_index(records)
        if not index:
            return  # schemas and channels alone stay for the next chunk (they are repeated in the summary)
        start = min(min(pairs[::2]) for pairs in index.values())
        end = max(max(pairs[::2]) for pairs in index.values())
        compressed = self._compressor.compress(records)
        chunk = _record(
            Chunk(
                message_start_time=start,
                message_end_time=end,
                uncompressed_size=len(records),
                uncompressed_crc=zlib.crc32(records),
                compression="zstd",
                data=compressed,
            )
        )
        chunk_offset = self._stream.tell()
        index_offsets: dict[int, int] = {}
        parts = [chunk]
        at = chunk_offset + len(chunk)
        counts = dict(state.message_counts)
        for channel_id, pairs in index.items():
            size = 8 * len(pairs)
            part = _INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 2 + 4 + size, channel_id, size) + struct.pack(
                f"<{len(pairs)}Q", *pairs
            )
            index_offsets[channel_id] = at
            at += len(part)
            parts.append(part)
            counts[channel_id] = counts.get(channel_id, 0) + len(pairs) // 2
        chunk_index = ChunkIndex(
            message_start_time=start,
            message_end_time=end,
            chunk_start_offset=chunk_offset,
            chunk_length=len(chunk),
            message_index_offsets=index_offsets,
            message_index_length=at - chunk_offset - len(chunk),
            compression="zstd",
            compressed_size=len(compressed),
            uncompressed_size=len(records),
        )
        first, last = state.time_span or (start, end)
        self._state = state._replace(
            chunk=bytearray(),
            chunk_indexes=(*state.chunk_indexes, chunk_index),
            message_counts=counts,
            time_span=(min(first, start), max(last, end)),
            unwritten=(chunk_offset, b"".join(parts)),
        )
        self._settle()

    def finish(self) -> None:
        """The last chunk, the data end, the summary (schemas, channels, statistics, chunk and metadata
        indexes, each group's offset), the footer and the closing magic. Called again after an
        interruption, it completes the file (once)."""
        if self._state.finished:
            self._settle()
            return
        self._finish_chunk()
        self._settle()
        state = self._state
        data_end = _record(DataEnd(data_section_crc=0))
        end_offset = self._stream.tell()
        summary_start = end_offset + len(data_end)
        first, last = state.time_span or (0, 0)
        statistics = Statistics(
            message_count=sum(state.message_counts.values()),
            schema_count=len(self._schemas),
            channel_count=len(self._channels),
            attachment_count=0,
            metadata_count=len(state.metadata_indexes),
            chunk_count=len(state.chunk_indexes),
            message_start_time=first,
            message_end_time=last,
            channel_message_counts=dict(state.message_counts),
        )
        groups = [
            (Opcode.SCHEMA, self._schemas),
            (Opcode.CHANNEL, self._channels),
            (Opcode.STATISTICS, [statistics]),
            (Opcode.CHUNK_INDEX, state.chunk_indexes),
            (Opcode.METADATA_INDEX, state.metadata_indexes),
        ]
        summary = bytearray()
        offsets = []
        for opcode, records in groups:
            if records:
                start = len(summary)
                for record in records:
                    summary += _record(record)
                at, length = summary_start + start, len(summary) - start
                offsets.append(SummaryOffset(group_opcode=opcode, group_start=at, group_length=length))
        summary_offset_start = summary_start + len(summary)
        for offset in offsets:
            summary += _record(offset)
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start), crc)
        footer = Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc)
        tail = b"".join((data_end, summary, _record(footer), MCAP0_MAGIC))
        self._state = state._replace(unwritten=(end_offset, tail), finished=True)
        self._settle()
