"""The robustness corpus: real 2-D laser logs with odometry a robot really shows, scored by relations.

Two kinds of log (`../shared/datasets`):

- the Freiburg logs with their published relations (intel, mit-csail, fr079 with its real sign error
  when the robot backs up), used as they are;
- the Radish "corrected" logs: real scans at poses already corrected by SLAM, no raw odometry. Each is
  written here as a CARMEN log whose odometry is the corrected motion corrupted by `OdometryFaults`
  (seeded: the same log and seed give the same file), with relations built from the corrected poses
  (`relations_from_poses`) beside it, so that `gslam ingest` and the GMapping harness read it alike.

The faults, all applied to the motion between consecutive scans, in the robot's frame, with
magnitudes drawn once per log (the log's "robot") from the seed:

| fault | model | magnitude drawn |
|---|---|---|
| scale error | translation x (1 + s) | s ~ N(0, 0.03) (wheel radius off by a few percent) |
| turn bias | heading += k x translation | k ~ N(0, 0.01) rad/m (unequal wheels curve the path) |
| rotation scale | rotation x (1 + g) | g ~ N(0, 0.03) (wheelbase off) |
| noise growing with motion | sd 0.03 m/m + 0.01 m/rad along, 0.03 rad/rad + 0.01 rad/m of heading | fixed |
| wheel slip bursts | 0.02 per metre; 1 to 3 scans report 1.2 to 2x the motion, heading off (sd 0.05 rad) | fixed |
| sign error when reversing | a backward step is reported forward | wherever the corrected path backs up |
| dropouts | 0.02 per scan: the reading repeats the last one; the motion is caught up at the next | fixed |

The reference is itself a SLAM result: differences below a few centimetres say little.
"""

from __future__ import annotations

import gzip
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gslam.motion import wrap_angle
from gslam.se2 import compose, inverse

FREIBURG_LOGS = ("mit-csail", "intel", "fr079")
RADISH_LOGS = ("belgioioso", "edmonton", "seattle", "freiburg-campus")
CORRECTED_SUFFIX = "-corrected.log.gz"
SCAN_PERIOD_S = 1.0
"""The clock given to the Radish scans (their own stamps are zero or repeated): one scan a second."""


