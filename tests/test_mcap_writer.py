"""mcaplog.writer.McapWriter: files the `mcap` library reads back whole, through its index and as a stream
with every CRC checked."""

from __future__ import annotations

import io

import numpy as np
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

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
    """A stream whose `at`-th write raises KeyboardInterrupt before writing (a Ctrl-C landing there)."""

    def __init__(self, at: int) -> None:
        super().__init__()
        self.writes = 0
        self.at = at

    def write(self, data) -> int:
        self.writes += 1
        if self.writes == self.at:
            raise KeyboardInterrupt
        return super().write(data)


def test_a_file_finished_after_an_interruption_mid_chunk_is_valid() -> None:
    """As `gslam process` does on Ctrl-C: the interrupted write is lost, the file is finished and reads whole."""
    sent = _messages(300, seed=3)
    for at in (3, 4, 7):  # the first chunk's record, its message indexes, a later chunk
        out = _InterruptedStream(at)
        w = McapWriter(out, chunk_size=2048)
        w.start()
        channel = w.register_channel("/t", "json", w.register_schema("t", "jsonschema", b"{}"))
        done = 0
        try:
            for _, t, data in sent:
                w.add_message(channel, t, data, t)
                done += 1
        except KeyboardInterrupt:
            pass
        assert done < len(sent)
        w.finish()
        data = out.getvalue()
        got = [m.data for _, _, m in make_reader(io.BytesIO(data)).iter_messages(log_time_order=False)]
        # A prefix of what was sent, none twice: the messages of the chunk whose write was cut may be lost,
        # and the interrupted call's own message may be in (the interruption came after its record).
        assert got == [d for _, _, d in sent[: len(got)]] and len(got) <= done + 1
        records = list(StreamReader(io.BytesIO(data), validate_crcs=True).records)
        assert type(records[-1]).__name__ == "Footer"
        assert [r.data for r in records if type(r).__name__ == "Message"] == got  # no chunk written twice
