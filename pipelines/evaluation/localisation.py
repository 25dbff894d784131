"""Localisation results (`gslam localise`) read back, for `gslam eval`, `plot` and `export`.

A localisation result is told from a mapping result by its metadata: `gslam localise` writes "localise"
(and "result"), `gslam process` writes "config" and "result". Its figures: the scans, the share the filter
says it tracks, when it first claimed a place, the fitness, the time per scan; and, given a reference, the
error of the estimate at the scans it tracks. The reference is a trajectory:

- a `gslam process` result MCAP: its final trajectory, matched to the localisation's scans by stamp
  (both write the scan's own stamp; the same log localised in its own SLAM map pairs scan for scan);
- a TUM file (`t x y z qx qy qz qw`, as `gslam export --tum` or evo write): matched by stamp;
- an input MCAP from `gslam ingest` (by default the one the localisation read): its true poses or GPS,
  interpolated at the scans' log times as `gslam eval` does for mapping results (GPS: position only), and
  its relations (Kuemmerle et al.), scored on the tracked scans as for mapping results.

Lost scans are not scored: the estimate there is the filter's best guess while it says it does not know.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gslam.motion import wrap_angle
from mcaplog import channels as ch
from mcaplog.mcapio import MCAP_MAGIC, McapInput, Message, read_error
from pipelines.errors import InputError
from pipelines.evaluation.mcap_info import message_count
from pipelines.evaluation.metrics import interpolate_positions, relations_error

LOCALISE_METADATA = "localise"
"""The metadata record only a localisation result has."""
POSE_TOPIC = "/localise/pose"
STATE_TOPIC = "/localise/state"
PARTICLES_TOPIC = "/localise/particles"
MAP_TOPIC = "/localise/map"
MATCH_TOLERANCE_S = 0.01
"""A reference pose is paired with a scan when their stamps differ by at most this (evo's default
`--t_max_diff`); the nearest is taken."""

LOCALISATION_KEYS = (
    "scans",
    "updates",
    "tracked_share",
    "first_tracking_scan",
    "first_tracking_time_s",
    "first_tracking_travel_m",
    "fitness_mean",
    "fitness_mean_tracking",
    "ms_per_scan",
    "real_time_factor",
    "reference",
    "reference_scans",
    "error_trans_mean_m",
    "error_trans_median_m",
    "error_trans_max_m",
    "error_rot_mean_deg",
    "error_rot_median_deg",
    "error_rot_max_deg",
    "relations_trans_m",
    "relations_trans_std_m",
    "relations_rot_deg",
    "relations_used",
)
"""What `evaluate_localisation` reports, in the order `gslam eval` prints it."""


def result_metadata(path: Path) -> dict[str, Any]:
    """The metadata of a result MCAP; InputError in one line when it is not a readable MCAP."""
    try:
        return McapInput(path).metadata()
    except Exception as e:  # the mcap library raises several types for a damaged file
        raise InputError(f"{path}: not a readable MCAP file ({read_error(e)})") from None


def is_localisation(metadata: dict[str, Any]) -> bool:
    """Whether metadata is a `gslam localise` result's."""
    return LOCALISE_METADATA in metadata


def is_localisation_result(path: Path) -> bool:
    """Whether the MCAP at `path` is a `gslam localise` result (InputError when it cannot be read)."""
    return is_localisation(result_metadata(path))


def checked_input(result: Path, metadata: dict[str, Any], option: str) -> Path:
    """The input MCAP a localisation result read, when it is still that file (as
    `pipelines.run.recorded_input` checks a mapping result's); InputError naming `option` otherwise."""
    from pipelines.run.recorded_input import recorded_input

    entry = metadata.get(LOCALISE_METADATA, {})
    recorded = {"path": entry.get("input"), "fingerprint": entry.get("input_fingerprint")}
    return recorded_input(result, {"input": recorded}, option)


