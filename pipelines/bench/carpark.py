"""`gslam bench`: the paper's Table 3 on the Car Park log, beside the paper's figures."""

from __future__ import annotations

import os
import platform
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from gslam import __version__
from gslam.config import FilterConfig
from pipelines.bench.tasks import Task, run_task
from pipelines.methods import METHODS, NAMES

# Table 3 of the paper: (N, M) -> (ms per step, position error m).
PAPER_TABLE3: dict[tuple[int, int], tuple[float, float]] = {
    (2, 4): (22, 1.55),
    (2, 10): (28, 1.15),
    (2, 20): (33, 1.19),
    (8, 4): (74, 0.44),
    (8, 10): (81, 0.41),
    (8, 20): (92, 0.40),
    (30, 4): (278, 0.42),
    (30, 10): (294, 0.40),
    (30, 20): (314, 0.40),
}
FULL_GRID = [(n, m) for n in (2, 8, 30) for m in (4, 10, 20)]
QUICK_GRID = [(2, 4), (8, 10)]
# Table 4 of the paper: (method, N) -> (ms per step, position error m).
PAPER_TABLE4: dict[tuple[str, int], tuple[float, float]] = {
    ("gslam", 2): (22, 1.55),
    ("fastslam1", 2): (12, 0.84),
    ("fastslam2", 2): (31, 0.47),
    ("gslam", 8): (81, 0.41),
    ("fastslam1", 8): (51, 0.62),
    ("fastslam2", 8): (101, 0.42),
    ("gslam", 30): (294, 0.40),
    ("fastslam1", 30): (148, 0.43),
    ("fastslam2", 30): (281, 0.40),
    ("grid", 2): (14, 1.04),
    ("grid-hr", 2): (180, 1.10),
    ("grid", 8): (46, 0.57),
    ("grid-hr", 8): (648, 0.41),
    ("grid", 30): (221, 0.40),
    ("grid-hr", 30): (1943, 0.41),
}


@dataclass
class CellResult:
    particles: int
    points: int
    method: str = "gslam"
    errors_m: list[float] = field(default_factory=list)
    online_errors_m: list[float] = field(default_factory=list)
    filter_ms: list[float] = field(default_factory=list)
    filter_mean_ms: list[float] = field(default_factory=list)
    end_to_end_ms: list[float] = field(default_factory=list)
    rtf: list[float] = field(default_factory=list)
    map_points: list[int] = field(default_factory=list)


def machine_description() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, {platform.system()}"


def versions() -> str:
    import numpy
    import rerun
    import scipy

    return f"gslam {__version__}, numpy {numpy.__version__}, scipy {scipy.__version__}, rerun-sdk {rerun.__version__}"


def run_bench(
    input_mcap: Path,
    grid: list[tuple[int, int]],
    seeds: int,
    progress: Callable[[str], None] | None = None,
    base: FilterConfig | None = None,
    methods: tuple[str, ...] = ("gslam",),
) -> list[CellResult]:
    """Run every (N, M) cell of G-SLAM, and every N of the baselines (M does not apply to them), for
    `seeds` seeds, end to end (MCAP and Rerun written), and evaluate."""
    results = []
    base_dict = (base or FilterConfig()).as_dict()
    runs = []  # the methods that take M over the whole grid first, then the others at each N
    for name in sorted(methods, key=lambda name: not METHODS[name].takes_points):
        if METHODS[name].takes_points:
            runs += [(name, n, m) for n, m in grid]
        else:
            runs += [(name, n, 0) for n in sorted({n for n, _ in grid})]
    # the base options besides those each task sets
    options = {k: v for k, v in base_dict.items() if k not in ("particles", "points_per_observation", "seed")}
    with tempfile.TemporaryDirectory(prefix="gslam-bench-") as tmp:
        for method, n, m in runs:
            cell = CellResult(n, m, method)
            for seed in range(seeds):
                task = Task(input_mcap, method, n, max(m, 1), seed, options)
                out = Path(tmp) / f"{method}_n{n}_m{m}_s{seed}.mcap"
                t0 = time.perf_counter()
                run = run_task(task, out, out.with_suffix(".rrd"), command="gslam bench")
                metrics, result = run.metrics, run.result
                cell.errors_m.append(metrics["gps_mean_error_m"])
                cell.online_errors_m.append(metrics["gps_mean_error_online_m"])
                cell.filter_ms.append(result["ms_per_step_filter_median"])
                cell.filter_mean_ms.append(result["ms_per_step_filter_mean"])
                cell.end_to_end_ms.append(result["ms_per_step_median"])
                cell.rtf.append(result["real_time_factor"])
                cell.map_points.append(result["final_map_points"])
                if progress is not None:
                    progress(
                        f"{method} N {n:>2} M {m:>2} seed {seed}: {metrics['gps_mean_error_m']:.2f} m, "
                        f"{result['ms_per_update_mean']:.1f} ms per update ({time.perf_counter() - t0:.0f} s)"
                    )
            results.append(cell)
    return results


