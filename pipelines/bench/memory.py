"""Does memory stay flat in the log's length? One `gslam process` run (MCAP and Rerun outputs written,
as a user runs it), with the peak resident memory (ru_maxrss) read after the first K scans and at the
end: a flat profile has the two within a small factor (docs/RELIABILITY.md: within 1.5x).

    python -m pipelines.bench.memory INPUT.mcap --first 2000 -N 30 [--max-scans S] [--json]
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from gslam.config import FilterConfig
from pipelines.process import peak_rss_mb as peak_rss_mib  # this process's own peak (VmHWM), in MiB
from pipelines.process import process
from pipelines.run.runner import RunConfig


def current_rss_mib() -> float:
    """Resident memory now [MiB] (Linux /proc; the peak elsewhere)."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
    except (OSError, IndexError, ValueError):
        return peak_rss_mib()
    return pages * resource.getpagesize() / 2**20


@dataclass
class MemoryReport:
    input: str
    particles: int
    first_scans: int
    scans: int
    peak_first_mib: float
    rss_first_mib: float
    peak_all_mib: float
    rss_end_mib: float
    wall_s: float

    @property
    def ratio(self) -> float:
        return self.peak_all_mib / self.peak_first_mib

    def describe(self) -> str:
        return (
            f"{self.input}, N {self.particles}: peak RSS {self.peak_first_mib:.0f} MiB over the first "
            f"{self.first_scans} scans, {self.peak_all_mib:.0f} MiB over all {self.scans} "
            f"(x{self.ratio:.2f}); RSS at the end {self.rss_end_mib:.0f} MiB; {self.wall_s:.0f} s"
        )


def measure(input_mcap: Path, cfg: RunConfig, first: int, rrd: bool = True) -> MemoryReport:
    """Process `input_mcap` once, recording the peak RSS after `first` scans and at the end."""
    marks: dict[str, float] = {}

    def progress(done: int, total: int, *_) -> None:
        if done == first:
            marks["peak_first"] = peak_rss_mib()
            marks["rss_first"] = current_rss_mib()

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="gslam-memory-") as tmp:
        out = Path(tmp) / "result.mcap"
        summary = process(input_mcap, out, out.with_suffix(".rrd") if rrd else None, cfg, progress)
    if "peak_first" not in marks:
        raise ValueError(f"the run had {summary.steps} scans, fewer than --first {first}")
    return MemoryReport(
        input=str(input_mcap),
        particles=cfg.filter.particles,
        first_scans=first,
        scans=summary.steps,
        peak_first_mib=marks["peak_first"],
        rss_first_mib=marks["rss_first"],
        peak_all_mib=peak_rss_mib(),
        rss_end_mib=current_rss_mib(),
        wall_s=time.perf_counter() - t0,
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipelines.bench.memory", description=__doc__.splitlines()[0])
    parser.add_argument("input", type=Path, help="input MCAP from `gslam ingest`")
    parser.add_argument("--first", type=int, default=2000, help="scans of the first measurement (default 2000)")
    parser.add_argument("-N", "--particles", type=int, default=FilterConfig.particles)
    parser.add_argument("--max-scans", type=int, default=None, help="stop after this many scans (default: all)")
    parser.add_argument("--no-rrd", action="store_true", help="do not write the Rerun recording")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    if args.first < 1 or (args.max_scans is not None and args.max_scans < args.first):
        parser.error("--first must be at least 1 and at most --max-scans")
    cfg = RunConfig(filter=FilterConfig(particles=args.particles), max_scans=args.max_scans)
    report = measure(args.input, cfg, args.first, rrd=not args.no_rrd)
    print(json.dumps(asdict(report) | {"ratio": report.ratio}, indent=2) if args.json else report.describe())
    return 0


if __name__ == "__main__":
    sys.exit(main())