@dataclass(frozen=True)
class OdometryFaults:
    """The corruption models of the module docstring; a robot is one draw of the magnitudes."""

    scale_sd: float = 0.03
    turn_bias_sd_rad_per_m: float = 0.01
    rotation_scale_sd: float = 0.03
    noise_trans_per_m: float = 0.03
    noise_trans_per_rad: float = 0.01
    noise_rot_per_rad: float = 0.03
    noise_rot_per_m: float = 0.01
    slip_per_m: float = 0.02
    slip_scans: tuple[int, int] = (1, 3)
    slip_gain: tuple[float, float] = (1.2, 2.0)
    slip_heading_sd_rad: float = 0.05
    reverse_sign_error: bool = True
    dropout_per_scan: float = 0.02

    def corrupt(self, poses: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Odometry poses (N, 3) for the corrected poses (N, 3): the same start, each step's motion in the
        robot frame corrupted by the models, integrated."""
        poses = np.asarray(poses, dtype=float)
        n = len(poses)
        out = np.empty_like(poses)
        if n == 0:
            return out
        scale = 1.0 + rng.normal(0.0, self.scale_sd)
        bias = rng.normal(0.0, self.turn_bias_sd_rad_per_m)
        rot_scale = 1.0 + rng.normal(0.0, self.rotation_scale_sd)
        out[0] = poses[0]
        reported = poses[0].copy()  # the odometry's own integrated pose
        slip_left, slip_gain, slip_turn = 0, 1.0, 0.0
        pending = np.zeros(3)  # motion not yet reported (a dropout)
        for k in range(1, n):  # one step per scan: a few thousand at most
            step = compose(inverse(poses[k - 1]), poses[k])  # the true motion in the robot frame
            step[2] = wrap_angle(step[2])
            trans = math.hypot(step[0], step[1])
            forward = step[0] >= 0.0
            direction = math.atan2(step[1], step[0]) if trans > 1e-9 else 0.0
            if not forward and self.reverse_sign_error:
                direction = wrap_angle(direction + math.pi)  # backing up reported as going forward
            rot = step[2]
            if slip_left == 0 and rng.random() < 1.0 - math.exp(-self.slip_per_m * trans):
                slip_left = int(rng.integers(self.slip_scans[0], self.slip_scans[1] + 1))
                slip_gain = float(rng.uniform(*self.slip_gain))
                slip_turn = float(rng.normal(0.0, self.slip_heading_sd_rad))
            gain, turn = 1.0, 0.0
            if slip_left > 0:
                gain, turn = slip_gain, slip_turn / slip_left
                slip_left -= 1
            t_odo = trans * scale * gain
            r_odo = rot * rot_scale + bias * trans + turn
            sd_t = self.noise_trans_per_m * trans + self.noise_trans_per_rad * abs(rot)
            sd_r = self.noise_rot_per_rad * abs(rot) + self.noise_rot_per_m * trans
            t_odo += rng.normal(0.0, sd_t)
            r_odo += rng.normal(0.0, sd_r)
            motion = np.array([t_odo * math.cos(direction), t_odo * math.sin(direction), r_odo])
            pending = compose(pending, motion)
            if rng.random() < self.dropout_per_scan and k < n - 1:
                out[k] = reported  # stale reading: the motion is reported with the next one
                continue
            reported = compose(reported, pending)
            reported[2] = wrap_angle(reported[2])
            pending = np.zeros(3)
            out[k] = reported
        return out


def relations_from_poses(
    t_s: np.ndarray,
    poses: np.ndarray,
    rng: np.random.Generator,
    short: int = 3,
    long_radius_m: float = 3.0,
    long_min_gap: int = 10,
    long_per_scan: float = 0.5,
) -> np.ndarray:
    """Relations (R, 5: t1, t2, dx, dy, dyaw) between reference poses, Kuemmerle et al. style: each scan to
    its `short` successors, and long ones between scans at least `long_min_gap` apart that lie within
    `long_radius_m` of each other (revisits, where a loop must hold), about `long_per_scan` per scan,
    drawn with `rng`."""
    poses = np.asarray(poses, dtype=float)
    n = len(poses)
    rows: list[tuple[int, int]] = [(i, j) for i in range(n) for j in range(i + 1, min(n, i + 1 + short))]
    d = np.hypot(poses[:, None, 0] - poses[None, :, 0], poses[:, None, 1] - poses[None, :, 1])
    i_idx, j_idx = np.nonzero((d < long_radius_m) & (np.arange(n)[None, :] - np.arange(n)[:, None] >= long_min_gap))
    if len(i_idx):
        take = min(len(i_idx), int(round(long_per_scan * n)))
        chosen = rng.choice(len(i_idx), size=take, replace=False)
        rows += [(int(i_idx[c]), int(j_idx[c])) for c in np.sort(chosen)]
    out = np.empty((len(rows), 5))
    for r, (i, j) in enumerate(rows):
        rel = compose(inverse(poses[i]), poses[j])
        out[r] = (t_s[i], t_s[j], rel[0], rel[1], wrap_angle(rel[2]))
    return out


@dataclass
class CorrectedLog:
    """A Radish corrected log: its PARAM lines, its scans (ranges as written) and corrected poses."""

    params: list[str]
    ranges: list[list[str]]
    poses: np.ndarray

    @property
    def path_m(self) -> float:
        return float(np.hypot(*np.diff(self.poses[:, :2], axis=0).T).sum())


def read_corrected(path: Path) -> CorrectedLog:
    """The PARAM lines and the FLASER scans (ranges, corrected pose) of a Radish corrected CARMEN log."""
    params, ranges, poses = [], [], []
    with gzip.open(path, "rt") if str(path).endswith(".gz") else open(path) as f:
        for line in f:
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "PARAM":
                params.append(line.rstrip("\n"))
            elif parts[0] == "FLASER":
                n = int(parts[1])
                ranges.append(parts[2 : 2 + n])
                poses.append([float(v) for v in parts[2 + n : 5 + n]])
    return CorrectedLog(params, ranges, np.asarray(poses, dtype=float).reshape(-1, 3))


@dataclass
class CorpusLog:
    """One log of the corpus: the CARMEN log the methods read, its relations beside it."""

    name: str
    log: Path
    scans: int
    path_m: float
    source: str
    """"real odometry" (Freiburg) or "corrupted from corrected poses, seed S" (Radish)."""


def write_corrupted(
    corrected: CorrectedLog, out: Path, seed: int, faults: OdometryFaults | None = None
) -> tuple[Path, np.ndarray]:
    """Write `out` (a .clf) with the corrected log's scans and corrupted odometry, and its relations
    beside it (`out` with .relations); returns (the log's path, the odometry poses)."""
    faults = faults or OdometryFaults()
    rng = np.random.default_rng(seed)
    odom = faults.corrupt(corrected.poses, rng)
    t = np.arange(len(corrected.poses)) * SCAN_PERIOD_S + SCAN_PERIOD_S
    relations = relations_from_poses(t, corrected.poses, np.random.default_rng(seed + 1_000_003))
    out.parent.mkdir(parents=True, exist_ok=True)
    lines = [*corrected.params]
    for k, (r, pose) in enumerate(zip(corrected.ranges, odom, strict=True)):
        x, y, th = (f"{v:.6f}" for v in pose)
        lines.append(f"FLASER {len(r)} {' '.join(r)} {x} {y} {th} {x} {y} {th} {t[k]:.6f} corpus {t[k]:.6f}")
    out.write_text("\n".join(lines) + "\n")
    rel_lines = [f"{a:.6f} {b:.6f} {dx:.6f} {dy:.6f} 0 0 0 {dyaw:.6f}" for a, b, dx, dy, dyaw in relations]
    out.with_suffix(".relations").write_text("\n".join(rel_lines) + "\n")
    return out, odom


def radish_logs(datasets: Path) -> tuple[str, ...]:
    """The Radish logs of the corpus: the four of `../shared/datasets` (RADISH_LOGS), then any other
    `NAME-corrected.log.gz` in `datasets/radish`, by name (e.g. the other nine of the same collection,
    acschaefer/ple's data/carmen), so that logs outside the corpus are run the same way. One whose name is a
    Freiburg log's is called `NAME-corrected`."""
    folder = datasets / "radish"
    files = folder.glob(f"*{CORRECTED_SUFFIX}") if folder.is_dir() else []
    found = sorted(p.name[: -len(CORRECTED_SUFFIX)] for p in files)
    more = [name for name in found if name not in RADISH_LOGS]
    return RADISH_LOGS + tuple(f"{name}-corrected" if name in FREIBURG_LOGS else name for name in more)


def _radish_source(datasets: Path, name: str) -> Path:
    """The corrected log behind the corpus name `name`: the inverse of `radish_logs`' renaming (a name
    that clashes with a Freiburg log's is called `NAME-corrected`)."""
    base = name.removesuffix("-corrected")
    return datasets / "radish" / f"{base if base in FREIBURG_LOGS else name}{CORRECTED_SUFFIX}"


def build_corpus(
    datasets: Path, workdir: Path, seed: int = 0, radish: tuple[str, ...] | None = None
) -> list[CorpusLog]:
    """The corpus in `workdir`: the Freiburg logs by path, the Radish logs (`radish`, by default
    `radish_logs(datasets)`) written with corrupted odometry (odometry seed `seed`). Logs whose files are
    absent are left out (the caller says which)."""
    if radish is None:
        radish = radish_logs(datasets)
    corpus: list[CorpusLog] = []
    for name in FREIBURG_LOGS:
        log = datasets / "freiburg" / f"{name}.clf.gz"
        if log.exists():
            corpus.append(CorpusLog(name, log, 0, float("nan"), "real odometry"))
    for name in radish:
        src = _radish_source(datasets, name)
        if not src.exists():
            continue
        corrected = read_corrected(src)
        out = workdir / f"{name}-s{seed}.clf"
        if not out.exists() or not out.with_suffix(".relations").exists():
            write_corrupted(corrected, out, seed)
        corpus.append(CorpusLog(name, out, len(corrected.ranges), corrected.path_m, f"corrupted, seed {seed}"))
    return corpus