def _mean_sd(values: list[float]) -> str:
    if len(values) == 1:
        return f"{values[0]:.2f}"
    return f"{statistics.mean(values):.2f} ± {statistics.stdev(values):.2f}"


def markdown_table(results: list[CellResult], seeds: int, command: str, wall_s: float) -> str:
    d = FilterConfig()  # the schedule the runs used, as it is now
    lines = [
        "## Car Park log: the paper's Tables 3 and 4",
        "",
        f"- Command: `{command}`",
        f"- Machine: {machine_description()}",
        f"- Software: {versions()}",
        f"- Date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; wall time {wall_s:.0f} s",
        f"- Data: ACFR Car Park log (586 scans, 125 s); {seeds} seed(s) per cell (0..{seeds - 1}).",
        "- Position error: mean distance of the final best trajectory to each GPS fix, run tied to GPS at the",
        "  start (paper's metric); mean ± standard deviation over seeds. Online: the filtered estimate.",
        "- ms/step: wall time of a scan step, filter alone (median and mean) and end to end (median, with MCAP",
        "  and Rerun writing); per-run figures, then their median over seeds. With the default update schedule",
        f"  (`travel`: the map and weights are updated after {d.min_travel_m:g} m or {d.min_turn_rad:g} rad, other "
        "scans only predict) the",
        "  median is a prediction step and the mean carries the updates. RTF: log duration / processing time.",
        "",
        "### Table 3: G-SLAM, N particles x M new points per observation",
        "",
        "| N | M | error (m) | online error (m) | paper error (m) | ms/step filter median / mean "
        "| ms/step end to end | paper ms/step | RTF | final map points | paper map |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in (c for c in results if c.method == "gslam"):
        paper = PAPER_TABLE3.get((c.particles, c.points))
        paper_ms = f"{paper[0]:.0f}" if paper else "-"
        paper_err = f"{paper[1]:.2f}" if paper else "-"
        paper_map = "~3280" if (c.particles, c.points) == (8, 10) else "-"
        lines.append(
            f"| {c.particles} | {c.points} | {_mean_sd(c.errors_m)} | {_mean_sd(c.online_errors_m)} | {paper_err} "
            f"| {statistics.median(c.filter_ms):.1f} / {statistics.median(c.filter_mean_ms):.1f} "
            f"| {statistics.median(c.end_to_end_ms):.1f} | {paper_ms} "
            f"| {statistics.median(c.rtf):.1f} | {statistics.median(c.map_points):.0f} | {paper_map} |"
        )
    baselines = [c for c in results if c.method != "gslam"]
    if baselines:
        # Table 4 compares G-SLAM at (2, 4), (8, 10), (30, 10) with the baselines at the same N.
        table4 = [c for c in results if c.method == "gslam" and (c.particles, c.points) in ((2, 4), (8, 10), (30, 10))]
        lines += [
            "",
            "### Table 4: G-SLAM and the baselines",
            "",
            "FastSLAM observes the reflective poles (beams with intensity > 0 grouped into pole centres).",
            "",
            "| method | N | M | error (m) | paper error (m) | ms/step filter median / mean | paper ms/step "
            "| final map (points or landmarks) |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for c in sorted(table4 + baselines, key=lambda c: (c.particles, NAMES.index(c.method))):
            paper = PAPER_TABLE4.get((c.method, c.particles))
            lines.append(
                f"| {c.method} | {c.particles} | {c.points or '-'} | {_mean_sd(c.errors_m)} "
                f"| {f'{paper[1]:.2f}' if paper else '-'} "
                f"| {statistics.median(c.filter_ms):.1f} / {statistics.median(c.filter_mean_ms):.1f} "
                f"| {f'{paper[0]:.0f}' if paper else '-'} | {statistics.median(c.map_points):.0f} |"
            )
    lines += ["", "The paper's times are from its own (unstated) machine and implementation.", ""]
    return "\n".join(lines)
