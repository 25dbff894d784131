"""`gslam bench --suite continue`: a map that goes on across mapping runs, on the robustness suite's corpus
and the Car Park.

Each log is cut in two at its middle scan (`cut_input`: two input MCAPs, the second with the odometry of the
second before its first scan). Per seed: the whole log mapped at once; the first half mapped; the second
half mapped from nothing ("alone") and continued from the first half's result (`gslam process B OUT
--continue A`, the start found by the run itself). The second half's relations error (the relations with
both stamps in it; on a log with GPS and no relations, the Car Park, the mean distance to the GPS fixes in
its time) is compared with the whole run's on the same references: continuing should be as good as
mapping the log at once, and better than mapping the half alone.

Also recorded: where the continued run found itself (the scan and the travel), the closures between the
runs, the merged map's size against the whole run's (places seen again updated, not doubled), the bytes a
result holds for a run to continue it (the final map, the graph and its scans) and how long loading them
takes (`pipelines.run.continuation.load_previous`, median of 3).
"""

from __future__ import annotations

import math
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

import numpy as np

from mcaplog import channels as ch
from pipelines.bench.suites import section_head

if TYPE_CHECKING:
    from mcap.reader import McapReader
    from mcap.writer import Writer

CONTINUE_CHANNELS = (
    ch.SLAM_MAP_FINAL,
    ch.SLAM_GRAPH,
    ch.SLAM_GRAPH_SCANS,
    ch.SLAM_SESSIONS,
    ch.SLAM_EARLIER_MAPS,
    ch.SLAM_EARLIER_GRAPHS,
    ch.SLAM_EARLIER_GRAPH_SCANS,
)
"""What a result holds for a run that continues it (besides its trajectory, which it holds anyway); the
earlier maps' channels are there only where a run mapped apart (`--if-lost new`)."""


def mirrored_writer(out: BinaryIO, reader: McapReader) -> tuple[Writer, dict[int, int]]:
    """An MCAP writer on `out`, started as the file `reader` reads (its header's profile and library) and
    holding its schemas, channels and metadata: (the writer, the reader's channel ids to the writer's). What
    a copy of the file, whole or in part, is written with."""
    from mcap.writer import Writer

    header, summary = reader.get_header(), reader.get_summary()
    w = Writer(out)
    w.start(profile=header.profile, library=header.library)
    schemas = {s.id: w.register_schema(s.name, s.encoding, s.data) for s in summary.schemas.values()}
    channels = {
        c.id: w.register_channel(c.topic, c.message_encoding, schemas.get(c.schema_id, 0), c.metadata)
        for c in summary.channels.values()
    }
    for m in reader.iter_metadata():
        w.add_metadata(m.name, m.metadata)
    return w, channels