@dataclass
class LocalisationData:
    """What a localisation result holds, as arrays over its scans."""

    metadata: dict[str, Any]
    t_s: np.ndarray
    """(T,) each scan's log time."""
    stamp_s: np.ndarray
    """(T,) each scan's own stamp (the header stamp of /localise/pose)."""
    poses: np.ndarray
    """(T, 3) the base's estimate in the map frame: x [m], y [m], heading [rad]."""
    tracking: np.ndarray
    """(T,) the filter says it tracks."""
    fitness: np.ndarray
    """(T,) the share of the scan's returns the map explains at the estimate."""
    particles: np.ndarray
    """(T,) the particle count."""
    step_ms: np.ndarray
    """(T,) the filter's time for the scan [ms]."""
    map_xy: np.ndarray
    """(K, 2) the map's obstacles the run localised against."""

    @property
    def first_tracking(self) -> int | None:
        """The index of the first scan the filter tracks, None when it never does."""
        idx = np.flatnonzero(self.tracking)
        return int(idx[0]) if len(idx) else None


def read_localisation(path: Path, progress: Callable[[int, int], None] | None = None) -> LocalisationData:
    """The scans of a localisation result; `progress(done, total)` counts the scans read."""
    from pipelines.run.input_log import converted

    meta = result_metadata(path)
    if not is_localisation(meta):
        raise InputError(f"{path}: no 'localise' metadata; is this a result of `gslam localise`?")
    src = McapInput(path)
    total = message_count(src, STATE_TOPIC) or 0
    t: list[float] = []
    stamp: list[float] = []
    states: list[dict[str, Any]] = []
    map_xy = np.empty((0, 2))

    def read(msg: Message) -> None:
        nonlocal map_xy
        if msg.topic == POSE_TOPIC:
            stamp.append(ch.t_of(msg.value.timestamp))
        elif msg.topic == STATE_TOPIC:
            t.append(msg.t_s)
            states.append(msg.value)
            if progress is not None:
                progress(len(states), total)
        else:
            map_xy = ch.cloud_arrays(msg.value)[0]

    for _ in converted(src, [POSE_TOPIC, STATE_TOPIC, MAP_TOPIC], read):
        pass
    if not states or len(stamp) != len(states):
        raise InputError(
            f"{path}: {len(states)} {STATE_TOPIC} and {len(stamp)} {POSE_TOPIC} messages; a result of "
            "`gslam localise` has one of each per scan"
        )
    try:

        def column(key: str, dtype=float) -> np.ndarray:
            return np.array([s[key] for s in states], dtype=dtype)

        return LocalisationData(
            meta,
            np.asarray(t, dtype=float),
            np.asarray(stamp, dtype=float),
            np.column_stack([column("x_m"), column("y_m"), column("yaw_rad")]),
            column("tracking", bool),
            column("fitness"),
            column("particles"),
            column("step_ms"),
            map_xy,
        )
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{path}: a {STATE_TOPIC} message is malformed ({e!r})") from None


@dataclass
class Reference:
    """A reference trajectory to score a localisation against."""

    what: str
    """What it is, for the user."""
    when_s: np.ndarray
    """(N,) when each pose was: its stamp (`by_stamp`) or its log time (otherwise)."""
    poses: np.ndarray
    """(N, 3) x, y, heading (heading unused when `has_heading` is False)."""
    has_heading: bool
    by_stamp: bool
    """True: each scan takes the pose whose stamp is nearest to its stamp, within MATCH_TOLERANCE_S. False:
    positions (and headings) interpolated at the scans' log times, inside the reference's span."""
    relations: np.ndarray | None = None
    """(R, 5) relations (t1, t2, dx, dy, dyaw) of the input, where it has them."""

    def at(self, loc: LocalisationData) -> tuple[np.ndarray, np.ndarray]:
        """(mask of the scans that have a reference pose, (M, 3) those poses)."""
        if len(self.when_s) == 0:
            return np.zeros(len(loc.t_s), dtype=bool), np.empty((0, 3))
        if self.by_stamp:
            order = np.argsort(self.when_s, kind="stable")
            ts, stamps = self.when_s[order], loc.stamp_s
            after = np.searchsorted(ts, stamps)
            lo, hi = np.clip(after - 1, 0, len(ts) - 1), np.clip(after, 0, len(ts) - 1)
            nearest = np.where(np.abs(ts[lo] - stamps) <= np.abs(ts[hi] - stamps), lo, hi)
            ok = np.abs(ts[nearest] - stamps) <= MATCH_TOLERANCE_S
            return ok, self.poses[order[nearest[ok]]]
        if len(self.when_s) < 2:
            return np.zeros(len(loc.t_s), dtype=bool), np.empty((0, 3))
        inside, xy = interpolate_positions(self.when_s, self.poses[:, :2], loc.t_s)
        heading = np.interp(loc.t_s[inside], self.when_s, np.unwrap(self.poses[:, 2]))
        return inside, np.column_stack([xy, heading])


