"""`gslam eval`: the metrics of docs (ALGORITHM.md "Metrics") for a result MCAP."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gslam.se2 import compose
from mcaplog import channels as ch
from mcaplog.mcapio import McapInput, Message, read_error
from pipelines.errors import InputError
from pipelines.evaluation.mcap_info import message_count
from pipelines.evaluation.metrics import (
    gps_mean_error,
    gps_mean_error_at_scans,
    gps_rmse_aligned,
    pole_map_error,
    relations_error,
    relations_frame_offset,
)
from pipelines.run.input_log import converted
from pipelines.run.recorded_input import process_result_metadata
from pipelines.run.recorded_input import recorded_input as checked_input

METRIC_KEYS = (
    "gps_mean_error_m",
    "gps_mean_error_online_m",
    "gps_rmse_aligned_m",
    "gps_mean_error_at_scans_m",
    "pole_map_error_m",
    "poles_within_1m",
    "relations_trans_m",
    "relations_trans_std_m",
    "relations_rot_deg",
    "ms_per_update_mean",
    "ms_per_step_median",
    "real_time_factor",
    "final_map_points",
    "particles",
    "points_per_observation",
)


@dataclass
class ResultData:
    """What a result MCAP holds, as arrays."""

    metadata: dict[str, Any]
    t_s: np.ndarray  # log time of each step
    stamp_s: np.ndarray  # sensor time stamp of each step
    online: np.ndarray  # (T, 3) best pose at each step
    trajectory: np.ndarray  # (T, 3) final best trajectory
    map_xy: np.ndarray
    map_p: np.ndarray
    step_ms: np.ndarray


def read_result(path: Path, progress: Callable[[int, int], None] | None = None) -> ResultData:
    """The steps, final trajectory and final map of a `gslam process` result; `progress(done, total)` counts
    the steps read (long logs take seconds)."""
    src = McapInput(path)
    meta = process_result_metadata(src, path)
    total = (message_count(src, ch.SLAM_POSE) or 0) if progress is not None else 0
    t, stamp, online, step_ms = [], [], [], []
    trajectory = None
    map_xy, map_p = np.empty((0, 2)), np.empty(0)

    def read(msg: Message) -> None:
        nonlocal trajectory, map_xy, map_p
        if msg.topic == ch.SLAM_POSE:
            pose = [msg.value.pose.position.x, msg.value.pose.position.y, ch.yaw_of(msg.value.pose)]
            stamp.append(ch.t_of(msg.value.timestamp))
            t.append(msg.t_s)
            online.append(pose)
            if progress is not None:
                progress(len(t), total)
        elif msg.topic == ch.SLAM_STATS:
            step_ms.append(float(msg.value["step_ms"]))
        elif msg.topic == ch.SLAM_TRAJECTORY:
            trajectory = ch.poses_of(msg.value)
        else:
            map_xy, map_p = ch.cloud_arrays(msg.value)

    for _ in converted(src, [ch.SLAM_POSE, ch.SLAM_TRAJECTORY, ch.SLAM_MAP_FINAL, ch.SLAM_STATS], read):
        pass
    if trajectory is None or len(trajectory) != len(t):
        raise InputError(f"{path}: no final trajectory matching the {len(t)} steps")
    return ResultData(
        meta,
        np.asarray(t),
        np.asarray(stamp),
        np.asarray(online).reshape(-1, 3),
        trajectory,
        map_xy,
        map_p,
        np.asarray(step_ms),
    )


def read_update_times(path: Path) -> list[float]:
    """The filter's time (ms) of every step of a result that updated the maps, in log order."""
    return [
        float(msg.value["step_ms"])
        for msg in McapInput(path).messages([ch.SLAM_STATS])
        if msg.value.get("updated", True)
    ]


def reference_truth(ref: McapInput) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """What an input MCAP knows of the truth: GPS (K, 3: t, x, y), poles (P, 2), relations (R, 5); None
    where it has none."""
    gps: list[list[float]] = []
    found: dict[str, np.ndarray] = {}

    def read(msg: Message) -> None:
        v = msg.value
        if msg.topic == ch.GPS:
            gps.append([msg.t_s, v.pose.position.x, v.pose.position.y])
        elif msg.topic == ch.LANDMARKS_TRUTH:
            found["poles"] = np.column_stack([v["x_m"], v["y_m"]]).astype(float)
        else:
            cols = [v["t1_s"], v["t2_s"], v["dx_m"], v["dy_m"], v["dyaw_rad"]]
            found["relations"] = np.column_stack(cols).astype(float)

    for _ in converted(ref, [ch.GPS, ch.LANDMARKS_TRUTH, ch.RELATIONS_TRUTH], read):
        pass
    return (np.asarray(gps) if gps else None), found.get("poles"), found.get("relations")


