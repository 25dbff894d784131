"""Accuracy metrics (pure numpy): GPS position error, SE(2)-aligned RMSE, pole map error, relations."""

from __future__ import annotations

import numpy as np

from gslam.motion import wrap_angle


def interpolate_positions(t_s: np.ndarray, poses: np.ndarray, query_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions of a trajectory linearly interpolated at query times inside its time span.

    Returns (mask of queries inside the span, (M, 2) positions for those queries).
    """
    inside = (query_s >= t_s[0]) & (query_s <= t_s[-1])
    q = query_s[inside]
    return inside, np.column_stack([np.interp(q, t_s, poses[:, 0]), np.interp(q, t_s, poses[:, 1])])


def gps_mean_error(t_s: np.ndarray, poses: np.ndarray, gps: np.ndarray) -> float:
    """The paper's position error: mean distance from the estimated position to each GPS fix (t, x, y)
    within the trajectory's time span."""
    inside, pos = interpolate_positions(t_s, poses, gps[:, 0])
    if not inside.any():
        return float("nan")
    return float(np.mean(np.hypot(*(pos - gps[inside, 1:3]).T)))


def gps_mean_error_at_scans(t_s: np.ndarray, poses: np.ndarray, gps: np.ndarray) -> float:
    """The same distance sampled the other way round: GPS interpolated at each step's time (within the
    GPS's span), the mean over steps. This is what evo's APE (translation, no alignment) gives for
    `gslam export --tum` against `gslam export --reference`."""
    inside, ref = interpolate_positions(gps[:, 0], gps[:, 1:3], t_s)
    if not inside.any():
        return float("nan")
    return float(np.mean(np.hypot(*(poses[inside, :2] - ref).T)))


def align_se2(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray]:
    """Least-squares rotation and translation taking src (K,2) onto dst (K,2) (Umeyama, no scale)."""
    cs, cd = src.mean(0), dst.mean(0)
    a, b = src - cs, dst - cd
    ang = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    c, s = np.cos(ang), np.sin(ang)
    return float(ang), cd - np.array([c * cs[0] - s * cs[1], s * cs[0] + c * cs[1]])


def gps_rmse_aligned(t_s: np.ndarray, poses: np.ndarray, gps: np.ndarray) -> float:
    """RMSE of position against GPS after a least-squares SE(2) alignment (evo's APE convention)."""
    inside, pos = interpolate_positions(t_s, poses, gps[:, 0])
    if inside.sum() < 2:
        return float("nan")
    ang, t = align_se2(pos, gps[inside, 1:3])
    c, s = np.cos(ang), np.sin(ang)
    aligned = pos @ np.array([[c, s], [-s, c]]) + t
    return float(np.sqrt(np.mean(np.sum((aligned - gps[inside, 1:3]) ** 2, axis=1))))


def map_modes(xy: np.ndarray, p: np.ndarray, radius_m: float = 0.5, quantile: float = 0.5) -> np.ndarray:
    """High-probability modes of a point map: points with p above the `quantile` of p that carry the
    largest p within `radius_m` (a local maximum)."""
    from scipy.spatial import cKDTree

    if len(p) == 0:
        return np.empty((0, 2))
    strong = p >= np.quantile(p, quantile)
    pts, ps = xy[strong], p[strong]
    tree = cKDTree(pts)
    neighbours = tree.query_ball_point(pts, radius_m)
    is_max = np.array([ps[i] >= ps[nb].max() for i, nb in enumerate(neighbours)])
    return pts[is_max]


def pole_map_error(xy: np.ndarray, p: np.ndarray, poles: np.ndarray, within_m: float = 1.0) -> tuple[float, int]:
    """Mean distance from each surveyed pole to the nearest high-probability map mode, and how many
    poles have a mode within `within_m`."""
    modes = map_modes(xy, p)
    if len(modes) == 0:
        return float("nan"), 0
    d = np.min(np.hypot(poles[:, None, 0] - modes[None, :, 0], poles[:, None, 1] - modes[None, :, 1]), axis=1)
    return float(d.mean()), int((d <= within_m).sum())


def relative_pose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose b expressed in the frame of pose a, for (..., 3) arrays."""
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[..., 2] - a[..., 2])], axis=-1)


def matched_relations(
    t_s: np.ndarray, relations: np.ndarray, tolerance_s: float = 1e-3
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(i1, i2, ok): for each relation (t1, t2, ...), the trajectory indices nearest its two times, and
    whether both lie within `tolerance_s` of them."""
    order = np.argsort(t_s, kind="stable")
    ts = t_s[order]

    def lookup(t):
        i = np.clip(np.searchsorted(ts, t), 1, len(ts) - 1)
        i = np.where(np.abs(ts[i - 1] - t) <= np.abs(ts[i] - t), i - 1, i)
        return order[i], np.abs(ts[i] - t) <= tolerance_s

    i1, ok1 = lookup(relations[:, 0])
    i2, ok2 = lookup(relations[:, 1])
    return i1, i2, ok1 & ok2


def relations_error(
    t_s: np.ndarray, poses: np.ndarray, relations: np.ndarray, tolerance_s: float = 1e-3
) -> dict[str, float]:
    """Kuemmerle et al. (2009) metric: per relation (t1, t2, dx, dy, dyaw) the translational and absolute
    rotational error of (estimated relation) (-) (reference relation); mean and std over relations
    whose two times match trajectory times within `tolerance_s`."""
    i1, i2, ok = matched_relations(t_s, relations, tolerance_s)
    if not ok.any():
        return {
            "relations_trans_m": float("nan"),
            "relations_trans_std_m": float("nan"),
            "relations_rot_deg": float("nan"),
            "relations_used": 0,
        }
    est = relative_pose(poses[i1[ok]], poses[i2[ok]])
    ref = relations[ok][:, [2, 3, 4]]
    err = relative_pose(ref, est)  # ref^-1 (+) est
    trans = np.hypot(err[:, 0], err[:, 1])
    rot = np.degrees(np.abs(err[:, 2]))
    return {
        "relations_trans_m": float(trans.mean()),
        "relations_trans_std_m": float(trans.std()),
        "relations_rot_deg": float(rot.mean()),
        "relations_used": int(ok.sum()),
    }


TURN_MIN_RAD = 0.3
"""A relation is a turn in place when it turns by at least this much ..."""
TURN_MAX_SHIFT_M = 0.2
"""... while its frame's origin moves by at most this much ..."""
TURN_MAX_GAP_S = 10.0
"""... within this time."""
FRAME_MIN_TURNS = 10
"""The fewest turns in place from which the relations' frame is located."""


def turn_centre(relative: np.ndarray) -> np.ndarray:
    """The point (x, y) in a frame that relative poses (K, 3) of that frame turn about: the least-squares
    solution c of (I - R(dyaw)) c = (dx, dy) over them (a turn by dyaw about c moves the frame's origin
    by (I - R(dyaw)) c)."""
    c, s = np.cos(relative[:, 2]), np.sin(relative[:, 2])
    a = np.zeros((2 * len(relative), 2))
    a[0::2, 0], a[0::2, 1] = 1.0 - c, s
    a[1::2, 0], a[1::2, 1] = -s, 1.0 - c
    return np.linalg.lstsq(a, relative[:, :2].reshape(-1), rcond=None)[0]


def relations_frame_offset(
    t_s: np.ndarray, poses: np.ndarray, relations: np.ndarray, tolerance_s: float = 1e-3
) -> tuple[np.ndarray, int] | None:
    """Where the origin of the relations' frame lies in the trajectory's frame (x ahead, y left [m]), and
    from how many turns in place; None with fewer than `FRAME_MIN_TURNS`.

    A robot turning in place turns about one point of its body. The reference's turns locate that point in
    the reference's frame, the trajectory's same turns locate it in the trajectory's; the difference is
    where one frame's origin lies in the other: a sensor offset that one of them carries and the other
    does not (a log that dropped its laser's mount). The relations metric compares the two frames' poses
    as if they were one; such an offset adds about twice itself to every relation that turns round."""
    i1, i2, ok = matched_relations(t_s, relations, tolerance_s)
    ref = relations[:, [2, 3, 4]]
    turn = (
        ok
        & (np.abs(ref[:, 2]) >= TURN_MIN_RAD)
        & (np.hypot(ref[:, 0], ref[:, 1]) <= TURN_MAX_SHIFT_M)
        & (np.abs(relations[:, 1] - relations[:, 0]) <= TURN_MAX_GAP_S)
    )
    if turn.sum() < FRAME_MIN_TURNS:
        return None
    est = relative_pose(poses[i1[turn]], poses[i2[turn]])
    return turn_centre(est) - turn_centre(ref[turn]), int(turn.sum())