def cut_input(src: Path, at_scan: int, first: Path, second: Path) -> float:
    """Cut the input MCAP `src` at scan `at_scan` into `first` (the scans before it) and `second` (that scan
    and the rest, with every other message of the second before it: the odometry its first scan needs);
    messages written once (relations, landmarks) go to both, with the metadata. Returns the cut's log time
    (s)."""
    from mcap.reader import make_reader

    with open(src, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        counts = summary.statistics.channel_message_counts
        scan_ids = {c.id for c in summary.channels.values() if c.topic == ch.LASER}
        times = [m.log_time for _, _, m in reader.iter_messages(topics=[ch.LASER])]
        if not 0 < at_scan < len(times):
            raise ValueError(f"{src}: cannot cut its {len(times)} scans at scan {at_scan}")
        cut = times[at_scan]
        outs = []
        for path in (first, second):
            fo = open(path, "wb")
            outs.append((fo, *mirrored_writer(fo, reader)))
        for _, c, m in reader.iter_messages(log_time_order=True):
            once = counts.get(c.id, 0) == 1
            lead = c.id not in scan_ids and m.log_time >= cut - 1_000_000_000
            for k, wanted in enumerate((once or m.log_time < cut, once or m.log_time >= cut or lead)):
                if wanted:
                    _, w, channels = outs[k]
                    w.add_message(channels[c.id], m.log_time, m.data, m.publish_time)
        for fo, w, _ in outs:
            w.finish()
            fo.close()
    return cut / 1e9


@dataclass
class ContinueRun:
    log: str
    seed: int
    scans: int
    whole: tuple[float, float]
    """The whole log mapped at once, scored on the second half's relations (m, deg) or GPS fixes (m, NaN)."""
    alone: tuple[float, float]
    """The second half mapped from nothing."""
    continued: tuple[float, float]
    """The second half continued from the first half's result."""
    references: int
    """The relations (or, on a log with GPS and no relations, the GPS fixes) the errors are scored on."""
    start: dict
    between_runs: int
    """Closures kept between the two runs."""
    map_points: tuple[int, int]
    """(whole run, continued run): final map points."""
    saved_bytes: int
    """The first half's result's channels a continuation reads (`CONTINUE_CHANNELS`) ..."""
    result_bytes: int
    """... and the whole result file."""
    load_s: float
    wall_s: float
    """The continued run's, whole command."""

    @property
    def reference(self) -> str:
        """What the errors are scored on: "relations", or "GPS fixes" (no rotation)."""
        return "GPS fixes" if math.isnan(self.continued[1]) else "relations"


def _references(input_mcap: Path) -> tuple[np.ndarray, np.ndarray]:
    """The log's relations (R, 5) and GPS fixes (G, 3: t, x, y); empty where it has none."""
    from mcaplog.mcapio import McapInput
    from pipelines.evaluation.evaluate import reference_truth

    gps, _, rel = reference_truth(McapInput(input_mcap))
    return (np.empty((0, 5)) if rel is None else rel), (np.empty((0, 3)) if gps is None else gps)


def _scored(result: Path, relations: np.ndarray, gps: np.ndarray) -> tuple[float, float, int]:
    """(translation m, rotation deg, references used): the relations error where there are relations, else
    the mean distance to the GPS fixes (the paper's measure; no rotation)."""
    from pipelines.evaluation.evaluate import read_result
    from pipelines.evaluation.metrics import gps_mean_error, interpolate_positions, relations_error

    data = read_result(result)
    if len(relations) or not len(gps):
        err = relations_error(data.stamp_s, data.trajectory, relations)
        return err["relations_trans_m"], err["relations_rot_deg"], err["relations_used"]
    inside, _ = interpolate_positions(data.t_s, data.trajectory, gps[:, 0])  # the fixes gps_mean_error takes
    return gps_mean_error(data.t_s, data.trajectory, gps), float("nan"), int(np.count_nonzero(inside))


def _channel_bytes(path: Path, topics: tuple[str, ...]) -> int:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        return sum(len(m.data) for _, _, m in reader.iter_messages(topics=list(topics)))


def _process(args: list[str]) -> float:
    import subprocess
    import sys

    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "pipelines.cli", "process", *args], capture_output=True, text=True)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise RuntimeError(f"gslam process {' '.join(args)} failed: {last}")
    return time.perf_counter() - t0


