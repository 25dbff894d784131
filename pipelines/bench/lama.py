"""IRIS LaMa (iris-ua/iris_lama, C++) as a peer of G-SLAM in `gslam bench`, beside GMapping.

LaMa runs through its harness, `../shared/tools/lama` (`run.sh LOG MODE PARTICLES SEED`): the harness
builds the library once into `/tmp/lama` (`$LAMA_BUILD`) from a git dir of iris_lama (`$LAMA_MIRROR`,
passed through from our environment), feeds it a CARMEN log (or the GMapping harness's text log) the way
the iris_lama_ros nodes feed it, with those nodes' defaults, scores the trajectory with the same relations
metric as the GMapping harness and prints one summary line, which `run_lama` parses.

Two modes, both as a ROS user gets them with no parameters set (the harness README lists the values):

- `pf`: PFSlam2D, the `pf_slam2d_ros` node: 30 particles, an update every 0.5 m or 0.25 rad.
- `slam2d`: Slam2D, the `slam2d_ros` node: one hypothesis (scan-to-map Gauss-Newton), an update every
  0.01 m or 0.25 rad; deterministic, so one run per log is enough.

Seeds: the harness's seed 0 is the ROS default, which makes LaMa draw its seed from std::random_device (a
different run each time). So that every PF run can be repeated, G-SLAM's seed s is run as LaMa seed s + 1
(`lama_seed`): G-SLAM seeds 0..k-1 face LaMa PF seeds 1..k.
"""

from __future__ import annotations

import os
import re
import subprocess
from dataclasses import dataclass
from pathlib import Path

MODES = ("pf", "slam2d")
"""LaMa's two SLAM modes the benchmarks run (the harness's `odom` is its own sanity check)."""
MODE_NAMES = {"pf": "LaMa PF", "slam2d": "LaMa Slam2D"}
"""The column names of the two modes in the tables."""
PARTICLES = 30
"""PF-SLAM's particle count: the `pf_slam2d_ros` default, and G-SLAM's and GMapping's N in the tables."""


def _num(name: str) -> str:
    return rf"(?P<{name}>nan|-?inf|[0-9.]+)"


_LINE = re.compile(
    r"^(?P<log>\S+)\s+(?P<mode>pf|slam2d|odom)\s+"
    r"(?:n=(?P<n>\d+) seed=(?P<seed>\d+)\(eff (?P<eff>\d+|-)\)|-)\s+"
    r"scans (?P<processed>\d+)/(?P<total>\d+)\s+"
    rf"trans (?:{_num('trans')}\+-{_num('sd')} m\s+rot {_num('rot')} deg\s+\(\d+/\d+ rel\)|\(no .*\))\s+"
    rf"{_num('ms')} ms/scan\s+slam {_num('slam')} s\s+wall {_num('wall')} s\s+peak (?P<peak>\d+) KB\s*$"
)
"""The harness's summary line (run.sh's last printf); "(no LOG.relations)" in place of the errors when the
log has no relations beside it."""


@dataclass
class LamaRun:
    """One run of IRIS LaMa through `../shared/tools/lama/run.sh`: its summary line, parsed."""

    log: str
    """The log's name (its file name up to the first dot, as the tables name logs)."""
    mode: str
    """`pf` (PFSlam2D) or `slam2d` (Slam2D)."""
    seed: int
    """The seed given to the harness (PF; 0 for Slam2D, which has none)."""
    effective_seed: int | None
    """The seed PFSlam2D used (it draws one when given 0); None for Slam2D."""
    processed: int
    """Scans LaMa updated on (the others are below its motion thresholds and scored through odometry)."""
    total: int
    trans_m: float | None
    """Relations translation error, mean (m); None when the log has no relations file beside it."""
    trans_sd_m: float | None
    rot_deg: float | None
    """Relations rotation error, mean (deg)."""
    wall_s: float
    """The driver's wall time under /usr/bin/time (reading the log included)."""
    peak_mb: float
    """The driver's maximum resident set (MB), from /usr/bin/time."""
    ms_per_update: float
    """Median time of one processed update (ms), point cloud build included."""


def lama_seed(seed: int) -> int:
    """The LaMa PF seed run beside G-SLAM's `seed`: seed + 1, because LaMa's seed 0 draws a random seed and a
    run with it cannot be repeated."""
    return seed + 1


def lama_build_dir() -> Path:
    """Where the harness builds LaMa: `$LAMA_BUILD`, or /tmp/lama."""
    return Path(os.environ.get("LAMA_BUILD") or "/tmp/lama")


def lama_built(harness: Path) -> bool:
    """Will `harness/run.sh` run the driver as built (`/tmp/lama/bin/lama_driver`), rather than build it
    first (which needs `$LAMA_MIRROR`)? Its own test: the driver exists and is newer than the harness's
    `driver.cpp` (a fresh copy of the harness, as in a clean checkout, is newer than any build)."""
    driver = lama_build_dir() / "bin" / "lama_driver"
    try:
        return driver.is_file() and driver.stat().st_mtime > (harness / "driver.cpp").stat().st_mtime
    except OSError:
        return False


