"""mcaplog.writer.McapWriter: files the `mcap` library reads back whole, through its index and as a stream
with every CRC checked."""

from __future__ import annotations

import io
import struct
import sys
import zlib

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    Footer,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import StreamReader, get_chunk_data_stream
from mcap.writer import MCAP0_MAGIC

from mcaplog import writer as writer_module
from mcaplog.writer import McapWriter


def _write(messages: list[tuple[int, int, bytes]], chunk_size: int, metadata_at: int = -1) -> bytes:
    out = io.BytesIO()
    w = McapWriter(out, chunk_size=chunk_size)
    w.start(profile="test", library="gslam-test")
    schema = w.register_schema("t.Json", "jsonschema", b"{}")
    channels = [w.register_channel(f"/topic/{k}", "json", schema, {"k": str(k)}) for k in range(3)]
    for i, (c, t, data) in enumerate(messages):
        if i == metadata_at:
            w.add_metadata("between", {"at": str(i)})
        w.add_message(channels[c], t, data, t, sequence=i)
    w.add_metadata("end", {"messages": str(len(messages))})
    w.finish()
    return out.getvalue()


def _messages(n: int, seed: int) -> list[tuple[int, int, bytes]]:
    rng = np.random.default_rng(seed)
    times = 1_000_000_000 + np.cumsum(rng.integers(0, 50_000_000, n))
    times[n // 2] -= 900_000_000  # a message out of order
    return [
        (int(rng.integers(0, 3)), int(t), bytes(rng.integers(0, 256, int(rng.integers(0, 300)), dtype=np.uint8)))
        for t in times
    ]


def test_messages_summary_and_metadata_read_back_through_the_index_over_many_chunks() -> None:
    sent = _messages(400, seed=1)
    data = _write(sent, chunk_size=4096, metadata_at=150)
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    assert summary.statistics.message_count == len(sent)
    assert len(summary.chunk_indexes) > 10  # many chunks, each indexed
    assert summary.statistics.chunk_count == len(summary.chunk_indexes)
    assert summary.statistics.message_start_time == min(t for _, t, _ in sent)
    assert summary.statistics.message_end_time == max(t for _, t, _ in sent)
    for k in range(3):
        assert summary.statistics.channel_message_counts[k + 1] == sum(c == k for c, _, _ in sent)
    assert [ch.topic for ch in summary.channels.values()] == ["/topic/0", "/topic/1", "/topic/2"]
    got = [(ch.id - 1, m.log_time, m.data, m.sequence) for _, ch, m in reader.iter_messages(log_time_order=False)]
    assert got == [(c, t, d, i) for i, (c, t, d) in enumerate(sent)]
    in_order = [m.log_time for _, _, m in reader.iter_messages(log_time_order=True)]
    assert in_order == sorted(t for _, t, _ in sent)
    assert {m.name: m.metadata for m in reader.iter_metadata()} == {
        "between": {"at": "150"},
        "end": {"messages": "400"},
    }


def test_every_record_parses_as_a_stream_with_its_crcs_checked() -> None:
    sent = _messages(200, seed=2)
    kinds: dict[str, int] = {}
    records = StreamReader(io.BytesIO(_write(sent, chunk_size=2048)), validate_crcs=True).records
    for record in records:
        kinds[type(record).__name__] = kinds.get(type(record).__name__, 0) + 1
    assert kinds["Message"] == len(sent)
    assert kinds["Header"] == kinds["Footer"] == kinds["DataEnd"] == kinds["Statistics"] == 1
    assert kinds["Schema"] >= 2 and kinds["Channel"] >= 6  # in the first chunk and again in the summary
    assert kinds["ChunkIndex"] > 1 and kinds["MessageIndex"] >= kinds["ChunkIndex"]


def test_a_file_without_messages_is_valid() -> None:
    reader = make_reader(io.BytesIO(_write([], chunk_size=1 << 20)))
    summary = reader.get_summary()
    assert summary.statistics.message_count == 0
    assert list(reader.iter_messages()) == []
    assert [m.name for m in reader.iter_metadata()] == ["end"]


class _InterruptedStream(io.BytesIO):
    """A stream whose `at`-th write is cut by KeyboardInterrupt (a Ctrl-C landing there) after writing the
    fraction `part` of its bytes: none, some (`io.BufferedWriter` runs a signal's handler between the raw
    writes of one call, so a write can be cut part way) or all (a handler run after the last raw write)."""

    def __init__(self, at: int, part: float) -> None:  # at 0: no cut
        super().__init__()
        self.writes = 0
        self.at = at
        self.part = part

    def write(self, data) -> int:
        self.writes += 1
        if self.writes == self.at:
            data = bytes(data)
            super().write(data[: int(len(data) * self.part)])
            raise KeyboardInterrupt
        return super().write(data)


def _cut_run(sent: list[tuple[int, int, bytes]], at: int, part: float) -> tuple | None:
    """`sent` written with the `at`-th write cut (0: none) and the writer finished as `gslam process` does after
    Ctrl-C (again when the cut fell in `finish` itself): the stream, the messages whose `add_message` returned,
    whether the cut fell in one, and the metadata whose `add_metadata` returned; None when it fell in `start`."""
    out = _InterruptedStream(at, part)
    w = McapWriter(out, chunk_size=2048)
    try:
        w.start()
    except KeyboardInterrupt:
        return None  # the header cut: the run cannot begin, its output is dropped (`pipelines.process._open`)
    channel = w.register_channel("/t", "json", w.register_schema("t", "jsonschema", b"{}"))
    done, in_message, metadata = 0, False, []
    try:
        for i, (_, t, data) in enumerate(sent):
            if i == 100:
                w.add_metadata("between", {})
                metadata.append("between")
            in_message = True
            w.add_message(channel, t, data, t)
            in_message = False
            done += 1
        w.finish()
    except KeyboardInterrupt:
        w.finish()
    return out, done, in_message, metadata


def test_a_file_finished_after_a_write_cut_by_an_interruption_holds_every_message() -> None:
    """As `gslam process` does on Ctrl-C: the writer is finished after the interruption, wherever it cut a write
    (a chunk's, a metadata record's, the summary's) and however much of it it had written. The file reads
    whole and holds every message sent until then, the interrupted call's too (a write comes after its
    record was in the chunk), none twice."""
    sent = _messages(300, seed=3)
    total = _cut_run(sent, 0, 0.0)[0].writes
    assert total > 20
    for part in (0.0, 0.5, 1.0):
        for at in range(1, total + 1):
            run = _cut_run(sent, at, part)
            if run is None:
                continue
            out, done, in_message, metadata = run
            messages, got_metadata = _read_whole(out.getvalue())
            assert [d for _, _, d in messages] == [d for _, _, d in sent[: done + in_message]], (at, part)
            assert got_metadata in (metadata, [*metadata, "between"])


# ---- an interruption at any bytecode of the writer ------------------------------------------------------------
_RECORD_HEAD = struct.Struct("<BQ")
_SUMMARY_OPCODES = {Opcode.SCHEMA, Opcode.CHANNEL, Opcode.STATISTICS, Opcode.CHUNK_INDEX, Opcode.METADATA_INDEX}


def _walk(data: bytes, start: int, end: int):
    """(offset, opcode, body) of the records in data[start:end], each checked to end within it."""
    o = start
    while o < end:
        opcode, length = _RECORD_HEAD.unpack_from(data, o)
        body_end = o + _RECORD_HEAD.size + length
        assert body_end <= end, f"the record at {o} runs past its end"
        yield o, opcode, data[o + _RECORD_HEAD.size : body_end]
        o = body_end


def _parse(record_type, body: bytes):
    stream = ReadDataStream(io.BytesIO(body))
    return record_type.read(stream, len(body)) if record_type is Message else record_type.read(stream)


def _read_whole(data: bytes) -> tuple[list[tuple[str, int, bytes]], list[str]]:
    """The messages (topic, log time, data) and metadata names of an MCAP, in file order, after checking that
    it is whole and agrees with itself: the data section walked record by record (every chunk's CRC, its
    start and end times, its message indexes entry by entry, a channel and schema record before any message
    of theirs and never two different ones under one id), the summary (chunk and metadata indexes pointing
    at those records, statistics counting them, its CRC), and the `mcap` library's readers (through the
    index and as a stream with CRCs checked) reading the same."""
    assert data[:8] == MCAP0_MAGIC and data[-8:] == MCAP0_MAGIC
    footer_at = len(data) - 8 - _RECORD_HEAD.size - 20
    assert _RECORD_HEAD.unpack_from(data, footer_at) == (Opcode.FOOTER, 20)
    footer = _parse(Footer, data[footer_at + _RECORD_HEAD.size : -8])
    crc = zlib.crc32(data[footer.summary_start : footer_at + _RECORD_HEAD.size + 16])
    assert crc == footer.summary_crc
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: list[tuple[str, int, bytes]] = []
    metadata: list[str] = []
    chunks: list[ChunkIndex] = []
    metadata_indexes: list[MetadataIndex] = []
    counts: dict[int, int] = {}
    pending: dict[int, list[tuple[int, int]]] | None = None  # the last chunk's message indexes still to come
    chunk_at = chunk_length = 0
    records = list(_walk(data, 8, footer.summary_start))
    assert records[0][1] == Opcode.HEADER and records[-1][1] == Opcode.DATA_END
    for o, opcode, body in records[1:-1]:
        if pending is not None and opcode != Opcode.MESSAGE_INDEX:
            assert not pending, f"message indexes missing after the chunk at {chunk_at}: {sorted(pending)}"
            pending = None
        if opcode == Opcode.CHUNK:
            chunk = _parse(Chunk, body)
            stream, size = get_chunk_data_stream(chunk, validate_crc=True)
            inner = stream.read(size)
            assert size == chunk.uncompressed_size == len(inner)
            pending = {}
            for at, inner_op, inner_body in _walk(inner, 0, len(inner)):
                if inner_op in (Opcode.SCHEMA, Opcode.CHANNEL):
                    record = _parse(Schema if inner_op == Opcode.SCHEMA else Channel, inner_body)
                    known = schemas if inner_op == Opcode.SCHEMA else channels
                    assert known.setdefault(record.id, record) == record, f"two records for id {record.id}"
                else:
                    assert inner_op == Opcode.MESSAGE
                    m = _parse(Message, inner_body)
                    assert m.channel_id in channels and channels[m.channel_id].schema_id in schemas
                    messages.append((channels[m.channel_id].topic, m.log_time, m.data))
                    pending.setdefault(m.channel_id, []).append((m.log_time, at))
                    counts[m.channel_id] = counts.get(m.channel_id, 0) + 1
            assert pending, f"the chunk at {o} holds no message"
            times = [t for entries in pending.values() for t, _ in entries]
            assert (chunk.message_start_time, chunk.message_end_time) == (min(times), max(times))
            chunk_at, chunk_length = o, _RECORD_HEAD.size + len(body)
            chunks.append(
                ChunkIndex(
                    message_start_time=chunk.message_start_time,
                    message_end_time=chunk.message_end_time,
                    chunk_start_offset=o,
                    chunk_length=chunk_length,
                    message_index_offsets={},
                    message_index_length=0,
                    compression=chunk.compression,
                    compressed_size=len(chunk.data),
                    uncompressed_size=chunk.uncompressed_size,
                )
            )
        elif opcode == Opcode.MESSAGE_INDEX:
            index = _parse(MessageIndex, body)
            assert pending is not None and pending.pop(index.channel_id) == index.records
            chunks[-1].message_index_offsets[index.channel_id] = o
            chunks[-1].message_index_length = o + _RECORD_HEAD.size + len(body) - chunk_at - chunk_length
        else:
            assert opcode == Opcode.METADATA, f"record {opcode:#x} at {o} in the data section"
            metadata.append(_parse(Metadata, body).name)
            metadata_indexes.append(MetadataIndex(offset=o, length=_RECORD_HEAD.size + len(body), name=metadata[-1]))
    assert not pending
    summary: dict[int, list] = {}
    summary_end = footer.summary_offset_start
    for _, opcode, body in _walk(data, footer.summary_start, summary_end):
        assert opcode in _SUMMARY_OPCODES
        record_type = {
            Opcode.SCHEMA: Schema,
            Opcode.CHANNEL: Channel,
            Opcode.STATISTICS: Statistics,
            Opcode.CHUNK_INDEX: ChunkIndex,
            Opcode.METADATA_INDEX: MetadataIndex,
        }[opcode]
        summary.setdefault(opcode, []).append(_parse(record_type, body))
    assert summary.get(Opcode.CHUNK_INDEX, []) == chunks
    assert summary.get(Opcode.METADATA_INDEX, []) == metadata_indexes
    summary_schemas = {s.id: s for s in summary.get(Opcode.SCHEMA, [])}
    summary_channels = {c.id: c for c in summary.get(Opcode.CHANNEL, [])}
    assert all(summary_schemas[i] == s for i, s in schemas.items())
    assert all(summary_channels[i] == c for i, c in channels.items())
    assert all(c.schema_id in summary_schemas for c in summary_channels.values())
    [statistics] = summary[Opcode.STATISTICS]
    times = [t for _, t, _ in messages] or [0]
    assert statistics == Statistics(
        message_count=len(messages),
        schema_count=len(summary_schemas),
        channel_count=len(summary_channels),
        attachment_count=0,
        metadata_count=len(metadata),
        chunk_count=len(chunks),
        message_start_time=min(times),
        message_end_time=max(times),
        channel_message_counts=counts,
    )
    for _, opcode, body in _walk(data, summary_end, footer_at):
        assert opcode == Opcode.SUMMARY_OFFSET
        offset = _parse(SummaryOffset, body)
        assert [r for _, r, _ in _walk(data, offset.group_start, offset.group_start + offset.group_length)] == [
            offset.group_opcode
        ] * len(summary[offset.group_opcode])
    reader = make_reader(io.BytesIO(data))
    by_index = [(ch.topic, m.log_time, m.data) for _, ch, m in reader.iter_messages(log_time_order=False)]
    assert by_index == messages
    assert [m.name for m in reader.iter_metadata()] == metadata
    streamed = list(StreamReader(io.BytesIO(data), validate_crcs=True).records)
    assert [m.data for m in streamed if isinstance(m, Message)] == [d for _, _, d in messages]
    return messages, metadata


class _CutAt:
    """Raises KeyboardInterrupt at the `at`-th line or bytecode executed in mcaplog/writer.py (as a signal's
    handler does: Python runs it between two bytecodes), through `sys.settrace`; `events` counts them
    (all of them when `at` is 0) and `where` says where the cut fell."""

    FILE = writer_module.__file__

    def __init__(self, at: int) -> None:
        self.at = at
        self.events = 0
        self.where: tuple[str, int] | None = None

    def __enter__(self) -> _CutAt:
        sys.settrace(self._call)
        return self

    def __exit__(self, *exc) -> None:
        sys.settrace(None)

    def _call(self, frame, event, arg):
        if self.where is not None or frame.f_code.co_filename != self.FILE:
            return None
        frame.f_trace_opcodes = True
        return self._event

    def _event(self, frame, event, arg):
        if event in ("line", "opcode") and self.where is None:
            self.events += 1
            if self.events == self.at:
                self.where = (frame.f_code.co_name, frame.f_lineno)
                raise KeyboardInterrupt  # tracing stops here (Python drops a trace function that raises)
        return self._event


def _plan(seed: int) -> list[tuple]:
    """A run's writes: messages on two topics crossing several chunk boundaries (chunks of 512 bytes), a
    third topic and its own schema registered mid-run, and metadata between chunks."""
    rng = np.random.default_rng(seed)
    plan: list[tuple] = []
    t = 1_000_000_000
    for i in range(24):
        if i == 9:
            plan.append(("metadata", "between"))
        topic = "/c" if i >= 14 and i % 3 == 0 else ("/a", "/b")[i % 2]
        t += int(rng.integers(0, 50_000_000))
        plan.append(("message", topic, t, bytes(rng.integers(0, 256, int(rng.integers(20, 140)), dtype=np.uint8))))
    return plan


class _Run:
    """Writes a plan as `AtomicMcapWriter` does (a topic's schema and channel are registered with its first
    message; an id is known only once its registration has returned) and notes the calls that returned."""

    def __init__(self, w: McapWriter) -> None:
        self.w = w
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.returned: list[tuple] = []

    def channel(self, topic: str) -> int:
        if topic not in self.channels:
            schema = "c.Json" if topic in ("/c", "/final") else "ab.Json"
            if schema not in self.schemas:
                self.schemas[schema] = self.w.register_schema(schema, "jsonschema", schema.encode())
            self.channels[topic] = self.w.register_channel(topic, "json", self.schemas[schema])
        return self.channels[topic]

    def do(self, op: tuple) -> None:
        if op[0] == "metadata":
            self.w.add_metadata(op[1], {"at": str(len(self.returned))})
        else:
            _, topic, t, data = op
            self.w.add_message(self.channel(topic), t, data, t)
        self.returned.append(op)


def _interrupted_at(plan: list[tuple], at: int) -> tuple[bytes, _Run, _CutAt]:
    """The plan written with a KeyboardInterrupt at the `at`-th event (0: none), then finished as `gslam
    process` finishes a result after Ctrl-C: more messages (a new topic among them), the result's metadata,
    `finish`."""
    out = io.BytesIO()
    w = McapWriter(out, chunk_size=512)
    w.start(profile="test", library="gslam-test")
    run = _Run(w)
    with _CutAt(at) as cut:
        try:
            for op in plan:
                run.do(op)
        except KeyboardInterrupt:
            assert cut.where is not None
    tail = [("message", "/final", 9_000_000_000, b"final"), ("message", "/a", 9_000_000_000, b"trajectory")]
    for op in [*tail, ("metadata", "result")]:
        run.do(op)
    w.finish()
    return out.getvalue(), run, cut


def test_an_interruption_at_any_bytecode_of_the_writer_loses_no_message_and_writes_none_twice() -> None:
    """A KeyboardInterrupt at every line and bytecode the writer runs for a sequence of writes crossing several
    chunk boundaries (the chunk hand-over, its indexes and counts, the registrations, the metadata), then the
    file finished as after Ctrl-C: it reads whole and holds every message whose `add_message` returned, in
    order, none twice, and the interrupted call's message exactly when the cut came after its commit (its
    record appended to the pending chunk): for the cuts within one call, lost before some point, kept after."""
    plan = _plan(seed=4)
    sent = [(op[1], op[2], op[3]) for op in plan if op[0] == "message"]
    tail = [("/final", 9_000_000_000, b"final"), ("/a", 9_000_000_000, b"trajectory")]
    data, run, cut = _interrupted_at(plan, 0)
    assert _read_whole(data) == (sent + tail, ["between", "result"])
    total = cut.events
    assert total > 2000  # every line and bytecode of the writer, not a sample
    kept_by_call: dict[int, list[bool]] = {}
    where: dict[str, int] = {}
    for at in range(1, total + 1):
        data, run, cut = _interrupted_at(plan, at)
        assert cut.where is not None
        where[cut.where[0]] = where.get(cut.where[0], 0) + 1
        call = len(run.returned) - 3  # the plan's call the cut fell in (3: the tail's calls)
        messages, metadata = _read_whole(data)
        done = sum(op[0] == "message" for op in plan[:call])
        assert messages[-len(tail) :] == tail, f"cut at {cut.where} (event {at})"
        got = messages[: -len(tail)]
        assert got in (sent[:done], sent[: done + 1]), f"cut at {cut.where} (event {at}): {len(got)} of {done}"
        kept = len(got) == done + 1
        assert not kept or plan[call][0] == "message"
        between = "between" in metadata
        assert metadata == ["between", "result"] if between else ["result"]
        if plan[call][0] == "metadata":
            kept = between
        else:
            assert between == (call > plan.index(("metadata", "between")))
        kept_by_call.setdefault(call, []).append(kept)
    for call, kept in kept_by_call.items():
        assert kept == sorted(kept), f"call {call} ({plan[call][0]}): kept, then lost again at a later cut"
    assert any(kept[-1] for kept in kept_by_call.values()) and any(not k[0] for k in kept_by_call.values())
    assert {"add_message", "register_channel", "register_schema", "add_metadata"} <= set(where)
