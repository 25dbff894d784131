"""`gslam process` stopped by SIGINT at random moments of its run: the result it leaves holds every step its
message says ("wrote ... with the N steps done, marked interrupted"), and `gslam eval` reads it."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from mcaplog import channels as ch
from mcaplog.mcapio import McapInput
from pipelines.cli.app import app

RUNS = 12
DONE = re.compile(r"wrote (\S+) with the (\d+) steps done, marked interrupted")
PROGRESS_EVERY_S = 0.02


def _start(inp: Path, out: Path) -> subprocess.Popen:
    env = dict(os.environ, GSLAM_PROGRESS_EVERY_S=str(PROGRESS_EVERY_S), GSLAM_PROGRESS="")
    cmd = [sys.executable, "-m", "pipelines.cli", "process", str(inp), str(out), "-N", "4", "--no-rrd"]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _run_begun(proc: subprocess.Popen) -> list[str]:
    """The stderr lines up to the run's first progress line (the run is then stepping)."""
    lines = []
    while True:
        line = proc.stderr.readline()
        lines.append(line)
        if line.startswith("G-SLAM: ") or not line:
            return lines


def test_a_result_interrupted_at_a_random_moment_holds_the_steps_its_message_says(carpark_mcap, tmp_path):
    """SIGINT at moments spread over a Car Park run's steps (seeded): every run stopped mid-run says how many
    steps it wrote, and its result holds exactly that many poses and step records, and is read by `gslam eval`."""
    out = tmp_path / "whole.mcap"
    proc = _start(carpark_mcap, out)
    _run_begun(proc)
    t0 = time.monotonic()
    while True:  # the steps end at the progress line of the last scan (the run's end follows: placing, closing loops)
        line = proc.stderr.readline()
        if not line or "(100%)" in line:
            break
    run_s = time.monotonic() - t0  # from the first progress line to the last step (the kernels are cached now)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    rng = np.random.default_rng(17)
    mid_run = []
    for k, delay in enumerate(rng.uniform(0.0, run_s, RUNS)):
        out = tmp_path / f"r{k}.mcap"
        proc = _start(carpark_mcap, out)
        head = _run_begun(proc)
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=300)
        err = "".join(head) + err
        said = DONE.search(err)
        if said is None:  # the signal came after the last scan (the run is whole) or once the process had ended
            assert proc.returncode in (0, 130) and "Traceback" not in err, err
            continue
        assert proc.returncode == 130 and Path(said.group(1)) == out, err
        steps = int(said.group(2))
        mid_run.append(steps)
        src = McapInput(out)
        assert src.metadata()["result"]["steps"] == steps and src.metadata()["result"]["interrupted"] is True
        assert src.metadata()["result"]["placement"] is None  # a run cut short keeps the filter's poses
        topics = [m.topic for m in src.messages([ch.SLAM_POSE, ch.SLAM_STATS])]
        poses, stats = topics.count(ch.SLAM_POSE), topics.count(ch.SLAM_STATS)
        assert (poses, stats) == (steps, steps), f"said {steps} steps, holds {poses} poses, {stats} step records"
        evaluated = CliRunner().invoke(app, ["eval", str(out)])
        assert evaluated.exit_code == 0, evaluated.output
        assert f"after {steps} of 586 scans" in evaluated.output.splitlines()[0], evaluated.output
    assert len(mid_run) >= RUNS // 2, mid_run  # most signals land mid-run
    assert not list(tmp_path.glob(".*.tmp"))
