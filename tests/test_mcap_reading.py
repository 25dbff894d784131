"""McapInput.messages reads chunks that follow one another in time on its own, and falls back to the
mcap library's merge when they overlap: the order is the library's either way."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader

from mcaplog.mcapio import AtomicMcapWriter, McapInput, to_ns

SCHEMA = {"type": "object"}


def _write(path, times_and_topics, chunk_size):
    with AtomicMcapWriter(path, chunk_size=chunk_size) as w:
        for i, (t_s, topic) in enumerate(times_and_topics):
            w.write_json(topic, "test.Value", SCHEMA, {"i": i}, to_ns(t_s))


def _library_order(path, topics):
    with open(path, "rb") as f:
        return [
            (c.topic, m.log_time, m.data)
            for _, c, m in make_reader(f).iter_messages(topics=topics, log_time_order=True)
        ]


def _ours(path, topics):
    import json

    return [
        (m.topic, m.log_time_ns, json.dumps(m.value, separators=(",", ":")).encode())
        for m in McapInput(path).messages(topics)
    ]


@pytest.mark.parametrize("overlapping", [False, True])
@pytest.mark.parametrize("topics", [None, ["/a"], ["/b", "/c"]])
def test_messages_come_in_the_library_order(tmp_path, overlapping, topics):
    rng = np.random.default_rng(3)
    t = 10.0 + np.cumsum(rng.integers(0, 3, 400)) * 0.01  # repeated times: ties keep their order in the file
    if overlapping:
        t = t + rng.normal(0, 0.2, t.size)  # written out of time order: chunks overlap in time
    items = [(float(x), ["/a", "/b", "/c"][k]) for x, k in zip(t, rng.integers(0, 3, t.size), strict=True)]
    path = tmp_path / "m.mcap"
    _write(path, items, chunk_size=512)  # many small chunks
    ours = _ours(path, topics)
    assert len(ours) == sum(1 for _, tp in items if topics is None or tp in topics)
    assert ours == _library_order(path, topics)
    times = [lt for _, lt, _ in ours]
    assert times == sorted(times)


@pytest.mark.parametrize("overlapping", [False, True])
def test_select_passes_over_the_others_in_the_same_order(tmp_path, overlapping):
    """`messages(topics, select)`: the n-th message of `topics` is yielded when `select(n)` is true, n counted
    in the order of the whole read, in both the chunk-by-chunk and the library's merged reading."""
    rng = np.random.default_rng(5)
    t = 10.0 + np.cumsum(rng.integers(0, 3, 300)) * 0.01
    if overlapping:
        t = t + rng.normal(0, 0.2, t.size)
    items = [(float(x), ["/a", "/b"][k]) for x, k in zip(t, rng.integers(0, 2, t.size), strict=True)]
    path = tmp_path / "m.mcap"
    _write(path, items, chunk_size=512)
    every = [(m.log_time_ns, m.value) for m in McapInput(path).messages(["/a"])]
    wanted = {0, 1, 7, 50, 51, 52, len(every) - 1}
    asked = []

    def select(n):
        asked.append(n)
        return n in wanted

    picked = [(m.log_time_ns, m.value) for m in McapInput(path).messages(["/a"], select)]
    assert picked == [every[n] for n in sorted(wanted)]
    assert asked == list(range(len(every)))  # asked once each, in order


def test_a_damaged_chunk_raises(tmp_path):
    path = tmp_path / "m.mcap"
    _write(path, [(i * 0.1, "/a") for i in range(200)], chunk_size=512)
    data = bytearray(path.read_bytes())
    data[300:340] = b"\xff" * 40  # inside the first chunk's compressed data
    path.write_bytes(bytes(data))
    with pytest.raises(Exception):  # noqa: B017 - any error: the pipeline turns it into one line
        _ours(path, None)