def lama_commit() -> str | None:
    """The iris_lama commit the harness built (`/tmp/lama/src/LAMA_COMMIT`), or None when unknown."""
    try:
        return (lama_build_dir() / "src" / "LAMA_COMMIT").read_text().strip() or None
    except OSError:
        return None


def _float(text: str | None) -> float | None:
    return None if text is None else float(text)


def run_lama(harness: Path, log: Path, mode: str, seed: int, workdir: Path, particles: int = PARTICLES) -> LamaRun:
    """`bash HARNESS/run.sh LOG MODE PARTICLES SEED` (LaMa built once first if needed, from `$LAMA_MIRROR`),
    its outputs under `workdir/lama` (`$LAMA_OUT`), and its one summary line parsed. `seed` is passed as it
    is (see `lama_seed` for the one to give beside G-SLAM's). A failing harness or a line that does not
    parse raises RuntimeError naming the command and the last line it wrote to stderr."""
    if mode not in MODES:
        raise ValueError(f"LaMa mode {mode!r}: expected one of {', '.join(MODES)}")
    env = dict(os.environ, LAMA_OUT=str(workdir / "lama"))  # LAMA_MIRROR, LAMA_BUILD: passed through
    cmd = ["bash", str(harness / "run.sh"), str(log), mode, str(particles), str(seed)]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    line = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
    m = _LINE.match(line)
    last = (proc.stderr.strip().splitlines() or [""])[-1]
    if proc.returncode != 0:
        # the driver's own stderr goes to a file under $LAMA_OUT; ours has the harness's and the build's
        why = last or line or f"(no message; the driver's .err and .time are in {workdir / 'lama'})"
        raise RuntimeError(f"{' '.join(cmd)} failed (exit {proc.returncode}): {why}")
    if m is None or m.group("mode") != mode:
        raise RuntimeError(
            f"{' '.join(cmd)} gave no {mode} summary line in the harness's format: {line or '(nothing)'!r}"
            + (f"; last stderr line: {last}" if last else "")
        )
    eff = m.group("eff")
    return LamaRun(
        log=log.name.split(".")[0],
        mode=m.group("mode"),
        seed=int(m.group("seed")) if m.group("seed") is not None else seed,
        effective_seed=int(eff) if eff and eff != "-" else None,
        processed=int(m.group("processed")),
        total=int(m.group("total")),
        trans_m=_float(m.group("trans")),
        trans_sd_m=_float(m.group("sd")),
        rot_deg=_float(m.group("rot")),
        wall_s=float(m.group("wall")),
        peak_mb=int(m.group("peak")) / 1024,
        ms_per_update=float(m.group("ms")),
    )


def lama_note(seeds: list[int], ran: bool, slam2d_each_repeat: bool = False) -> list[str]:
    """The lines of a suite's header saying how LaMa was run (commit, modes, parameters, seeds), or that it
    was not. `slam2d_each_repeat`: the speed suite runs Slam2D once per timing repeat, not once per log."""
    if not ran:
        return [
            "- LaMa (IRIS LaMa, `../shared/tools/lama`): not run (harness absent, or it could not build or run:",
            "  the progress lines say why; building needs `LAMA_MIRROR`); its columns read n/a.",
        ]
    commit = lama_commit() or "unknown (no /tmp/lama/src/LAMA_COMMIT)"
    pf_seeds = ", ".join(str(lama_seed(s)) for s in seeds)
    once = "once per timing repeat" if slam2d_each_repeat else "one run per log"
    return [
        "- LaMa: IRIS LaMa (iris-ua/iris_lama, CMake Release -O3, one core, no thread pool), commit",
        f"  {commit}, through `../shared/tools/lama/run.sh`, fed and parameterised as the",
        "  iris_lama_ros nodes with no parameter set (the harness README): LaMa PF = `pf` (PFSlam2D,",
        "  `pf_slam2d_ros`): 30 particles, update every 0.5 m / 0.25 rad, srr 0.1, str 0.2, stt 0.1, srt 0.2,",
        "  sigma 0.05, lgain 3, resolution 0.05 m, max range 16 m; LaMa Slam2D = `slam2d` (Slam2D, `slam2d_ros`,",
        "  one hypothesis): update every 0.01 m / 0.25 rad, resolution 0.05 m, max range 16 m, Gauss-Newton,",
        "  100 iterations. Scans LaMa skips are scored at its last pose plus odometry (what map->odom gives).",
        f"  Seeds: LaMa PF seed s + 1 beside G-SLAM's seed s (here {pf_seeds}): LaMa's seed 0 draws a random",
        f"  seed and cannot be repeated. Slam2D is deterministic: {once}.",
    ]
