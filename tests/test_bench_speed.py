"""The speed table: GMapping run beside gslam through its harness (parsed from its summary line), and the
ratio taken from the runs made side by side; reference times only when the harness is absent or fails."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipelines.bench.suites import GMappingRun, SuiteRun, run_gmapping, speed_section

LINE = (
    "mit-csail  n=30  seed=0  scans 430/1988  trans 0.055+-0.059 m  rot 3.39 deg  (1172/1172 rel)  182.2 ms/scan  "
    "slam 82.2 s  wall 82.44 s  peak 127 MB"
)


def stand_in_harness(tmp_path: Path, body: str, name: str = "harness") -> Path:
    """A stand-in harness directory `name` whose run.sh runs `body` (the peers' harnesses are run so)."""
    d = tmp_path / name
    d.mkdir()
    (d / "run.sh").write_text(f"#!/usr/bin/env bash\n{body}\n")
    return d


def test_the_harness_summary_line_is_read(tmp_path):
    harness = stand_in_harness(tmp_path, f"echo building >&2; echo '{LINE}'")
    run = run_gmapping(harness, Path("/data/mit-csail.clf.gz"), 30, 0, tmp_path)
    assert run == GMappingRun("mit-csail", 82.44, 127.0, 0.055, 3.39)  # rotation too: the tables compare both


def test_a_failing_harness_says_why(tmp_path):
    harness = stand_in_harness(tmp_path, "echo 'GM_MIRROR: set GM_MIRROR to a git clone' >&2; exit 1")
    with pytest.raises(RuntimeError, match="GM_MIRROR"):
        run_gmapping(harness, Path("/data/intel.clf.gz"), 30, 0, tmp_path)


def _run(log: str, wall: float) -> SuiteRun:
    return SuiteRun(log, 30, 0, 0, wall, 300.0, {"relations_trans_m": 0.05}, [10.0, 12.0], 1.1, 120.0)


def test_the_ratio_comes_from_the_runs_side_by_side():
    runs = [_run("mit-csail", w) for w in (20.0, 25.0, 30.0)]
    gm = [GMappingRun("mit-csail", w, 127.0, 0.055) for w in (80.0, 75.0, 90.0)]
    text = speed_section(runs, "gslam bench --suite speed", "machine", "software", 3, gm)
    row = next(line for line in text.splitlines() if line.startswith("| mit-csail"))
    assert "| 80.0, 127 MB | 3.20 |" in row  # medians 80 s and 25 s
    assert "300 + 120" in row
    assert "run right after each of gslam's runs" in text


def test_without_the_harness_the_reference_time_is_labelled():
    text = speed_section([_run("intel", 30.0)], "cmd", "machine", "software", 3, [])
    row = next(line for line in text.splitlines() if line.startswith("| intel"))
    assert "68.7 (reference)" in row and "not run beside this table" in text


def test_the_back_end_cost_is_the_median_of_paired_ratios():
    """Each pair's ratio on / off, then the median: (26 / 20, 27 / 24, 30 / 22) -> 1.30."""
    from dataclasses import replace

    from pipelines.bench.suites import backend_cost_section

    pairs = []
    for on, off in ((26.0, 20.0), (27.0, 24.0), (30.0, 22.0)):
        a = replace(_run("intel", on), finish_s=(3.0, 2.5), live_s=2.0, peak_mb=350.0)
        pairs.append((a, replace(_run("intel", off), options={"loop_closure": False}, peak_mb=250.0)))
    text = backend_cost_section(pairs)
    row = next(line for line in text.splitlines() if line.startswith("| intel"))
    assert row.startswith("| intel | 27.0 / 22.0 | 1.30 | 2.5 | 2.0 | 350 / 250 |"), row
