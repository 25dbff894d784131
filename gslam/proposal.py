"""Improved proposal (open point 6): match the scan against the particle's own point map.

Point-to-point ICP with a closed-form weighted 2-D rigid fit per iteration; correspondences are the
nearest map points (KD-tree) within a gate, weighted by their probability. A match that finds too
few correspondences, or moves the pose implausibly far, falls back to the motion prediction.
"""

from __future__ import annotations

import numpy as np

from .config import FilterConfig
from .motion import wrap_angle
from .pointmap import PointMap
from .scan import transform_points


def rigid_fit(src: np.ndarray, dst: np.ndarray, w: np.ndarray) -> tuple[float, np.ndarray]:
    """Weighted least-squares rotation angle and translation taking src (K,2) onto dst (K,2)."""
    ws = w.sum()
    cs = (w[:, None] * src).sum(0) / ws
    cd = (w[:, None] * dst).sum(0) / ws
    a = src - cs
    b = dst - cd
    sxx = (w * (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])).sum()
    sxy = (w * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])).sum()
    ang = np.arctan2(sxy, sxx)
    c, s = np.cos(ang), np.sin(ang)
    t = cd - np.array([c * cs[0] - s * cs[1], s * cs[0] + c * cs[1]])
    return float(ang), t


def match_scan(m: PointMap, pose: np.ndarray, pts_sensor: np.ndarray, cfg: FilterConfig) -> tuple[np.ndarray, bool]:
    """Refine `pose` so that the scan end points `pts_sensor` (K,2) fall on the map. Returns (pose, ok)."""
    if len(m) < 20 or len(pts_sensor) < 10:
        return pose, False
    p_rel = m.p if cfg.map_update == "binary" else np.minimum(m.p / m.mean_p, 1.0)
    cur = np.array(pose, dtype=float)
    gate = cfg.match_max_distance_m
    for _ in range(cfg.match_iterations):
        world = transform_points(cur, pts_sensor)
        dist, idx = m.tree.query(world, k=1, distance_upper_bound=gate)
        found = np.isfinite(dist)
        if found.sum() < max(10, len(pts_sensor) // 5):
            return pose, False
        w = p_rel[idx[found]] / (1.0 + (dist[found] / (0.5 * gate)) ** 2)
        ang, t = rigid_fit(world[found], m.xy[idx[found]], w)
        c, s = np.cos(ang), np.sin(ang)
        cur = np.array([c * cur[0] - s * cur[1] + t[0], s * cur[0] + c * cur[1] + t[1], wrap_angle(cur[2] + ang)])
        gate = max(gate * 0.6, 3 * cfg.hit_sigma_m)
        if abs(ang) < 1e-4 and np.hypot(*t) < 1e-3:
            break
    moved = np.hypot(cur[0] - pose[0], cur[1] - pose[1])
    turned = abs(wrap_angle(cur[2] - pose[2]))
    if moved > 2 * cfg.match_max_distance_m or turned > np.radians(10):
        return pose, False
    return cur, True
