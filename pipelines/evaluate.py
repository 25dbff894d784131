"""`gslam eval`: the metrics of docs (ALGORITHM.md "Metrics") for a result MCAP."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gslam.metrics import gps_mean_error, gps_rmse_aligned, pole_map_error, relations_error
from mcaplog import channels as ch
from mcaplog.mcapio import McapInput

from .errors import InputError

METRIC_KEYS = (
    "gps_mean_error_m",
    "gps_mean_error_online_m",
    "gps_rmse_aligned_m",
    "pole_map_error_m",
    "poles_within_1m",
    "relations_trans_m",
    "relations_trans_std_m",
    "relations_rot_deg",
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


def read_result(path: Path) -> ResultData:
    src = McapInput(path)
    try:
        meta = src.metadata()
    except Exception as e:
        raise InputError(f"{path}: not a readable MCAP file ({type(e).__name__}: {e})") from None
    if "result" not in meta or "config" not in meta:
        raise InputError(f"{path}: no 'result'/'config' metadata; is this a result of `gslam process`?")
    t, stamp, online, step_ms = [], [], [], []
    trajectory = None
    map_xy, map_p = np.empty((0, 2)), np.empty(0)
    for msg in src.messages([ch.SLAM_POSE, ch.SLAM_TRAJECTORY, ch.SLAM_MAP_FINAL, ch.SLAM_STATS]):
        if msg.topic == ch.SLAM_POSE:
            t.append(msg.t_s)
            stamp.append(ch.t_of(msg.value.timestamp))
            online.append([msg.value.pose.position.x, msg.value.pose.position.y, ch.yaw_of(msg.value.pose)])
        elif msg.topic == ch.SLAM_STATS:
            step_ms.append(msg.value["step_ms"])
        elif msg.topic == ch.SLAM_TRAJECTORY:
            trajectory = ch.poses_of(msg.value)
        else:
            map_xy, map_p = ch.cloud_arrays(msg.value)
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


def _clean(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def evaluate_result(result: Path, reference: Path | None = None) -> dict[str, Any]:
    """All metrics, None where the data does not allow one. The reference (input MCAP) is found from
    the result's metadata when not given."""
    res = read_result(result)
    meta = res.metadata
    if reference is None:
        ref_path = meta.get("input", {}).get("path")
        if not ref_path or not Path(ref_path).exists():
            raise InputError(f"{result}: its input {ref_path!r} is not there; pass --reference INPUT.mcap")
        reference = Path(ref_path)
    ref = McapInput(reference)
    gps, poles, relations = None, None, None
    for msg in ref.messages([ch.GPS, ch.LANDMARKS_TRUTH, ch.RELATIONS_TRUTH]):
        if msg.topic == ch.GPS:
            gps = [] if gps is None else gps
            gps.append([msg.t_s, msg.value.pose.position.x, msg.value.pose.position.y])
        elif msg.topic == ch.LANDMARKS_TRUTH:
            poles = np.column_stack([msg.value["x_m"], msg.value["y_m"]])
        else:
            v = msg.value
            relations = np.column_stack([v["t1_s"], v["t2_s"], v["dx_m"], v["dy_m"], v["dyaw_rad"]])
    out: dict[str, Any] = dict.fromkeys(METRIC_KEYS)
    if gps is not None and len(res.t_s):
        g = np.asarray(gps)
        out["gps_mean_error_m"] = gps_mean_error(res.t_s, res.trajectory, g)
        out["gps_mean_error_online_m"] = gps_mean_error(res.t_s, res.online, g)
        out["gps_rmse_aligned_m"] = gps_rmse_aligned(res.t_s, res.trajectory, g)
    if poles is not None and len(res.map_p):
        err, n = pole_map_error(res.map_xy, res.map_p, poles)
        out["pole_map_error_m"] = err
        out["poles_within_1m"] = n
    if relations is not None and len(res.t_s):
        rel = relations_error(res.stamp_s, res.trajectory, relations)
        for k in ("relations_trans_m", "relations_trans_std_m", "relations_rot_deg"):
            out[k] = rel[k]
    r = meta["result"]
    out["ms_per_step_median"] = r.get("ms_per_step_filter_median")
    out["real_time_factor"] = r.get("real_time_factor")
    out["final_map_points"] = r.get("final_map_points")
    out["particles"] = meta["config"]["filter"]["particles"]
    out["points_per_observation"] = meta["config"]["filter"]["points_per_observation"]
    return {k: _clean(v) for k, v in out.items()}