def read_tum(path: Path) -> np.ndarray:
    """(N, 8) the rows `t x y z qx qy qz qw` of a TUM trajectory file (comment lines start with #)."""
    try:
        text = Path(path).read_text()
    except UnicodeDecodeError:
        raise InputError(f"--reference {path}: not a text file (a TUM trajectory is lines of 8 numbers)") from None
    except OSError as e:
        raise InputError(f"--reference {path}: cannot read it ({e.strerror})") from None
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        try:
            row = [float(v) for v in parts]
        except ValueError:
            row = []
        if len(row) != 8 or not all(math.isfinite(v) for v in row):
            raise InputError(
                f"--reference {path}: line {n} is not a TUM pose (8 numbers: t x y z qx qy qz qw); "
                "give a TUM file, a `gslam process` result or an input MCAP"
            )
        rows.append(row)
    if not rows:
        raise InputError(f"--reference {path}: no poses (a TUM trajectory is lines of t x y z qx qy qz qw)")
    return np.array(rows)


def _from_tum(path: Path) -> Reference:
    rows = read_tum(path)
    qx, qy, qz, qw = rows[:, 4], rows[:, 5], rows[:, 6], rows[:, 7]
    yaw = np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
    poses = np.column_stack([rows[:, 1:3], yaw])
    return Reference(f"{path.name} (TUM, matched by stamp)", rows[:, 0], poses, has_heading=True, by_stamp=True)


def _from_input(path: Path, what: str) -> Reference | None:
    """The truth an input MCAP holds (true poses, else GPS; and relations), None when it holds none."""
    from pipelines.evaluation.evaluate import reference_truth
    from pipelines.run.input_log import converted

    src = McapInput(path)

    def pose(m: Message) -> list[float]:
        return [m.t_s, m.value.pose.position.x, m.value.pose.position.y, ch.yaw_of(m.value.pose)]

    truth = list(converted(src, [ch.TRAJECTORY_TRUTH], pose))
    gps, _, relations = reference_truth(src)
    if len(truth) >= 2:
        rows = np.array(truth)
        return Reference(f"{what}: its true poses", rows[:, 0], rows[:, 1:], True, False, relations)
    if gps is not None and len(gps) >= 2:
        poses = np.column_stack([gps[:, 1:3], np.zeros(len(gps))])
        return Reference(f"{what}: its GPS (position only)", gps[:, 0], poses, False, False, relations)
    if relations is not None:
        return Reference(f"{what}: its relations", np.empty(0), np.empty((0, 3)), False, False, relations)
    return None


def load_reference(
    result: Path, metadata: dict[str, Any], reference: Path | None
) -> tuple[Reference | None, list[str]]:
    """The reference `--reference` names (None: the truth of the input the localisation read), with notes
    on what could not be used."""
    notes: list[str] = []
    if reference is None:
        try:
            path = checked_input(result, metadata, "--reference")
        except InputError as e:
            return None, [f"no reference: {e}"]
        ref = _from_input(path, f"the input {path.name}")
        if ref is None:
            notes.append(
                f"no reference: the input {path.name} holds no true poses, GPS or relations; give --reference: the "
                "`gslam process` result of the same log (e.g. the map, when it was built from this input) or a "
                "TUM trajectory"
            )
        return ref, notes
    reference = Path(reference)
    if not reference.is_file():
        raise InputError(f"--reference {reference}: no such file")
    if not _is_mcap(reference):
        return _from_tum(reference), notes
    meta = result_metadata(reference)
    if is_localisation(meta):
        raise InputError(
            f"--reference {reference} is a localisation result; give a `gslam process` result, a TUM trajectory "
            "or an input MCAP"
        )
    if "result" in meta and "config" in meta:
        from pipelines.evaluation.evaluate import read_result

        res = read_result(reference)
        what = f"{reference.name}: the final trajectory of `gslam process`, matched by stamp"
        return Reference(what, res.stamp_s, res.trajectory, has_heading=True, by_stamp=True), notes
    if "dataset" in meta:
        ref = _from_input(reference, f"the input {reference.name}")
        if ref is None:
            raise InputError(
                f"--reference {reference}: an input MCAP with no true poses, GPS or relations to score with"
            )
        return ref, notes
    raise InputError(
        f"--reference {reference}: an MCAP that is neither a `gslam process` result nor an input from `gslam ingest`"
    )


