"""The robustness corpus (`pipelines.bench.corpus`): odometry faults a robot shows, relations from the
corrected poses, and the logs written so that `gslam ingest` reads them with their relations."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gslam.se2 import compose, inverse
from pipelines.bench.corpus import OdometryFaults, read_corrected, relations_from_poses, write_corrupted
from pipelines.evaluation.metrics import relations_error


def _loop(n: int = 200, radius_m: float = 8.0) -> np.ndarray:
    """A circle driven twice, a scan about every 0.5 m: revisits for the long relations."""
    a = np.linspace(0.0, 4 * math.pi, n)
    return np.column_stack([radius_m * np.cos(a), radius_m * np.sin(a), a + math.pi / 2])


NO_FAULTS = OdometryFaults(
    scale_sd=0,
    turn_bias_sd_rad_per_m=0,
    rotation_scale_sd=0,
    noise_trans_per_m=0,
    noise_trans_per_rad=0,
    noise_rot_per_rad=0,
    noise_rot_per_m=0,
    slip_per_m=0,
    dropout_per_scan=0,
)


def test_without_faults_the_odometry_is_the_corrected_path():
    poses = _loop()
    odom = NO_FAULTS.corrupt(poses, np.random.default_rng(0))
    np.testing.assert_allclose(odom[:, :2], poses[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.cos(odom[:, 2] - poses[:, 2]), 1.0, atol=1e-12)


def test_relations_of_the_reference_score_zero_and_the_faulty_odometry_does_not():
    poses = _loop()
    t = np.arange(len(poses), dtype=float)
    rel = relations_from_poses(t, poses, np.random.default_rng(1))
    short = rel[rel[:, 1] - rel[:, 0] <= 3]
    assert len(short) == 3 * len(poses) - 6 and len(rel) > len(short)  # and long ones, at the revisits
    assert relations_error(t, poses, rel)["relations_trans_m"] < 1e-9
    odom = OdometryFaults().corrupt(poses, np.random.default_rng(2))
    assert relations_error(t, odom, rel)["relations_trans_m"] > 0.05
    np.testing.assert_array_equal(OdometryFaults().corrupt(poses, np.random.default_rng(2)), odom)  # seeded


def test_each_fault_changes_the_motion_as_documented():
    poses = _loop()
    steps = lambda p: np.array([compose(inverse(p[k - 1]), p[k]) for k in range(1, len(p))])  # noqa: E731
    true = steps(poses)
    longer = dataclasses.replace(NO_FAULTS, scale_sd=1e-9)
    scaled = dataclasses.replace(NO_FAULTS, scale_sd=0.05).corrupt(poses, np.random.default_rng(3))
    ratio = np.hypot(*steps(scaled)[:, :2].T) / np.hypot(*true[:, :2].T)
    assert np.ptp(ratio) < 1e-9 and abs(ratio[0] - 1) > 1e-4  # one scale for the whole log
    assert longer.corrupt(poses, np.random.default_rng(3))[:, :2] == pytest.approx(poses[:, :2], abs=1e-6)
    dropped = dataclasses.replace(NO_FAULTS, dropout_per_scan=0.3).corrupt(poses, np.random.default_rng(4))
    stale = np.all(np.diff(dropped, axis=0) == 0, axis=1)
    assert 0.15 < stale.mean() < 0.45  # readings repeated ...
    np.testing.assert_allclose(dropped[-1, :2], poses[-1, :2], atol=1e-9)  # ... and the motion caught up
    back = poses[::-1].copy()  # the same path driven backwards: heading kept, every step a reverse
    back[:, 2] = poses[::-1, 2]
    flipped = NO_FAULTS.corrupt(back, np.random.default_rng(5))
    assert np.all(steps(flipped)[:, 0] > 0)  # reported forward
    assert np.all(steps(back)[:, 0] < 0)


def test_a_corrupted_log_is_ingested_with_its_relations(tmp_path):
    from ingest import read_log
    from pipelines.bench.corpus import CorrectedLog

    poses = _loop(60)
    ranges = [[f"{5.0 + 0.01 * k:.2f}"] * 180 for k in range(len(poses))]
    corrected = CorrectedLog(["PARAM robot_frontlaser_offset 0.0 nohost 0"], ranges, poses)
    log, odom = write_corrupted(corrected, tmp_path / "loop-s0.clf", seed=0)
    data = read_log(log)
    assert data.relations is not None and len(data.relations) >= 3 * 60 - 6
    assert len(data.scan_t_s) == 60 and data.geometry.beam_count == 180
    again = read_corrected(log)  # the written log reads back: the odometry in its poses
    np.testing.assert_allclose(again.poses, odom, atol=1e-6)


def test_radish_logs_beyond_the_corpus_are_found_and_written_like_its_own(tmp_path):
    """Any other `NAME-corrected.log.gz` beside the corpus's four is run the same way (logs outside the
    corpus, for the same rule); one named like a Freiburg log keeps apart from it."""
    import gzip

    from pipelines.bench.corpus import RADISH_LOGS, build_corpus, radish_logs
    from pipelines.bench.dispatch import corpus_logs

    folder = tmp_path / "datasets" / "radish"
    folder.mkdir(parents=True)
    poses = _loop(40)
    text = "".join(
        f"FLASER 3 4.0 4.1 4.2 {x:.4f} {y:.4f} {th:.4f} {x:.4f} {y:.4f} {th:.4f} {k}.0 h {k}.0\n"
        for k, (x, y, th) in enumerate(poses)
    )
    for name in ("orebro", "intel", "aces"):
        with gzip.open(folder / f"{name}-corrected.log.gz", "wt") as f:
            f.write(text)
    (folder / "notes.txt").write_text("not a log")
    names = radish_logs(tmp_path / "datasets")
    assert names == (*RADISH_LOGS, "aces", "intel-corrected", "orebro")
    assert radish_logs(tmp_path / "nowhere") == RADISH_LOGS
    assert corpus_logs("orebro,intel-corrected", tmp_path / "datasets") == ["orebro", "intel-corrected"]
    corpus = build_corpus(tmp_path / "datasets", tmp_path / "work", 0)
    assert [c.name for c in corpus] == ["aces", "intel-corrected", "orebro"]  # the four are absent here
    assert all(c.scans == 40 and c.log.with_suffix(".relations").exists() for c in corpus)
    assert corpus[1].log.name == "intel-corrected-s0.clf"


def test_the_verdict_is_the_issues_bar():
    from pathlib import Path

    from pipelines.bench.corpus import CorpusLog
    from pipelines.bench.robustness import LogResult, robustness_section

    log = CorpusLog("x", Path("x.clf"), 10, 5.0, "corrupted, seed 0")
    holds = LogResult(log, odometry_m=1.0, gslam_m={0: 0.05, 1: 0.06}, gmapping_m={0: 0.06, 1: 0.06})
    assert holds.verdict() == "holds"
    broken = LogResult(log, odometry_m=0.3, gslam_m={0: 0.05, 1: 0.4}, gmapping_m={0: 0.06, 1: 0.06})
    assert broken.verdict() == "mean above GMapping's; a seed above 2x GMapping; a seed worse than odometry"
    text = robustness_section([holds, broken], "gslam bench --suite robustness", "m", "s", 30, 0)
    assert "| x | 10 | 1.000 | 0.050 / 0.060 | 0.055 |" in text and text.count("| x |") == 4