def run_continue_bench(
    inputs: list[tuple[str, Path]], seeds: list[int], progress: Callable[[str], None]
) -> list[ContinueRun]:
    """Every log of `inputs` (name, input MCAP) cut in two and mapped whole, in halves and continued."""
    from mcaplog.mcapio import McapInput
    from pipelines.evaluation.evaluate import read_result
    from pipelines.evaluation.mcap_info import message_count
    from pipelines.run.continuation import load_previous

    runs = []
    with tempfile.TemporaryDirectory(prefix="gslam-bench-continue-") as tmp:
        work = Path(tmp)
        for name, mcap in inputs:
            relations, gps = _references(mcap)
            scans = message_count(McapInput(mcap), ch.LASER) or 0
            first, second = work / f"{name}-a.mcap", work / f"{name}-b.mcap"
            cut_input(mcap, scans // 2, first, second)
            for seed in seeds:
                common = ["--seed", str(seed), "--no-rrd"]
                whole, a, alone, cont = (work / f"{name}-{seed}-{k}.mcap" for k in ("whole", "a", "alone", "cont"))
                _process([str(mcap), str(whole), *common])
                _process([str(first), str(a), *common])
                _process([str(second), str(alone), *common])
                wall = _process([str(second), str(cont), "--continue", str(a), *common])
                loads = []
                for _ in range(3):
                    t0 = time.perf_counter()
                    load_previous(a)
                    loads.append(time.perf_counter() - t0)
                # the relations between the second half's scans (by the sensor stamps they name), or the
                # GPS fixes in its time
                half = read_result(alone)
                since = float(half.stamp_s[0]) - 1e-3
                later = relations[(relations[:, 0] >= since) & (relations[:, 1] >= since)]
                fixes = gps[gps[:, 0] >= float(half.t_s[0])]
                w, al, co = (_scored(r, later, fixes) for r in (whole, alone, cont))
                meta = read_result(cont).metadata
                closure = meta["result"].get("loop_closure") or {}
                run = ContinueRun(
                    name, seed, scans, w[:2], al[:2], co[:2], co[2], meta.get("continuation", {}).get("start", {}),
                    int(closure.get("closures_between_runs", 0)),
                    (int(read_result(whole).metadata["result"]["final_map_points"]),
                     int(meta["result"]["final_map_points"])),
                    _channel_bytes(a, CONTINUE_CHANNELS), a.stat().st_size, statistics.median(loads), wall,
                )  # fmt: skip
                runs.append(run)
                progress(
                    f"continue {name} seed {seed}: whole {w[0]:.3f} m, alone {al[0]:.3f} m, continued {co[0]:.3f} m "
                    f"on {co[2]} {run.reference}; start {run.start.get('how')} at scan {run.start.get('found_at_scan')}"
                )
                for p in (whole, a, alone, cont):
                    p.unlink(missing_ok=True)
    return runs


def _cell(errors: tuple[float, float]) -> str:
    t, r = errors
    return "-" if math.isnan(t) else f"{t:.4f}; " + ("-" if math.isnan(r) else f"{r:.3f}")


def _means(runs: list[ContinueRun]) -> list[str]:
    """Per log, the seeds' means of the three errors, and whether the continued run is at or below the whole
    log mapped at once (translation; rotation)."""
    lines = [
        "",
        "| log | seeds | whole | alone | continued | continued at or below whole |",
        "|---|---|---|---|---|---|",
    ]
    for log in dict.fromkeys(r.log for r in runs):
        mine = [r for r in runs if r.log == log]
        w, a, c = (tuple(np.mean([getattr(r, k) for r in mine], axis=0)) for k in ("whole", "alone", "continued"))
        verdict = "; ".join("-" if math.isnan(c[i]) else "yes" if c[i] <= w[i] else "no" for i in (0, 1))
        lines.append(f"| {log} | {len(mine)} | {_cell(w)} | {_cell(a)} | {_cell(c)} | {verdict} |")
    return lines


def continue_section(runs: list[ContinueRun], command: str, machine: str, software: str) -> str:
    lines = [
        *section_head("## Maps that go on: a log continued from its first half", command, machine, software),
        "- Logs: the robustness suite's corpus (Radish odometry corrupted, odometry seed 0) and the Car Park,",
        "  each cut at its middle scan. Whole: the log mapped at once; alone: the second half mapped from",
        "  nothing; continued: `gslam process SECOND OUT --continue FIRST_RESULT`, the start found by the run",
        "  (two of its scans found in the first half's map; the Car Park's by its controls dead-reckoned).",
        "  Errors: relations with both stamps in the second half (translation m; rotation deg); the Car Park's,",
        "  the mean distance to the GPS fixes in the second half's time (m). Each run N 30 with the defaults.",
        "  Saved: the bytes of the first half's result that a continuation reads (final map, graph, graph",
        "  scans) / the whole file; load: reading them.",
        "",
        "| log | seed | scored on | whole | alone | continued | start found at (scan, travel) "
        "| closures between runs | map points whole / continued | saved (KB) / file (MB) | load (s) | wall (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        start = r.start or {}
        where = f"scan {start.get('found_at_scan')}, {start.get('travel_m', 0):.1f} m" if start else "-"
        lines.append(
            f"| {r.log} | {r.seed} | {r.references} {r.reference} "
            f"| {_cell(r.whole)} | {_cell(r.alone)} | {_cell(r.continued)} "
            f"| {where} | {r.between_runs} | {r.map_points[0]} / {r.map_points[1]} "
            f"| {r.saved_bytes / 1e3:.0f} / {r.result_bytes / 1e6:.1f} | {r.load_s:.2f} | {r.wall_s:.1f} |"
        )
    return "\n".join(lines + _means(runs)) + "\n"