def _is_mcap(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(len(MCAP_MAGIC)) == MCAP_MAGIC
    except OSError:
        return False


def pose_errors(estimate: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(translation error [m], absolute heading error [deg]) of (K, 3) estimates against (K, 3) references."""
    trans = np.hypot(*(estimate[:, :2] - reference[:, :2]).T)
    rot = np.degrees(np.abs(wrap_angle(estimate[:, 2] - reference[:, 2])))
    return trans, rot


def _stats(values: np.ndarray) -> tuple[float | None, float | None, float | None]:
    if len(values) == 0:
        return None, None, None
    return float(np.mean(values)), float(np.median(values)), float(np.max(values))


def evaluate_localisation(
    result: Path, reference: Path | None = None, progress: Callable[[int, int], None] | None = None
) -> dict[str, Any]:
    """The figures of a localisation result (`LOCALISATION_KEYS`, None where the data allow none), with
    "kind": "localisation" and "interrupted" (stopped by a signal: the figures cover the scans done) first and
    "notes" last (what the figures mean for this run)."""
    loc = read_localisation(result, progress)
    meta = loc.metadata
    summary = meta.get("result", {})
    out: dict[str, Any] = dict.fromkeys(LOCALISATION_KEYS)
    n = len(loc.t_s)
    out["scans"] = n
    out["updates"] = summary.get("updates")
    out["tracked_share"] = float(loc.tracking.mean())
    first = loc.first_tracking
    if first is not None:
        out["first_tracking_scan"] = first
        out["first_tracking_time_s"] = float(loc.t_s[first] - loc.t_s[0])
        out["first_tracking_travel_m"] = summary.get("converged_at_m")
    out["fitness_mean"] = float(np.mean(loc.fitness))
    if loc.tracking.any():
        out["fitness_mean_tracking"] = float(np.mean(loc.fitness[loc.tracking]))
    out["ms_per_scan"] = summary.get("ms_per_scan")
    wall = summary.get("wall_s")
    if isinstance(wall, int | float) and wall > 0 and n > 1:
        out["real_time_factor"] = float((loc.t_s[-1] - loc.t_s[0]) / wall)
    notes: list[str] = []
    interrupted = bool(summary.get("interrupted"))
    if interrupted:  # `gslam localise` stopped by a signal: the result holds the scans done before it
        total = summary.get("scans_in_input")
        of = f" of {total}" if isinstance(total, int) else ""
        why = summary.get("error") or "a signal"
        notes.append(
            f"partial result: the localisation was interrupted ({why}) after {n}{of} scans; the figures cover those"
        )
    if first is None:
        notes.append("the filter never tracked: no error is computed (lost scans are not scored)")
    ref, ref_notes = load_reference(result, meta, reference)
    notes += ref_notes
    if ref is not None:
        out["reference"] = ref.what
        has, ref_poses = ref.at(loc)
        if len(ref.when_s):
            scored = has & loc.tracking
            out["reference_scans"] = int(scored.sum())
            trans, rot = pose_errors(loc.poses[scored], ref_poses[loc.tracking[has]])
            out["error_trans_mean_m"], out["error_trans_median_m"], out["error_trans_max_m"] = _stats(trans)
            if ref.has_heading:
                out["error_rot_mean_deg"], out["error_rot_median_deg"], out["error_rot_max_deg"] = _stats(rot)
            if loc.tracking.any() and scored.sum() < loc.tracking.sum():
                notes.append(
                    f"the reference covers {int(scored.sum())} of the {int(loc.tracking.sum())} tracked scans; the "
                    "error is over those"
                )
            if not ref.by_stamp:
                notes.append(
                    "the error against the input's own truth assumes the map is in its frame (a map `gslam process` "
                    "started from GPS, or a simulator's)"
                )
        if ref.relations is not None and loc.tracking.any():
            rel = relations_error(loc.stamp_s[loc.tracking], loc.poses[loc.tracking], ref.relations)
            for k in ("relations_trans_m", "relations_trans_std_m", "relations_rot_deg", "relations_used"):
                out[k] = rel[k]
            if not rel["relations_used"]:
                notes.append("no relation has both its scans tracked: the relations error is not computed")
    cleaned = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in out.items()}
    return {"kind": "localisation", "interrupted": interrupted, **cleaned, "notes": notes}
