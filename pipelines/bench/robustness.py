"""`gslam bench --suite robustness`: every log of the corpus (`pipelines.bench.corpus`), G-SLAM at N 30 and
with no options at all, its peers beside it, odometry alone; relations error in translation and rotation.

The peers, each as its ROS node runs it with no parameter set: GMapping (30 particles, `run_gmapping`) and
IRIS LaMa in its two modes (`pipelines.bench.lama`): PF-SLAM (30 particles) at the seeds G-SLAM runs, each
shifted by one (`lama_seed`: LaMa's seed 0 is a random one), and online Slam2D once per log (deterministic).

Two verdicts per log:
- the robustness bar: G-SLAM's mean translation error over seeds at or below GMapping's, and no seed worse
  than twice GMapping's mean or than odometry alone (`LogResult.verdict`);
- beside the peers: G-SLAM's mean, in translation and in rotation, at or below the better of the peers'
  means (GMapping, LaMa PF, LaMa Slam2D; `LogResult.peer_verdict`).
"""

from __future__ import annotations

import statistics
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from pipelines.bench.corpus import CorpusLog, build_corpus
from pipelines.bench.lama import MODE_NAMES, LamaRun, lama_note, lama_seed, run_lama
from pipelines.bench.suites import (
    Errors,
    cartographer_lines,
    errors_cell,
    ingest_to,
    peer_verdict,
    run_gmapping,
    section_head,
)
from pipelines.bench.tasks import Task, run_task
from pipelines.run.input_log import InputLog


@dataclass
class LogResult:
    """One corpus log's results: G-SLAM's, its peers' and odometry's relations errors, wall times, peaks."""

    log: CorpusLog
    odometry_m: float = float("nan")
    gslam_m: dict[int, float] = field(default_factory=dict)
    """Relations translation error (m) of G-SLAM at N 30, by seed."""
    defaults_m: dict[int, float] = field(default_factory=dict)
    """Relations error of `gslam process IN OUT` with no options, by seed."""
    gmapping_m: dict[int, float] = field(default_factory=dict)
    gslam_wall_s: list[float] = field(default_factory=list)
    gmapping_wall_s: list[float] = field(default_factory=list)
    peak_mb: list[float] = field(default_factory=list)
    gmapping_peak_mb: list[float] = field(default_factory=list)
    gslam_rot_deg: dict[int, float] = field(default_factory=dict)
    """Relations rotation error (deg) of G-SLAM at N 30, by seed."""
    gmapping_rot_deg: dict[int, float] = field(default_factory=dict)
    lama: list[LamaRun] = field(default_factory=list)
    """LaMa's runs on this log: PF at each seed (`lama_seed`), Slam2D once."""

    def errors(self) -> tuple[Errors, dict[str, Errors]]:
        """G-SLAM's errors (translation, rotation over seeds) and each peer's, by the tables' names."""
        seeds = sorted(self.gslam_m)
        gslam: Errors = ([self.gslam_m[s] for s in seeds], [self.gslam_rot_deg.get(s) for s in seeds])
        gm_seeds = sorted(self.gmapping_m)
        peers: dict[str, Errors] = {
            "GMapping": ([self.gmapping_m[s] for s in gm_seeds], [self.gmapping_rot_deg.get(s) for s in gm_seeds])
        }
        for mode, name in MODE_NAMES.items():
            sel = [r for r in self.lama if r.mode == mode]
            peers[name] = ([r.trans_m for r in sel], [r.rot_deg for r in sel])
        return gslam, peers

    def peer_verdict(self) -> str:
        """Beside the peers: G-SLAM's mean at or below the better peer's, in translation and in rotation."""
        return peer_verdict(*self.errors())

    def verdict(self) -> str:
        """The robustness bar (translation, against GMapping): `holds`, or what fails."""
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


def _error(metrics: dict, key: str = "relations_trans_m") -> float:
    value = metrics.get(key)
    return float("nan") if value is None else float(value)


def _lama_line(r: LamaRun) -> str:
    err = "no relations" if r.trans_m is None else f"{r.trans_m:.3f} m {r.rot_deg:.2f} deg"
    return f"{MODE_NAMES[r.mode]}{f' (seed {r.seed})' if r.mode == 'pf' else ''} {err}"


