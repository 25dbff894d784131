"""`gslam bench --suite localise`: localisation in a map G-SLAM built, on the corpus of the robustness suite
(the Freiburg logs with their real odometry, the Radish logs with corrupted odometry).

For each log: `gslam process` (N 30, seed 0) gives the map and the reference trajectory; then
`gslam localise` (a child process, timed whole, as a user runs it) localises the same log's scans with its
raw odometry in three ways: from no initial pose (global), from a wrong initial pose (1.5 m and 60 deg off
with a tight spread, so the filter must notice), and in a map built from the first half of the log only
(`--max-scans`), localising the second half (`--skip-scans`). A kidnap run (the core on the same scans:
half-way through, the scans jump 30 % of the log ahead while the odometry goes on) measures recovery.

Figures: distance travelled until the filter first tracks, the error against the SLAM trajectory at the
scans where it tracks after that (mean position, mean heading), the share of scans tracked, time per scan
and the real-time factor (log duration / wall time of the whole command).
"""

from __future__ import annotations

import math
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mcaplog.mcapio import McapInput
from pipelines.bench.suites import section_head

SCENARIOS = ("global", "wrong start", "half map", "kidnap")


@dataclass
class LocaliseRun:
    log: str
    scenario: str
    converged_m: float | None
    position_m: float
    heading_deg: float
    tracked: float
    ms_per_scan: float
    real_time: float
    recovered_m: float | None = None
    """kidnap: distance travelled from the jump until the filter tracks the new place."""


def _states(path: Path) -> list[dict]:
    return [m.value for m in McapInput(path).messages(["/localise/state"])]


def score(states: list[dict], reference: np.ndarray, travelled: np.ndarray) -> tuple[float | None, float, float, float]:
    """(travel until first tracking, mean position and heading error where tracking after it, tracked share)
    of per-scan states against the reference poses at the same scans."""
    est = np.array([[s["x_m"], s["y_m"], s["yaw_rad"]] for s in states])
    tracking = np.array([s["tracking"] for s in states], dtype=bool)
    if not tracking.any():
        return None, math.nan, math.nan, 0.0
    first = int(np.argmax(tracking))
    sel = tracking.copy()
    sel[:first] = False
    err = np.hypot(*(est[:, :2] - reference[:, :2]).T)
    head = np.abs((est[:, 2] - reference[:, 2] + math.pi) % (2 * math.pi) - math.pi)
    return (
        float(travelled[first]),
        float(err[sel].mean()),
        math.degrees(float(head[sel].mean())),
        float(tracking.mean()),
    )


def _travelled(poses: np.ndarray) -> np.ndarray:
    return np.r_[0.0, np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))]


