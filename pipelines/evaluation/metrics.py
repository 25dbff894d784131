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


def relations_error(
    t_s: np.ndarray, poses: np.ndarray, relations: np.ndarray, tolerance_s: float = 1e-3
) -> dict[str, float]:
    """Kuemmerle et al. (2009) metric: per relation (t1, t2, dx, dy, dyaw) the translational and absolute
    rotational error of (estimated relation) (-) (reference relation); mean and std over relations
    whose two times match trajectory times within `tolerance_s`."""
    order = np.argsort(t_s, kind="stable")
    ts = t_s[order]

    def lookup(t):
        i = np.clip(np.searchsorted(ts, t), 1, len(ts) - 1)
        i = np.where(np.abs(ts[i - 1] - t) <= np.abs(ts[i] - t), i - 1, i)
        return order[i], np.abs(ts[i] - t) <= tolerance_s

    i1, ok1 = lookup(relations[:, 0])
    i2, ok2 = lookup(relations[:, 1])
    ok = ok1 & ok2
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
