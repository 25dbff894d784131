"""`gslam info`: what an MCAP file holds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mcaplog.mcapio import NS, McapInput, read_error
from pipelines.errors import InputError


def mcap_info(path: Path) -> dict[str, Any]:
    """Channels with message counts and schemas, start, end, duration [s], and the metadata."""
    src = McapInput(path)
    try:
        summary = src.summary()
        metadata = src.metadata()
    except Exception as e:  # the mcap library raises several types for a damaged file
        raise InputError(f"{path}: not a readable MCAP file ({read_error(e)})") from None
    if summary is None or summary.statistics is None:
        raise InputError(f"{path}: MCAP has no summary section (unfinished file?)")
    stats = summary.statistics
    channels: dict[str, int] = {}
    schemas: dict[str, str] = {}
    for cid, channel in sorted(summary.channels.items(), key=lambda kv: kv[1].topic):
        channels[channel.topic] = int(stats.channel_message_counts.get(cid, 0))
        schema = summary.schemas.get(channel.schema_id)
        schemas[channel.topic] = f"{schema.name} ({channel.message_encoding})" if schema else channel.message_encoding
    start = stats.message_start_time / NS
    end = stats.message_end_time / NS
    return {
        "channels": channels,
        "schemas": schemas,
        "start_s": start,
        "end_s": end,
        "duration_s": end - start,
        "message_count": int(stats.message_count),
        "metadata": metadata,
    }


def message_count(src: McapInput, topic: str) -> int | None:
    """The messages on `topic` by the file's summary section (for progress); None when the file has no
    summary or it cannot be read."""
    try:
        summary = src.summary()
    except Exception:  # a damaged file is reported by the reading that follows
        return None
    if summary is None or summary.statistics is None:
        return None
    counts = summary.statistics.channel_message_counts
    return sum(int(counts.get(cid, 0)) for cid, channel in summary.channels.items() if channel.topic == topic)