def _cli(command: str, args: list[str]) -> float:
    """Run `gslam COMMAND ARGS --no-rrd` as a child process; its wall time."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pipelines.cli", command, *args, "--no-rrd"], capture_output=True,
                          text=True)  # fmt: skip
    if done.returncode:
        raise RuntimeError(f"gslam {command} {' '.join(args)} failed: {done.stderr.strip().splitlines()[-1:]}")
    return time.perf_counter() - t0


def _localise_cli(args: list[str]) -> float:
    return _cli("localise", args)


def run_localise_bench(inputs: list[tuple[str, Path]], progress: Callable[[str], None]) -> list[LocaliseRun]:
    """`inputs`: (name, ingested MCAP) of logs with odometry (the corpus: the Freiburg logs, the Radish logs
    with corrupted odometry)."""
    from gslam.localise import LocaliseConfig, MonteCarloLocaliser
    from gslam.motion import odometry_delta
    from pipelines.evaluation.evaluate import read_result
    from pipelines.localise.maps import load_map
    from pipelines.run.input_log import InputLog
    from pipelines.run.scans import scan_stream

    runs: list[LocaliseRun] = []
    with tempfile.TemporaryDirectory(prefix="gslam-bench-localise-") as tmp:
        work = Path(tmp)
        for name, mcap in inputs:
            log = InputLog(mcap)
            if log.mount is not None:
                raise RuntimeError(f"{mcap}: the kidnap run takes the laser at the base; this log mounts it off")
            duration = log.end_s - log.start_s
            slam_path = work / f"{name}-slam.mcap"
            _cli("process", [str(mcap), str(slam_path), "--occupancy"])
            ref = read_result(slam_path).trajectory
            travelled = _travelled(ref)
            progress(f"localise: {name}: map and reference from gslam process ({len(ref)} scans)")
            out = work / f"{name}-loc.mcap"
            # global
            wall = _localise_cli([str(slam_path), str(mcap), str(out)])
            st = _states(out)
            runs.append(_run(name, "global", score(st, ref, travelled), st, duration, wall))
            # wrong start
            x, y, yaw = ref[0]
            wrong = [str(v) for v in (x + 1.5 * math.cos(yaw + 1), y + 1.5 * math.sin(yaw + 1), yaw + math.radians(60))]
            wall = _localise_cli([str(slam_path), str(mcap), str(out), "--initial-pose", *wrong,
                                  "--initial-sigma", "0.1", "0.05"])  # fmt: skip
            st = _states(out)
            runs.append(_run(name, "wrong start", score(st, ref, travelled), st, duration, wall))
            # half map
            half = len(ref) // 2
            half_path = work / f"{name}-half.mcap"
            _cli("process", [str(mcap), str(half_path), "--max-scans", str(half), "--occupancy"])
            wall = _localise_cli([str(half_path), str(mcap), str(out), "--skip-scans", str(half)])
            st = _states(out)
            runs.append(_run(name, "half map", score(st, ref[half:], travelled[half:] - travelled[half]), st,
                             duration * (len(ref) - half) / len(ref), wall))  # fmt: skip
            # kidnap (the core on the scans: the scans jump ahead, the odometry does not)
            saved = load_map(slam_path)
            stream = list(scan_stream(log))
            jump, shift = len(stream) // 2, int(0.3 * len(stream))
            loc = MonteCarloLocaliser(saved.field, LocaliseConfig(seed=0), initial_pose=ref[0])
            tracked_after, t0 = [], time.perf_counter()
            for k in range(len(stream)):
                if k + (shift if k >= jump else 0) >= len(stream):
                    break
                src = k + shift if k >= jump else k
                if k:
                    prev = stream[k - 1 + (shift if k - 1 >= jump else 0)][2]
                    if k == jump:
                        prev = stream[src - 1][2]  # the odometry goes on smoothly
                    loc.predict(odometry_delta(prev, stream[src][2]))
                s = loc.step(stream[src][1], stream[src][3])
                if k >= jump:
                    err = math.hypot(*(s.pose[:2] - ref[src, :2]))
                    tracked_after.append((s.tracking and err < 0.3, travelled[src] - travelled[jump + shift]))
            back = next((d for ok, d in tracked_after if ok), None)
            per_scan = 1e3 * (time.perf_counter() - t0) / len(stream)
            runs.append(LocaliseRun(name, "kidnap", None, math.nan, math.nan, math.nan, per_scan, math.nan, back))
            progress(f"localise: {name}: " + "; ".join(_line(r) for r in runs[-4:]))
    return runs


def _run(name: str, scenario: str, scored, states: list[dict], duration: float, wall: float) -> LocaliseRun:
    conv, pos, head, tracked = scored
    ms = float(np.mean([s["step_ms"] for s in states]))
    return LocaliseRun(name, scenario, conv, pos, head, tracked, ms, duration / wall)


def _line(r: LocaliseRun) -> str:
    if r.scenario == "kidnap":
        return (
            f"kidnap: recovered after {r.recovered_m:.1f} m" if r.recovered_m is not None else "kidnap: not recovered"
        )
    conv = "never" if r.converged_m is None else f"{r.converged_m:.1f} m"
    return f"{r.scenario}: converged {conv}, {r.position_m:.3f} m, {r.heading_deg:.2f} deg"


def localise_section(runs: list[LocaliseRun], command: str, machine: str, software: str) -> str:
    lines = [
        *section_head("## Localisation in a saved map", command, machine, software),
        "- Logs: the robustness suite's corpus, the Freiburg logs with their odometry and the Radish logs with",
        "  odometry corrupted (odometry seed 0).",
        "- Map and reference: `gslam process` (N 30, seed 0) on the same log; `gslam localise` with the defaults",
        "  (seed 0) on the log's scans and raw odometry. Error: against the SLAM trajectory at the scans where",
        "  the filter says it tracks, after it first does. Wrong start: 1.5 m and 60 deg off, spread 0.1 m /",
        "  0.05 rad. Half map: the map of the first half of the log, localising the second half (the scans",
        "  of places the first half did not see cannot be tracked). Kidnap: half-way through, the scans jump",
        "  30 % of the log ahead while the odometry goes on; recovery = distance travelled until tracking",
        "  within 0.3 m of the reference. Real-time factor: log duration / wall time of the whole command.",
        "",
        "| log | scenario | travel to converge (m) | position error (m) | heading error (deg) | scans tracked "
        "| ms per scan | real-time factor |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        if r.scenario == "kidnap":
            rec = "not recovered" if r.recovered_m is None else f"recovered after {r.recovered_m:.1f} m"
            lines.append(f"| {r.log} | kidnap | {rec} | | | | {r.ms_per_scan:.2f} | |")
            continue
        conv = "never" if r.converged_m is None else f"{r.converged_m:.1f}"
        lines.append(
            f"| {r.log} | {r.scenario} | {conv} | {r.position_m:.3f} | {r.heading_deg:.2f} | {100 * r.tracked:.0f} % "
            f"| {r.ms_per_scan:.2f} | {r.real_time:.0f} |"
        )
    return "\n".join(lines) + "\n"