def run_robustness(
    datasets: Path,
    seeds: list[int],
    progress: Callable[[str], None],
    gmapping: Path | None = None,
    particles: int = 30,
    corpus_seed: int = 0,
    only: list[str] | None = None,
    workdir: Path | None = None,
    lama: Path | None = None,
) -> list[LogResult]:
    """Run the corpus: odometry alone and LaMa Slam2D once, G-SLAM at N `particles` and with its defaults,
    GMapping and LaMa PF (seed `lama_seed(seed)`) for every seed. `gmapping`, `lama`: the harness
    directories (None: that peer left out; one that cannot build or run is said so in one line and left
    out of the rest). `only`: the names of the logs to run (all by default)."""
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
            if lama is not None:
                try:
                    res.lama.append(run_lama(lama, log.log, "slam2d", 0, work))
                except RuntimeError as e:  # e.g. not built and no LAMA_MIRROR to build it from
                    progress(f"robustness: LaMa left out: {e}")
                    lama = None
                else:
                    progress(f"robustness: {log.name} {_lama_line(res.lama[-1])}")
            for seed in seeds:
                # a child process, as a user runs it: its wall time and peak memory are this run's own
                run = run_task(Task(mcap, particles=particles, seed=seed), out, child_process=True)
                res.gslam_m[seed] = _error(run.metrics)
                res.gslam_rot_deg[seed] = _error(run.metrics, "relations_rot_deg")
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
                        res.gmapping_rot_deg[seed] = float("nan") if g.rot_deg is None else g.rot_deg
                        res.gmapping_wall_s.append(g.wall_s)
                        res.gmapping_peak_mb.append(g.peak_mb)
                        line += f", GMapping {res.gmapping_m[seed]:.3f} m"
                if lama is not None:
                    try:
                        res.lama.append(run_lama(lama, log.log, "pf", lama_seed(seed), work))
                    except RuntimeError as e:
                        progress(f"robustness: LaMa left out: {e}")
                        lama = None
                    else:
                        line += f", {_lama_line(res.lama[-1])}"
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
    """The robustness section: per log, G-SLAM's translation error by seed with the robustness bar, then
    G-SLAM beside GMapping and LaMa's two modes in translation and rotation with the verdict against the
    better peer; then wall time and peak memory."""
    seeds = sorted({s for r in results for s in r.gslam_m})
    lama_ran = any(r.lama for r in results)
    lines = [
        *section_head("## Robustness: the corpus, beside GMapping and LaMa", command, machine, software),
        "- Logs: the Freiburg logs with their published relations and real odometry (fr079's is wrong when",
        "  the robot backs up); the Radish corrected logs with odometry corrupted by the documented, seeded",
        f"  models of `pipelines/bench/corpus.py` (corpus seed {corpus_seed}: scale and turn bias, rotation scale,",
        "  noise growing with motion, slip bursts, reverse sign errors, dropouts) and relations built from the",
        "  corrected poses (short ones between successive scans, long ones at revisits).",
        f"- Relations error (translation m, rotation deg), seeds {', '.join(map(str, seeds))}: G-SLAM at N",
        f"  {particles}; G-SLAM with no options (`gslam process IN OUT`); GMapping (`../shared/tools/gmapping`, 30",
        "  particles, ROS defaults, same seeds, run on the same log on the same machine); odometry alone",
        "  (`--method odometry`).",
        *lama_note(seeds, lama_ran),
        "- Robustness bar (translation): G-SLAM's mean at or below GMapping's, and no seed above twice",
        "  GMapping's mean or above odometry alone.",
        "- Beside the peers: translation (m); rotation (deg), mean ± sd over seeds (one run: no sd). Verdict:",
        "  G-SLAM's mean at or below the better (lower) of the peers' means (GMapping, LaMa PF, LaMa Slam2D), in",
        "  translation and in rotation; in brackets the better peer and its mean.",
        "",
        f"| log | scans | odometry alone (m) | G-SLAM N {particles} per seed (m) | mean | defaults per seed (m) "
        f"| robustness bar | G-SLAM N {particles} | GMapping | LaMa PF | LaMa Slam2D | at or below the better peer |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        gslam, peers = r.errors()
        lines.append(
            f"| {r.log.name} | {r.log.scans or '-'} | {r.odometry_m:.3f} | {_seeds(r.gslam_m)} | {_mean(r.gslam_m)} "
            f"| {_seeds(r.defaults_m)} | {r.verdict()} | {errors_cell(gslam)} "
            f"| {' | '.join(errors_cell(peers[name]) for name in ('GMapping', *MODE_NAMES.values()))} "
            f"| {r.peer_verdict()} |"
        )
    lines += cartographer_lines()
    lines += [
        "",
        "Wall time and peak memory, medians over seeds: G-SLAM's `gslam process` in a child process, import to",
        "exit, with the Rerun recording off (the peak: the filter's process); GMapping's and LaMa's drivers under",
        "`/usr/bin/time` (LaMa Slam2D: its one run):",
        "",
        "| log | G-SLAM wall (s) | G-SLAM peak MB | GMapping wall (s) | GMapping peak MB | LaMa PF wall (s) "
        "| LaMa PF peak MB | LaMa Slam2D wall (s) | LaMa Slam2D peak MB |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    med = lambda v: f"{statistics.median(v):.0f}" if v else "-"  # noqa: E731
    for r in results:
        lama = [
            med([getattr(x, key) for x in r.lama if x.mode == mode])
            for mode in MODE_NAMES
            for key in ("wall_s", "peak_mb")
        ]
        lines.append(
            f"| {r.log.name} | {med(r.gslam_wall_s)} | {med(r.peak_mb)} | {med(r.gmapping_wall_s)} "
            f"| {med(r.gmapping_peak_mb)} | {' | '.join(lama)} |"
        )
    return "\n".join(lines) + "\n"
