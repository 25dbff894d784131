"""`gslam bench --suite robustness`: every log of the corpus (`pipelines.bench.corpus`), G-SLAM at N 30 and
with no options at all, GMapping beside it (30 particles, ROS defaults), odometry alone; relations error.

A log passes when G-SLAM's mean over seeds is at or below GMapping's and no seed is worse than twice
GMapping's mean or than odometry alone (the robustness bar).
"""

from __future__ import annotations

import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from pipelines.bench.corpus import CorpusLog, build_corpus
from pipelines.bench.suites import ingest_to, run_gmapping
from pipelines.bench.tasks import Task, run_task
from pipelines.run.input_log import InputLog


@dataclass
class LogResult:
    log: CorpusLog
    odometry_m: float = float("nan")
    gslam_m: dict[int, float] = field(default_factory=dict)
    """Relations error of G-SLAM at N 30, by seed."""
    defaults_m: dict[int, float] = field(default_factory=dict)
    """Relations error of `gslam process IN OUT` with no options, by seed."""
    gmapping_m: dict[int, float] = field(default_factory=dict)
    gslam_wall_s: list[float] = field(default_factory=list)
    gmapping_wall_s: list[float] = field(default_factory=list)
    peak_mb: list[float] = field(default_factory=list)
    gmapping_peak_mb: list[float] = field(default_factory=list)

    def verdict(self) -> str:
        if not self.gslam_m or not self.gmapping_m:
            return "n/a"
        gm = statistics.mean(self.gmapping_m.values())
        mean = statistics.mean(self.gslam_m.values())
        worst = max(self.gslam_m.values())
        fails = []
        if mean > gm:
            fails.append("mean above GMapping's")
        if worst > 2 * gm:
            fails.append("a seed above 2x GMapping")
        if worst > self.odometry_m:
            fails.append("a seed worse than odometry")
        return "holds" if not fails else "; ".join(fails)


def _error(metrics: dict) -> float:
    value = metrics.get("relations_trans_m")
    return float("nan") if value is None else float(value)


def run_robustness(
    datasets: Path,
    seeds: list[int],
    progress: Callable[[str], None],
    gmapping: Path | None = None,
    particles: int = 30,
    corpus_seed: int = 0,
    only: list[str] | None = None,
    workdir: Path | None = None,
) -> list[LogResult]:
    """Run the corpus: odometry alone once, G-SLAM at N `particles` and with its defaults and GMapping for
    every seed. `only`: the names of the logs to run (all by default)."""
    results: list[LogResult] = []
    with tempfile.TemporaryDirectory(prefix="gslam-bench-robustness-") as tmp:
        work = Path(workdir or tmp)
        work.mkdir(parents=True, exist_ok=True)
        for log in build_corpus(datasets, work / "corpus", corpus_seed):
            if only and log.name not in only:
                continue
            mcap = ingest_to(log.log, work)
            if not log.scans:
                log.scans = InputLog(mcap).scan_count
            res = LogResult(log)
            out = work / f"{log.name}-result.mcap"
            res.odometry_m = _error(run_task(Task(mcap, "odometry", 1), out, command="gslam bench robustness").metrics)
            progress(f"robustness: {log.name} odometry alone {res.odometry_m:.3f} m")
            for seed in seeds:
                # a child process, as a user runs it: its wall time and peak memory are this run's own
                run = run_task(Task(mcap, particles=particles, seed=seed), out, child_process=True)
                res.gslam_m[seed] = _error(run.metrics)
                res.gslam_wall_s.append(run.wall_s)
                res.peak_mb.append(float(run.result.get("peak_rss_mb") or float("nan")))
                defaults = Task(mcap, seed=seed)  # N and M: the filter's defaults
                if defaults == run.task:  # the defaults are N `particles`: the same run
                    res.defaults_m[seed] = res.gslam_m[seed]
                else:
                    res.defaults_m[seed] = _error(run_task(defaults, out, child_process=True).metrics)
                line = f"robustness: {log.name} seed {seed}: G-SLAM N {particles} {res.gslam_m[seed]:.3f} m, "
                line += f"defaults {res.defaults_m[seed]:.3f} m"
                if gmapping is not None:
                    try:
                        g = run_gmapping(gmapping, log.log, 30, seed, work)
                    except RuntimeError as e:
                        progress(f"robustness: GMapping not run: {e}")
                        gmapping = None
                    else:
                        res.gmapping_m[seed] = float("nan") if g.trans_m is None else g.trans_m
                        res.gmapping_wall_s.append(g.wall_s)
                        res.gmapping_peak_mb.append(g.peak_mb)
                        line += f", GMapping {res.gmapping_m[seed]:.3f} m"
                progress(line)
            results.append(res)
    return results


def _seeds(values: dict[int, float]) -> str:
    return " / ".join(f"{values[s]:.3f}" for s in sorted(values)) or "-"


def _mean(values: dict[int, float]) -> str:
    return f"{statistics.mean(values.values()):.3f}" if values else "-"


def robustness_section(
    results: list[LogResult], command: str, machine: str, software: str, particles: int, corpus_seed: int
) -> str:
    seeds = sorted({s for r in results for s in r.gslam_m})
    lines = [
        "## Robustness: the corpus, beside GMapping",
        "",
        f"- Command: `{command}`",
        f"- Machine: {machine}",
        f"- Software: {software}",
        f"- Date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}",
        "- Logs: the Freiburg logs with their published relations and real odometry (fr079's is wrong when",
        "  the robot backs up); the Radish corrected logs with odometry corrupted by the documented, seeded",
        f"  models of `pipelines/bench/corpus.py` (corpus seed {corpus_seed}: scale and turn bias, rotation scale,",
        "  noise growing with motion, slip bursts, reverse sign errors, dropouts) and relations built from the",
        "  corrected poses (short ones between successive scans, long ones at revisits).",
        f"- Relations translation error (m), seeds {', '.join(map(str, seeds))}: G-SLAM at N {particles}; G-SLAM",
        "  with no options (`gslam process IN OUT`); GMapping (`../shared/tools/gmapping`, 30 particles, ROS",
        "  defaults, run on the same log on the same machine); odometry alone (`--method odometry`).",
        "- Verdict: G-SLAM's mean at or below GMapping's, and no seed above twice GMapping's mean or above",
        "  odometry alone.",
        "",
        f"| log | scans | odometry alone | G-SLAM N {particles} per seed | mean | defaults per seed "
        "| GMapping per seed | mean | verdict |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r.log.name} | {r.log.scans or '-'} | {r.odometry_m:.3f} | {_seeds(r.gslam_m)} | {_mean(r.gslam_m)} "
            f"| {_seeds(r.defaults_m)} | {_seeds(r.gmapping_m)} | {_mean(r.gmapping_m)} | {r.verdict()} |"
        )
    lines += [
        "",
        "Wall time and peak memory, medians over seeds: G-SLAM's `gslam process` in a child process, import to",
        "exit, with the Rerun recording off (the peak: the filter's process); GMapping's driver under `/usr/bin/time`:",
        "",
        "| log | G-SLAM wall (s) | G-SLAM peak MB | GMapping wall (s) | GMapping peak MB |",
        "|---|---|---|---|---|",
    ]
    med = lambda v: f"{statistics.median(v):.0f}" if v else "-"  # noqa: E731
    for r in results:
        lines.append(
            f"| {r.log.name} | {med(r.gslam_wall_s)} | {med(r.peak_mb)} | {med(r.gmapping_wall_s)} "
            f"| {med(r.gmapping_peak_mb)} |"
        )
    return "\n".join(lines) + "\n"