def _clean(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _check_reference(reference: Path) -> McapInput:
    """The reference must be an input MCAP (from `gslam ingest`), not a result or another file."""
    ref = McapInput(reference)
    try:
        meta = ref.metadata()
    except Exception as e:  # the mcap library raises several types for a damaged file
        raise InputError(f"{reference}: not a readable MCAP file ({read_error(e)})") from None
    if "result" in meta:
        raise InputError(
            f"--reference {reference} is a result of `gslam process`; give the input MCAP the run read "
            f"(from `gslam ingest`)"
        )
    if "dataset" not in meta:
        raise InputError(f"--reference {reference}: no 'dataset' metadata; is it an input MCAP from `gslam ingest`?")
    return ref


def recorded_input(result: Path) -> Path | None:
    """The input MCAP a result (of `gslam process` or `gslam localise`) names in its metadata (None when it
    names none or cannot be read)."""
    try:
        meta = McapInput(result).metadata()
    except Exception:  # an unreadable result is reported by the command that reads it
        return None
    path = meta["localise"].get("input") if "localise" in meta else meta.get("input", {}).get("path")
    return Path(path) if isinstance(path, str) and path else None


def partial_note(meta: dict[str, Any]) -> str | None:
    """A sentence saying the result is partial (interrupted, or cut by max_scans), else None."""
    r = meta.get("result", {})
    steps, total = r.get("steps"), r.get("scans_in_log")
    of = f" of {total}" if total else ""
    if r.get("interrupted"):
        why = r.get("error") or "interrupted"
        return f"partial result: the run was interrupted ({why}) after {steps}{of} scans; metrics cover those steps"
    if r.get("max_scans") and total and steps is not None and steps < total:
        return f"partial result: the run stopped at --max-scans after {steps}{of} scans"
    return None


RELATION_TOLERANCE_MS = 1.0
"""How close (ms) a relation's two times must be to steps' time stamps to be scored (`relations_error`)."""


def loop_closure_note(closure: dict[str, Any]) -> str:
    """One line on the back end's pose graph (the result's `loop_closure` record)."""

    def score(v: Any) -> str:
        return "-" if v is None else f"{v:.2f}"

    return (
        f"loop closure: {closure.get('nodes')} nodes, {closure.get('searches')} searches, "
        f"{closure.get('closures_kept')} closures kept (mean score {score(closure.get('kept_score_mean'))}), "
        f"{closure.get('closures_rejected')} rejected (mean score {score(closure.get('rejected_score_mean'))}); "
        f"search {closure.get('search_s')} s, {closure.get('optimisations')} optimisations "
        f"{closure.get('optimise_s')} s, {closure.get('seconds')} s in all; "
        f"the front end missed {closure.get('closures_missed_by_front_end')} of the closures: "
        + (
            "trajectory and map on the optimised graph"
            if closure.get("applied")
            else "they confirm it, trajectory and map left as they were"
        )
        + _live_note(closure.get("live"))
    )


def _live_note(live: dict[str, Any] | None) -> str:
    """The live graph's part of the loop-closure line (`loop_closure_live`)."""
    if not live:
        return ""
    when = live.get("first_corrected_step")
    return (
        f"; while the run went: {live.get('nodes')} nodes, {live.get('closures_kept')} closures kept, "
        + (
            f"/tf corrected from step {when} ({live.get('corrections_published')} corrections)"
            if when is not None
            else "/tf not corrected (the front end held its closures)"
        )
        + (f", stopped early: {live['error']}" if live.get("error") else "")
    )


def relations_note(given: int, matched: int, steps: int) -> str:
    """How many of the reference's relations were scored: a relation counts only when both its times match
    a step's sensor time stamp, so a log whose relations do not match its scans (another log's relations
    file, times on another clock, a run cut short) would otherwise just show n/a."""
    of = f"{given} relation{'s' if given != 1 else ''} given"
    if matched == 0:
        why = "the result has no steps" if steps == 0 else "no relation has both its times at scans' time stamps"
        return (
            f"relations: none of the {of} matched the run's scans (within {RELATION_TOLERANCE_MS:g} ms; {why}): "
            f"relations metric not computed"
        )
    within = f"within {RELATION_TOLERANCE_MS:g} ms"
    return f"relations: {matched} of the {of} matched the run's scans ({within}) and are scored"


FRAME_NOTE_M = 0.02
"""The offset between the relations' frame and the trajectory's (`relations_frame_offset`) from which
`gslam eval` says so."""


def frame_note(t_s: np.ndarray, poses: np.ndarray, relations: np.ndarray) -> str | None:
    """A note when the relations' frame lies `FRAME_NOTE_M` or more from the trajectory's, with the error
    scored in the relations' frame; None otherwise (or when too few turns in place tell)."""
    found = relations_frame_offset(t_s, poses, relations, RELATION_TOLERANCE_MS / 1e3)
    if found is None or float(np.hypot(*found[0])) < FRAME_NOTE_M:
        return None
    (ox, oy), turns = found
    moved = compose(poses, np.array([ox, oy, 0.0]))
    fitted = relations_error(t_s, moved, relations, RELATION_TOLERANCE_MS / 1e3)["relations_trans_m"]
    return (
        f"relations' frame: its origin lies {ox:.3f} m ahead and {oy:.3f} m left of the trajectory's, by the "
        f"{turns} turns in place of the reference (a sensor offset one of the two carries and the other does "
        f"not); the relations scored in that frame: {fitted:.3f} m"
    )


def evaluate_result(result: Path, reference: Path | None = None) -> dict[str, Any]:
    """All metrics, None where the data does not allow one, with `interrupted`, `steps` and `notes`
    (what the figures mean for this run: partial, no GPS). The reference (input MCAP) is found from the
    result's metadata when not given."""
    res = read_result(result)
    meta = res.metadata
    if reference is None:
        reference = checked_input(result, meta, "--reference")
    ref = _check_reference(reference)
    notes: list[str] = []
    partial = partial_note(meta)
    if partial:
        notes.append(partial)
    gps, poles, relations = reference_truth(ref)
    out: dict[str, Any] = dict.fromkeys(METRIC_KEYS)
    if gps is not None and len(res.t_s):
        g = gps
        out["gps_mean_error_m"] = gps_mean_error(res.t_s, res.trajectory, g)
        out["gps_mean_error_online_m"] = gps_mean_error(res.t_s, res.online, g)
        out["gps_rmse_aligned_m"] = gps_rmse_aligned(res.t_s, res.trajectory, g)
        out["gps_mean_error_at_scans_m"] = gps_mean_error_at_scans(res.t_s, res.trajectory, g)
    from_gps = meta.get("initialisation", {}).get("from_gps", gps is not None)
    if poles is not None and len(res.map_p) and not from_gps:
        notes.append(
            "pole map error not computed: the run did not start from GPS, so its map is not in the frame of "
            "the surveyed poles"
        )
    elif poles is not None and len(res.map_p):
        err, n = pole_map_error(res.map_xy, res.map_p, poles)
        out["pole_map_error_m"] = err
        out["poles_within_1m"] = n
    if gps is None and relations is None and poles is None:
        notes.append("no ground truth in the reference (GPS, poles or relations): only speed and map size")
    if relations is not None:
        rel = {"relations_used": 0}
        if len(res.t_s):
            rel = relations_error(res.stamp_s, res.trajectory, relations, RELATION_TOLERANCE_MS / 1e3)
        for k in ("relations_trans_m", "relations_trans_std_m", "relations_rot_deg"):
            out[k] = rel.get(k)
        notes.append(relations_note(len(relations), rel["relations_used"], len(res.t_s)))
        if len(res.t_s):
            frame = frame_note(res.stamp_s, res.trajectory, relations)
            if frame:
                notes.append(frame)
    r = meta["result"]
    placement = r.get("placement")
    if isinstance(placement, dict) and placement.get("scans"):
        notes.append(
            f"every scan placed by the final map: {placement.get('matched')} of {placement['scans']} matched, "
            f"{placement.get('between_matched')} placed between matched neighbours, "
            f"{placement.get('no_returns')} without returns"
            + (
                f"; {placement['retracked_segments']} update segments placed from the pose tracked to them"
                if placement.get("retracked_segments")
                else ""
            )
        )
    closure = r.get("loop_closure")
    if isinstance(closure, dict):
        notes.append(loop_closure_note(closure))
    out["ms_per_update_mean"] = r.get("ms_per_update_mean")
    out["ms_per_step_median"] = r.get("ms_per_step_filter_median")
    out["real_time_factor"] = r.get("real_time_factor")
    out["final_map_points"] = r.get("final_map_points")
    out["particles"] = meta["config"]["filter"]["particles"]
    out["points_per_observation"] = meta["config"]["filter"]["points_per_observation"]
    cleaned = {k: _clean(v) for k, v in out.items()}
    return {"interrupted": bool(r.get("interrupted")), "steps": r.get("steps"), **cleaned, "notes": notes}
