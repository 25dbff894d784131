"""IRIS LaMa beside G-SLAM and GMapping in `gslam bench` (`pipelines.bench.lama`): its harness's summary line
read, a failing harness said in one message, the verdict against the better peer (translation and rotation),
the freiburg, speed and robustness tables with LaMa's two modes, and one real Slam2D run when LaMa is built."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from conftest import MIT, ROOT, require
from test_bench_speed import stand_in_harness

from pipelines.bench.corpus import CorpusLog
from pipelines.bench.lama import LamaRun, lama_build_dir, lama_built, lama_commit, lama_note, lama_seed, run_lama
from pipelines.bench.robustness import LogResult, robustness_section
from pipelines.bench.suites import (
    GMappingRun,
    SuiteRun,
    at_or_below_better_peer,
    better_peer,
    freiburg_section,
    peer_verdict,
    speed_section,
)

HARNESS = ROOT.parent / "shared" / "tools" / "lama"

# The harness's lines as run.sh prints them (mit-csail, 2026-12-05 and this change's runs).
PF_LINE = (
    "mit-csail  pf     n=30 seed=1(eff 1)  scans 773/1988  trans 0.047+-0.047 m  rot 2.32 deg  (1172/1172 rel)  "
    "32.0 ms/scan  slam 27.0 s  wall 27.15 s  peak 155396 KB"
)
SLAM2D_LINE = (
    "mit-csail  slam2d -  scans 1836/1988  trans 0.162+-0.581 m  rot 1.50 deg  (1172/1172 rel)  0.6 ms/scan  "
    "slam 1.1 s  wall 1.24 s  peak 20620 KB"
)
SEED0_LINE = (
    "carpark    pf     n=30 seed=0(eff 1906136070)  scans 700/900  trans (no /data/x y/carpark.relations)  "
    "12.5 ms/scan  slam 9.0 s  wall 9.50 s  peak 102400 KB"
)


def test_the_pf_summary_line_is_read(tmp_path):
    harness = stand_in_harness(tmp_path, f"echo 'CXX driver.cpp' >&2; echo building; echo '{PF_LINE}'")
    run = run_lama(harness, Path("/data/mit-csail.clf.gz"), "pf", 1, tmp_path)
    assert run == LamaRun("mit-csail", "pf", 1, 1, 773, 1988, 0.047, 0.047, 2.32, 27.15, 155396 / 1024, 32.0)


def test_the_slam2d_line_has_no_seed(tmp_path):
    harness = stand_in_harness(tmp_path, f"echo '{SLAM2D_LINE}'")
    run = run_lama(harness, Path("/data/mit-csail.clf.gz"), "slam2d", 0, tmp_path)
    assert (run.mode, run.effective_seed, run.processed, run.total) == ("slam2d", None, 1836, 1988)
    assert (run.trans_m, run.trans_sd_m, run.rot_deg, run.wall_s, run.ms_per_update) == (0.162, 0.581, 1.5, 1.24, 0.6)
    assert run.peak_mb == pytest.approx(20.1, abs=0.05)


def test_a_log_without_relations_and_a_drawn_seed(tmp_path):
    harness = stand_in_harness(tmp_path, f"echo '{SEED0_LINE}'")
    run = run_lama(harness, Path("/w/carpark.gmapping.txt"), "pf", 0, tmp_path)
    assert (run.log, run.seed, run.effective_seed) == ("carpark", 0, 1906136070)
    assert run.trans_m is None and run.rot_deg is None and run.peak_mb == 100.0


def test_the_harness_gets_its_arguments_lama_out_and_lama_mirror(tmp_path, monkeypatch):
    monkeypatch.setenv("LAMA_MIRROR", "/mirrors/iris_lama")
    harness = stand_in_harness(tmp_path, f'echo "$*|$LAMA_OUT|$LAMA_MIRROR" > "{tmp_path}/args"; echo \'{PF_LINE}\'')
    run_lama(harness, Path("/data/mit-csail.clf.gz"), "pf", 3, tmp_path, particles=12)
    assert (tmp_path / "args").read_text().strip() == (
        f"/data/mit-csail.clf.gz pf 12 3|{tmp_path / 'lama'}|/mirrors/iris_lama"
    )


def test_a_failing_harness_says_why(tmp_path):
    body = (
        "echo 'cmake -S /tmp/lama/src' >&2\n"
        "echo 'build.sh: line 13: LAMA_MIRROR: set LAMA_MIRROR to a git clone (or git dir) of github "
        "iris-ua/iris_lama' >&2; exit 1"
    )
    harness = stand_in_harness(tmp_path, body)
    with pytest.raises(RuntimeError) as e:
        run_lama(harness, Path("/data/intel.clf.gz"), "pf", 1, tmp_path)
    message = str(e.value)
    assert message.startswith(f"bash {harness / 'run.sh'} /data/intel.clf.gz pf 30 1 failed (exit 1): ")
    assert message.endswith("LAMA_MIRROR: set LAMA_MIRROR to a git clone (or git dir) of github iris-ua/iris_lama")
    assert "\n" not in message  # one line in the progress output


def test_a_line_out_of_format_is_refused_with_the_line(tmp_path):
    harness = stand_in_harness(tmp_path, "echo 'warning: odd' >&2; echo 'mit-csail  pf  something else'")
    with pytest.raises(RuntimeError, match=r"pf 30 1 gave no pf summary line.*something else.*warning: odd"):
        run_lama(harness, Path("/data/mit-csail.clf.gz"), "pf", 1, tmp_path)


def test_a_silent_crash_points_to_the_drivers_files(tmp_path):
    harness = stand_in_harness(tmp_path, "exit 139")
    with pytest.raises(RuntimeError, match=r"failed \(exit 139\): \(no message; the driver's .err"):
        run_lama(harness, Path("/data/mit-csail.clf.gz"), "slam2d", 0, tmp_path)


def test_unknown_mode_is_refused(tmp_path):
    with pytest.raises(ValueError, match="odom"):
        run_lama(tmp_path, Path("/data/mit-csail.clf.gz"), "odom", 0, tmp_path)


def test_lama_seeds_skip_the_random_seed_zero():
    assert [lama_seed(s) for s in range(3)] == [1, 2, 3]
    assert "seed s + 1 beside G-SLAM's seed s (here 1, 2, 3)" in " ".join(lama_note([0, 1, 2], True))
    assert "not run" in " ".join(lama_note([0], False))


def test_the_better_peer_verdict():
    peers = {"GMapping": 0.054, "LaMa PF": 0.047, "LaMa Slam2D": 0.162}
    assert better_peer(peers) == ("LaMa PF", 0.047)
    assert at_or_below_better_peer(0.047, peers) is True  # at: holds
    assert at_or_below_better_peer(0.048, peers) is False
    assert at_or_below_better_peer(0.050, {"GMapping": 0.054, "LaMa PF": None, "LaMa Slam2D": float("nan")}) is True
    assert at_or_below_better_peer(0.050, {"GMapping": None}) is None  # no peer ran
    assert at_or_below_better_peer(None, peers) is None
    gslam = ([0.048, 0.049], [2.79, 2.81])
    text = peer_verdict(
        gslam,
        {
            "GMapping": ([0.055, 0.054, 0.053], [3.35]),
            "LaMa PF": ([0.047, 0.048], [2.32, 2.39]),
            "LaMa Slam2D": ([0.162], [1.50]),
        },
    )
    assert text == "trans no (LaMa PF 0.048), rot no (LaMa Slam2D 1.50)"  # LaMa PF's mean 0.0475
    text = peer_verdict(gslam, {"GMapping": ([0.055], [3.35]), "LaMa PF": ([], []), "LaMa Slam2D": ([], [])})
    assert text == "trans yes (GMapping 0.055), rot yes (GMapping 3.35)"
    assert peer_verdict(gslam, {"LaMa PF": ([], [])}) == "trans n/a, rot n/a"


def _suite_run(log: str, seed: int, trans: float, rot: float, wall: float = 13.5) -> SuiteRun:
    metrics = {"relations_trans_m": trans, "relations_trans_std_m": 0.044, "relations_rot_deg": rot}
    metrics["final_map_points"] = 21000.0
    return SuiteRun(log, 30, seed, 0, wall, 220.0, metrics, [16.0, 17.0, 22.0], 1.2, 121.0)


def _lama(log: str, mode: str, seed: int, trans: float, rot: float, wall: float) -> LamaRun:
    eff = seed if mode == "pf" else None
    done = 773 if mode == "pf" else 1836
    return LamaRun(log, mode, seed, eff, done, 1988, trans, 0.05, rot, wall, 150.0 if mode == "pf" else 20.1, 30.0)


def _row(text: str, start: str, nth: int = 0) -> str:
    return [line for line in text.splitlines() if line.startswith(start)][nth]


def test_the_freiburg_tables_set_lama_beside_gmapping():
    runs = [_suite_run("mit-csail", s, t, 2.80) for s, t in ((0, 0.049), (1, 0.048), (2, 0.046))]
    lama = [_lama("mit-csail", "pf", s + 1, t, 2.3, 27.0) for s, t in ((0, 0.047), (1, 0.048), (2, 0.046))]
    lama.append(_lama("mit-csail", "slam2d", 0, 0.162, 1.50, 1.2))
    text = freiburg_section(runs, "gslam bench --suite freiburg", "machine", "software", lama)
    header = _row(text, "| log | N | seeds |")
    assert header == (
        "| log | N | seeds | G-SLAM | worst seed (m) | GMapping (reference) | LaMa PF | LaMa Slam2D "
        "| at or below the better peer |"
    )
    row = _row(text, "| mit-csail | 30 | 3 |")
    assert row == (
        "| mit-csail | 30 | 3 | 0.048 ± 0.002; 2.80 ± 0.00 | 0.049 | 0.054 ± 0.001; 3.35 | 0.047 ± 0.001; 2.30 ± 0.00 "
        "| 0.162; 1.50 | trans no (LaMa PF 0.047), rot no (LaMa Slam2D 1.50) |"
    )
    assert _row(text, "| mit-csail | 30 | 13.5, 220 + 121 |") == (
        "| mit-csail | 30 | 13.5, 220 + 121 | 60.0 | 27.0, 150, 773/1988 | 1.2, 20, 1836/1988 |"
    )
    assert "LaMa PF seed s + 1 beside G-SLAM's seed s (here 1, 2, 3)" in text
    assert "seeds 0, 1, 2." in text and (lama_commit() or "unknown (no /tmp/lama/src/LAMA_COMMIT)") in text


def test_the_freiburg_tables_without_lama_say_so():
    text = freiburg_section([_suite_run("intel", 0, 0.033, 1.30)], "cmd", "machine", "software")
    row = _row(text, "| intel | 30 | 1 |")
    assert row.endswith("| 0.041 ± 0.001; 1.90 | n/a | n/a | trans yes (GMapping 0.041), rot yes (GMapping 1.90) |")
    assert "LaMa (IRIS LaMa, `../shared/tools/lama`): not run" in text


def test_the_speed_table_gives_lama_beside_gmapping():
    runs = [_suite_run("mit-csail", 0, 0.049, 2.80, wall) for wall in (20.0, 25.0, 30.0)]
    gm = [GMappingRun("mit-csail", w, 127.0, 0.055, 3.39) for w in (80.0, 75.0, 90.0)]
    lama = [_lama("mit-csail", "pf", 1, 0.047, 2.32, w) for w in (50.0, 40.0, 45.0)]
    lama += [_lama("mit-csail", "slam2d", 0, 0.162, 1.50, w) for w in (1.3, 1.2, 1.25)]
    text = speed_section(runs, "gslam bench --suite speed", "machine", "software", 3, gm, lama)
    assert _row(text, "| log |").endswith(
        "| GMapping wall (s), peak MB | ratio | LaMa PF wall (s), peak MB (ratio) | LaMa Slam2D wall (s), peak MB "
        "(ratio) |"
    )
    row = _row(text, "| mit-csail")
    assert "| 0.049 m, 2.80 deg (relations) | 80.0, 127 MB | 3.20 | 45.0, 150 MB (1.80) | 1.2, 20 MB (0.05) |" in row
    assert "`../shared/tools/lama/run.sh LOG pf 30 1` and `run.sh LOG slam2d`" in text
    alone = speed_section(runs, "cmd", "machine", "software", 3, gm)
    assert _row(alone, "| mit-csail").endswith("| 3.20 | - | - |")


def test_the_robustness_table_compares_every_peer_in_translation_and_rotation():
    log = CorpusLog("seattle", Path("seattle.clf"), 241, 5.0, "corrupted, seed 0")
    res = LogResult(
        log,
        odometry_m=0.624,
        gslam_m={0: 0.038, 1: 0.040},
        defaults_m={0: 0.038, 1: 0.040},
        gmapping_m={0: 0.068, 1: 0.054},
        gslam_wall_s=[5.0, 6.0],
        gmapping_wall_s=[19.0, 20.0],
        peak_mb=[326.0, 330.0],
        gmapping_peak_mb=[44.0, 44.0],
        gslam_rot_deg={0: 1.10, 1: 1.30},
        gmapping_rot_deg={0: 2.0, 1: 2.2},
        lama=[
            _lama("seattle", "slam2d", 0, 0.030, 1.40, 0.8),
            _lama("seattle", "pf", 1, 0.045, 1.00, 9.0),
            _lama("seattle", "pf", 2, 0.047, 1.10, 11.0),
        ],
    )
    assert res.peer_verdict() == "trans no (LaMa Slam2D 0.030), rot no (LaMa PF 1.05)"
    assert res.verdict() == "holds"  # the robustness bar is GMapping's, as before
    text = robustness_section([res], "gslam bench --suite robustness", "m", "s", 30, 0)
    assert _row(text, "| log |") == (
        "| log | scans | odometry alone (m) | G-SLAM N 30 per seed (m) | mean | defaults per seed (m) "
        "| robustness bar | G-SLAM N 30 | GMapping | LaMa PF | LaMa Slam2D | at or below the better peer |"
    )
    assert _row(text, "| seattle") == (
        "| seattle | 241 | 0.624 | 0.038 / 0.040 | 0.039 | 0.038 / 0.040 | holds | 0.039 ± 0.001; 1.20 ± 0.14 "
        "| 0.061 ± 0.010; 2.10 ± 0.14 | 0.046 ± 0.001; 1.05 ± 0.07 | 0.030; 1.40 "
        "| trans no (LaMa Slam2D 0.030), rot no (LaMa PF 1.05) |"
    )
    assert _row(text, "| seattle", 1) == "| seattle | 6 | 328 | 20 | 44 | 10 | 150 | 1 | 20 |"
    assert "LaMa PF seed s + 1 beside G-SLAM's seed s (here 1, 2)" in text


def test_a_real_slam2d_run_on_mit_csail(tmp_path):
    """The harness as the suites run it, on the log the README measured (about 2 s)."""
    if not (HARNESS / "run.sh").exists():
        pytest.skip(f"LaMa harness not found: {HARNESS}")
    if not lama_built(HARNESS) and not os.environ.get("LAMA_MIRROR"):
        ci = " (LaMa is not built in CI)" if os.environ.get("CI", "").lower() == "true" else ""
        driver = lama_build_dir() / "bin" / "lama_driver"
        pytest.skip(
            f"LaMa is not built for this harness: no {driver}, or one older than {HARNESS}/driver.cpp{ci}, and no "
            f"LAMA_MIRROR to build it from; build it: LAMA_MIRROR=<iris_lama git dir> {HARNESS}/build.sh"
        )
    run = run_lama(HARNESS, require(MIT), "slam2d", 0, tmp_path)
    assert (run.log, run.mode, run.total, run.effective_seed) == ("mit-csail", "slam2d", 1988, None)
    assert 1500 < run.processed <= 1988  # an update every centimetre: most scans
    assert run.trans_m is not None and run.trans_m < 0.5 and run.rot_deg < 3.0  # the README: 0.162 m, 1.50 deg
    assert run.wall_s > 0 and run.peak_mb > 1
    assert (tmp_path / "lama" / "mit-csail-slam2d.traj").exists()


def test_the_suite_runs_lama_beside_each_gslam_run(tmp_path, monkeypatch):
    """PF at seed + 1 after every G-SLAM run at N 30 with the default threads, Slam2D after the first seed's;
    a harness that fails is said once and not run again."""
    from pipelines.bench import suites

    calls: list[tuple[str, int]] = []
    monkeypatch.setattr(suites, "ingest_to", lambda log, work: log)
    monkeypatch.setattr(suites, "timed_run", lambda mcap, n, seed, k, work: _suite_run("mit-csail", seed, 0.05, 2.8))

    def fake_lama(harness, log, mode, seed, workdir):
        calls.append((mode, seed))
        return _lama("mit-csail", mode, seed, 0.05, 2.0, 1.0)

    monkeypatch.setattr(suites, "run_lama", fake_lama)
    log, lines, lama_runs = tmp_path / "mit-csail.clf.gz", [], []
    suites.run_suite("freiburg", [log], [30], [0, 1, 2], [0], 1, lines.append, lama=tmp_path, lama_runs=lama_runs)
    assert calls == [("pf", 1), ("slam2d", 0), ("pf", 2), ("pf", 3)]
    assert [(r.mode, r.seed) for r in lama_runs] == calls
    assert "freiburg: LaMa PF mit-csail seed 1 (effective 1): 1.0 s, 0.050 m, 2.00 deg, 773/1988 updates" in lines

    def failing(harness, log, mode, seed, workdir):
        calls.append((mode, seed))
        raise RuntimeError("bash run.sh failed (exit 1): LAMA_MIRROR: set LAMA_MIRROR")

    calls.clear()
    monkeypatch.setattr(suites, "run_lama", failing)
    lines.clear()
    suites.run_suite("speed", [log], [30], [0], [0], 3, lines.append, lama=tmp_path, lama_runs=[])
    assert calls == [("pf", 1)]
    assert [line for line in lines if "LaMa" in line] == [
        "speed: LaMa left out: bash run.sh failed (exit 1): LAMA_MIRROR: set LAMA_MIRROR"
    ]


def test_the_robustness_suite_runs_slam2d_once_and_pf_at_each_seed(tmp_path, monkeypatch):
    from types import SimpleNamespace

    from pipelines.bench import robustness

    log = CorpusLog("seattle", tmp_path / "seattle.clf", 241, 5.0, "corrupted, seed 0")
    monkeypatch.setattr(robustness, "build_corpus", lambda datasets, work, seed: [log])
    monkeypatch.setattr(robustness, "ingest_to", lambda path, work: path)

    def fake_task(task, out, command=None, child_process=False):
        metrics = {"relations_trans_m": 0.04 + task.seed / 1000, "relations_rot_deg": 1.2}
        return SimpleNamespace(task=task, metrics=metrics, wall_s=5.0, result={"peak_rss_mb": 300.0})

    monkeypatch.setattr(robustness, "run_task", fake_task)
    gm = GMappingRun("seattle", 19.0, 44.0, 0.06, 2.1)
    monkeypatch.setattr(robustness, "run_gmapping", lambda harness, path, n, seed, work: gm)
    calls: list[tuple[str, int]] = []

    def fake_lama(harness, path, mode, seed, workdir):
        calls.append((mode, seed))
        return _lama("seattle", mode, seed, 0.05, 1.4, 1.0)

    monkeypatch.setattr(robustness, "run_lama", fake_lama)
    lines: list[str] = []
    (res,) = robustness.run_robustness(tmp_path, [0, 1], lines.append, tmp_path, workdir=tmp_path / "w", lama=tmp_path)
    assert calls == [("slam2d", 0), ("pf", 1), ("pf", 2)]
    assert res.gslam_rot_deg == {0: 1.2, 1: 1.2} and res.gmapping_rot_deg == {0: 2.1, 1: 2.1}
    assert res.peer_verdict() == "trans yes (LaMa PF 0.050), rot yes (LaMa PF 1.40)"  # a tie: the first named
    assert lines[-1].endswith("GMapping 0.060 m, LaMa PF (seed 2) 0.050 m 1.40 deg")


def test_lama_counts_as_built_only_when_the_harness_would_not_rebuild_it(tmp_path, monkeypatch):
    """run.sh rebuilds when its driver.cpp is newer than the built driver (as in a fresh checkout of the
    harness beside an old build): then LaMa is not 'built' for it, and a run would need LAMA_MIRROR."""
    harness, build = tmp_path / "harness", tmp_path / "build"
    (harness).mkdir()
    (build / "bin").mkdir(parents=True)
    monkeypatch.setenv("LAMA_BUILD", str(build))
    source = harness / "driver.cpp"
    source.write_text("// driver\n")
    assert not lama_built(harness)  # no driver
    driver = build / "bin" / "lama_driver"
    driver.write_text("#!/bin/sh\n")
    os.utime(source, (1_000_000, 1_000_000))
    os.utime(driver, (2_000_000, 2_000_000))
    assert lama_built(harness)
    os.utime(source, (3_000_000, 3_000_000))  # the harness copied after the build
    assert not lama_built(harness)
