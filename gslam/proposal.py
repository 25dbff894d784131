"""Improved proposal (open point 6): match the scan against each particle's own point map.

The score of a pose is a likelihood field over the particle's map points: each scan end point scores
exp(-d^2 / 2 sigma^2), d its distance to the nearest map point (capped at 3 sigma). The pose is
refined by hill climbing, as GMapping's scan matcher does on grids: from the motion-model sample, try
one step forwards and backwards along x, y and phi, move while the score improves, halve the steps
when it does not. All particles climb at once: their maps go into one KD-tree, each particle's points
shifted by its own offset, so one query serves every candidate pose of every particle. The tree holds
each map smoothed per 3 x 3 cells (the centre line of the scatter that point generation leaves around
surfaces) and only the points near the scan's end points.

As in GMapping, the particle is then weighed at the matched pose (step 5, unchanged): an
approximation of the weight of the optimal proposal that ignores how the match moved the sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .config import FilterConfig
from .motion import wrap_angle
from .pointmap import PointMap, smooth_by_cells

_OFFSET_M = 1.0e5  # particles' maps are laid side by side along x, this far apart


def _end_points(poses: np.ndarray, pts_sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World x and y (P, K) of the sensor-frame end points (K, 2) seen from each of `poses` (P, 3)."""
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    wx = poses[:, 0, None] + c * pts_sensor[:, 0] - s * pts_sensor[:, 1]
    wy = poses[:, 1, None] + s * pts_sensor[:, 0] + c * pts_sensor[:, 1]
    return wx, wy


@dataclass
class StackedMaps:
    """The distinct maps of the particles in one KD-tree; `slot[i]` is the map of particle i."""

    tree: cKDTree | None
    slot: np.ndarray
    sizes: np.ndarray

    @classmethod
    def of(cls, maps: list[PointMap], smooth_cell_m: float = 0.0, windows: np.ndarray | None = None) -> StackedMaps:
        """`windows` (N, 4): per particle, the box (x_min, y_min, x_max, y_max) outside which its map
        points cannot take part (a map shared by several particles keeps the union of their boxes)."""
        ids: dict[int, int] = {}
        distinct: list[PointMap] = []
        slot = np.empty(len(maps), dtype=np.int64)
        for i, m in enumerate(maps):  # particles that share a map after resampling share its slot
            k = ids.setdefault(id(m), len(distinct))
            if k == len(distinct):
                distinct.append(m)
            slot[i] = k
        sizes = np.array([len(m) for m in distinct])
        if sizes.sum() == 0:
            return cls(None, slot, sizes[slot])
        xy = np.concatenate([m.xy for m in distinct])
        owner = np.repeat(np.arange(len(distinct)), sizes)
        if smooth_cell_m > 0:  # maps are sorted by cell, so the concatenation is sorted by (slot, cell)
            xy = smooth_by_cells(owner, xy, smooth_cell_m)
        if windows is not None:
            box = np.full((len(distinct), 4), [np.inf, np.inf, -np.inf, -np.inf])
            np.minimum.at(box[:, :2], slot, windows[:, :2])
            np.maximum.at(box[:, 2:], slot, windows[:, 2:])
            b = box[owner]
            inside = (xy[:, 0] >= b[:, 0]) & (xy[:, 1] >= b[:, 1]) & (xy[:, 0] <= b[:, 2]) & (xy[:, 1] <= b[:, 3])
            xy, owner = xy[inside], owner[inside]
            sizes = np.bincount(owner, minlength=len(distinct))
            if len(xy) == 0:
                return cls(None, slot, sizes[slot])
        xy = xy + np.column_stack([owner * _OFFSET_M, np.zeros(len(xy))])
        return cls(cKDTree(xy), slot, sizes[slot])

    def scores(self, particle: np.ndarray, poses: np.ndarray, pts_sensor: np.ndarray, sigma_m: float) -> np.ndarray:
        """Likelihood-field score of the scan end points `pts_sensor` (K, 2) from `poses` (P, 3), each
        against the map of `particle[p]`: sum over end points of exp(-d^2 / 2 sigma^2), d the distance to
        the nearest (smoothed) map point, capped at 3 sigma."""
        wx, wy = _end_points(poses, pts_sensor)
        wx = wx + (self.slot[particle] * _OFFSET_M)[:, None]
        cap = 3 * sigma_m
        d, _ = self.tree.query(np.column_stack([wx.ravel(), wy.ravel()]), distance_upper_bound=cap)
        d = np.minimum(d, cap).reshape(len(poses), len(pts_sensor))
        return np.exp(-0.5 * (d / sigma_m) ** 2).sum(axis=1)


_MOVES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)


def match_scans(
    maps: list[PointMap], poses: np.ndarray, pts_sensor: np.ndarray, cfg: FilterConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hill-climb every particle's pose so that the scan end points `pts_sensor` (K, 2) fall on its map.

    Returns (refined poses (N, 3), matched mask (N,), score at the returned pose (N,)). A particle whose
    map is nearly empty, or whose best score is below `match_min_score` x K, keeps its pose (matched False).
    """
    n = len(poses)
    out = np.array(poses, dtype=float, copy=True)
    matched = np.zeros(n, dtype=bool)
    if len(pts_sensor) < 10:
        return out, matched, np.zeros(n)
    # Only map points near the scan can match: a box around the end points at each particle's pose.
    wx, wy = _end_points(out, pts_sensor)
    margin = cfg.match_window_margin_m
    windows = np.column_stack([wx.min(1) - margin, wy.min(1) - margin, wx.max(1) + margin, wy.max(1) + margin])
    stacked = StackedMaps.of(maps, cfg.cell_size_m if cfg.match_smoothing else 0.0, windows)
    if stacked.tree is None:
        return out, matched, np.zeros(n)
    sigma = cfg.match_sigma_m
    usable = stacked.sizes >= 20
    idx = np.flatnonzero(usable)
    score = np.zeros(n)
    if len(idx) == 0:
        return out, matched, score
    score[idx] = stacked.scores(idx, out[idx], pts_sensor, sigma)
    step = np.tile([cfg.match_step_xy_m, cfg.match_step_xy_m, cfg.match_step_phi_rad], (n, 1))
    level = np.where(usable, 0, cfg.match_levels)
    for _ in range(cfg.match_max_iterations):
        active = np.flatnonzero(level < cfg.match_levels)
        if len(active) == 0:
            break
        cand = out[active, None, :] + _MOVES[None] * step[active, None, :]  # (A, 6, 3)
        cand_scores = stacked.scores(np.repeat(active, 6), cand.reshape(-1, 3), pts_sensor, sigma).reshape(-1, 6)
        best = cand_scores.argmax(axis=1)
        best_score = cand_scores[np.arange(len(active)), best]
        better = best_score > score[active] * (1 + 1e-9)
        up = active[better]
        out[up] = cand[better, best[better]]
        score[up] = best_score[better]
        down = active[~better]
        step[down] *= 0.5
        level[down] += 1
    out[:, 2] = wrap_angle(out[:, 2])
    matched = usable & (score >= cfg.match_min_score * len(pts_sensor))
    out[~matched] = poses[~matched]
    return out, matched, score
